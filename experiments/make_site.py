"""Write a simulated site campaign: a town scanned from terrestrial-scanner stations along its streets, with the
stations' true poses (:mod:`rpmnet_jax.simulation.sites`).

    python -m experiments.make_site --stations 1000 --seed 0 --out site1000 --shuffle

writes ``OUT/scan0000.ply …`` (binary PLY, float64, each station's points in its own frame), ``OUT/truth.conf``
(each file's true pose, Stanford ``.conf``: ``rpmnet-eval-scans --scans OUT --conf truth.conf --multiway`` scores
a registration of the set) and ``OUT/settings.json``. ``--shuffle``: files in a seeded random order. The first
``S`` stations of a seed's town are one connected stretch of streets, so 10, 100 and 1,000 stations of one seed
are nested campaigns (the scaling benchmark's sets). 1,000 stations: a town 532 m across, about 70k points a
station, 1.7 GB of files.
"""

import argparse
import sys
import time

from rpmnet_jax.simulation import range_scans, sites


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--stations", type=int, default=100, help="number of stations (default 100)")
    p.add_argument("--step", type=float, default=sites.STEP_DEG,
                   help=f"the scanner's angular step, degrees (default {sites.STEP_DEG}: about 70k points a "
                        "station)")
    p.add_argument("--seed", type=int, default=0, help="the town, the stations' headings and the noise")
    p.add_argument("--shuffle", action="store_true", help="name the files in a seeded random order")
    p.add_argument("--out", required=True, help="output folder (empty or new)")
    a = p.parse_args(argv)
    if a.stations < 1:
        p.error(f"--stations must be >= 1 (got {a.stations})")
    if not 0.05 <= a.step <= 10.0:
        p.error(f"--step must be in [0.05, 10] degrees (got {a.step})")
    t0 = time.perf_counter()
    site, stations = sites.stations(
        a.stations, a.seed, a.step,
        progress=lambda done, total: print(f"station {done}/{total}", file=sys.stderr, flush=True)
        if done % max(1, total // 20) == 0 or done == total else None)
    settings = {"stations": a.stations, "step": a.step, "seed": a.seed, "shuffle": a.shuffle,
                "town_size_m": [float(v) for v in site.size], "max_range_m": sites.MAX_RANGE,
                "noise_m": sites.NOISE}
    try:
        range_scans.write_set(a.out, stations, shuffle_seed=a.seed if a.shuffle else None, settings=settings)
    except (ValueError, OSError) as e:
        print(f"error: {e} (choose another --out)", file=sys.stderr)
        return 2
    points = sum(len(s.points) for s in stations)
    print(f"wrote {a.stations} stations ({points} points, {points // a.stations} a station; a town "
          f"{site.size[0]:.0f} m across) and truth.conf to {a.out} in {time.perf_counter() - t0:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
