"""Wall seconds of a one-shot ``rpmnet-register SRC REF --out-transform T.txt`` beside the Open3D script
(``benchmarks/open3d_register.py``: read, voxel 2 mm, normals, FPFH, RANSAC, Tukey ICP), each a fresh process,
alternating, same files.

    python benchmarks/cli_time.py SRC REF [--repeats 5] [--conf bun.conf]

Prints one JSON line: each command's median and minimum wall seconds over ``--repeats`` runs (after one
untimed run each, which fills the OS file cache and Numba's on-disk cache), and with ``--conf`` (Stanford
poses) each answer's rotation (°) and translation (mm) error.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time

import bench_utils


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("src")
    p.add_argument("ref")
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--conf", default=None, help="Stanford .conf with both scans' poses")
    a = p.parse_args()
    import numpy as np

    out = tempfile.mkdtemp()
    commands = {
        "rpmnet-register": [sys.executable, "-m", "rpmnet_jax.cli.register", a.src, a.ref, "--out-transform",
                            os.path.join(out, "rpmnet.txt")],
        "open3d_script": [sys.executable, os.path.join(bench_utils.HERE, "open3d_register.py"), a.src, a.ref,
                          os.path.join(out, "open3d.txt")]}
    env = dict(os.environ, PYTHONPATH=bench_utils.REPO)
    walls = {k: [] for k in commands}
    for i in range(a.repeats + 1):
        for name, cmd in commands.items():
            t0 = time.perf_counter()
            subprocess.run(cmd, check=True, capture_output=True, env=env)
            if i:
                walls[name].append(time.perf_counter() - t0)
    record = {"task": "one_shot_cli", "src": os.path.basename(a.src), "ref": os.path.basename(a.ref),
              "repeats": a.repeats}
    for name in commands:
        record[name] = {"wall_median": statistics.median(walls[name]), "wall_min": min(walls[name])}
    if a.conf:
        from rpmnet_jax.io import poses as poses_io
        from rpmnet_jax.ops import se3

        stem = lambda f: os.path.splitext(os.path.basename(f))[0]
        gt = poses_io.relative_motion(poses_io.read_poses(a.conf), stem(a.src), stem(a.ref))
        for name, file in (("rpmnet-register", "rpmnet.txt"), ("open3d_script", "open3d.txt")):
            t = np.loadtxt(os.path.join(out, file))
            record[name]["rotation_error_deg"] = float(se3.rotation_angle_deg(t[:3, :3] @ gt[:3, :3].T))
            record[name]["translation_error_mm"] = float(1e3 * np.linalg.norm(t[:3, 3] - gt[:3, 3]))
    record["ratio_median"] = record["rpmnet-register"]["wall_median"] / record["open3d_script"]["wall_median"]
    bench_utils.emit({**record, **bench_utils.environment()})


if __name__ == "__main__":
    main()
