"""Two dense clouds (the Stanford bunny scans ``bun045`` → ``bun000`` densified in memory) registered by the default
:func:`rpmnet_jax.align` and by Open3D's scan recipe (voxel first: :func:`rpmnet_jax.evaluation.baselines.
open3d_scan_pair`), each in a process of its own, one after the other.

    python benchmarks/dense_time.py --scans ../shared/data/stanford_bunny [--points 10000000] [--voxel 0.002]

Each scan is repeated with 0.1 mm Gaussian jitter (seeded) up to ``--points`` rows. Prints one JSON line per
method: seconds (registration only, the clouds already in memory), the process's peak resident memory and its
increment over the two input clouds, the rotation (°) and translation (mm) error against ``bun.conf``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

import bench_utils


def _densified(path: str, points: int, seed: int):
    import numpy as np

    from rpmnet_jax.io import clouds

    xyz = clouds.read_cloud(path)[0]
    rng = np.random.default_rng(seed)
    reps = -(-points // len(xyz))
    dense = np.repeat(xyz, reps, axis=0)[:points]
    dense += rng.normal(0.0, 1e-4, dense.shape)
    return dense


def _measure(a) -> dict:
    import numpy as np

    from rpmnet_jax.io import poses as poses_io
    from rpmnet_jax.ops import se3

    src = _densified(os.path.join(a.scans, "bun045.ply"), a.points, 0)
    ref = _densified(os.path.join(a.scans, "bun000.ply"), a.points, 1)
    base_mb = bench_utils.peak_rss_mb()
    t0 = time.perf_counter()
    if a.method == "rpmnet_jax":
        from rpmnet_jax.pairwise import alignment

        transform = alignment.align(src, ref).transform
    else:
        from rpmnet_jax.evaluation import baselines

        transform = baselines.open3d_scan_pair(src, ref, a.voxel)
    seconds = time.perf_counter() - t0
    gt = poses_io.relative_motion(poses_io.read_poses(os.path.join(a.scans, "bun.conf")), "bun045", "bun000")
    return {"task": "dense_pair", "method": a.method, "points": a.points, "seconds": seconds,
            "peak_rss_mb": bench_utils.peak_rss_mb(), "peak_over_inputs_mb": bench_utils.peak_rss_mb() - base_mb,
            "rotation_error_deg": float(se3.rotation_angle_deg(transform[:3, :3] @ gt[:3, :3].T)),
            "translation_error_mm": float(1e3 * np.linalg.norm(transform[:3, 3] - gt[:3, 3]))}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scans", required=True, help="folder with bun045.ply, bun000.ply and bun.conf")
    p.add_argument("--points", type=int, default=10_000_000)
    p.add_argument("--voxel", type=float, default=0.002, help="Open3D's voxel size (default 2 mm)")
    p.add_argument("--method", choices=("rpmnet_jax", "open3d"), default=None, help="(internal) one method")
    a = p.parse_args()
    if a.method:
        print(json.dumps(_measure(a)))
        return
    for method in ("rpmnet_jax", "open3d"):
        out = subprocess.run([sys.executable, __file__, *sys.argv[1:], "--method", method], capture_output=True,
                             text=True)
        if out.returncode:
            raise SystemExit(out.stderr)
        bench_utils.emit({**json.loads(out.stdout.strip().splitlines()[-1]), **bench_utils.environment()})


if __name__ == "__main__":
    main()
