"""Write a set of simulated range scans of a mesh with their true poses (:mod:`rpmnet_jax.simulation.range_scans`).

    python -m experiments.make_range_scans --mesh ../shared/data/stanford_bunny/bun_zipper_res2.ply --scans 60 \
        --image-size 640 --noise 0.0005 --seed 0 --out scans60 --shuffle

writes ``OUT/scan000.ply …`` (binary PLY, float64, each scan in its sensor frame), ``OUT/truth.conf`` (each
file's true pose, Stanford ``.conf``: ``rpmnet-eval-scans --scans OUT --conf truth.conf --multiway`` scores a
registration of the set) and ``OUT/settings.json``. ``--shuffle``: files in a seeded random order.
"""

import argparse
import sys
import time

from rpmnet_jax.simulation import range_scans
from rpmnet_jax.io import clouds, ply


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--mesh", required=True, help="triangle mesh (PLY, ASCII or binary; polygons are triangulated)")
    p.add_argument("--scans", type=int, default=60, help="number of scans (default 60)")
    p.add_argument("--image-size", type=int, default=640, help="pixels per image side (default 640)")
    p.add_argument("--fov", type=float, default=40.0, help="field of view, degrees (default 40)")
    p.add_argument("--noise", type=float, default=0.0005, help="depth noise std along each ray, mesh units "
                                                                 "(default 0.0005: 0.5 mm for a mesh in metres)")
    p.add_argument("--distance", type=float, default=None, help="camera distance from the mesh centre, mesh "
                                                                  "units (default: the mesh fills the image)")
    p.add_argument("--max-incidence", type=float, default=80.0, help="drop hits this many degrees or more off "
                                                                       "the face normal (default 80)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--shuffle", action="store_true", help="name the files in a seeded random order")
    p.add_argument("--out", required=True, help="output folder")
    a = p.parse_args(argv)
    t0 = time.perf_counter()
    try:
        vertices, faces = ply.read_mesh(a.mesh)
        scans = range_scans.simulate(
            vertices, faces, a.scans, image_size=a.image_size, fov_deg=a.fov, noise=a.noise, distance=a.distance,
            max_incidence_deg=a.max_incidence, seed=a.seed,
            progress=lambda done, total: print(f"scan {done}/{total}", file=sys.stderr, flush=True))
    except (ValueError, clouds.CloudError) as e:
        print(f"error: {e} (check --mesh, --scans, --image-size, --fov, --noise, --distance)", file=sys.stderr)
        return 2
    settings = {k: getattr(a, k) for k in ("mesh", "scans", "image_size", "fov", "noise", "distance",
                                           "max_incidence", "seed", "shuffle")}
    try:
        range_scans.write_set(a.out, scans, shuffle_seed=a.seed if a.shuffle else None, settings=settings)
    except (ValueError, OSError) as e:
        print(f"error: {e} (choose another --out)", file=sys.stderr)
        return 2
    points = sum(len(s.points) for s in scans)
    print(f"wrote {a.scans} scans ({points} points, {points // a.scans} a scan) and truth.conf to {a.out} "
          f"in {time.perf_counter() - t0:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
