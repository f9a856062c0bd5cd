"""``experiments.eval_scans --multiway``: many scans into one frame, ours and Open3D's recipe, against a ``.conf``
of true poses (see :mod:`rpmnet_jax.cli.eval_scans`)."""

from __future__ import annotations

import json
import os
import sys

import numpy as np

from rpmnet_jax.cli import runtime

METHODS = ("rpmnet_multiway", "open3d_multiway")


def _timed(fn):
    """``(fn(), wall seconds, CPU seconds)``."""
    from rpmnet_jax import stopwatch

    clock = stopwatch.Stopwatch()
    out = fn()
    return out, clock.elapsed(), clock.cpu_elapsed()


def run(a) -> int:
    from rpmnet_jax.evaluation import baselines, pose_errors
    from rpmnet_jax.io import clouds as cloud_io, poses as poses_io
    from rpmnet_jax.multiway import options as options_lib, scan_alignment
    from rpmnet_jax.weights import loading

    try:
        conf = os.path.join(a.scans, a.conf)
        true = poses_io.read_poses(conf)
        names = list(true)
        methods = [m for m in a.multiway_methods.split(",") if m]
        unknown = [m for m in methods if m not in METHODS]
        if unknown:
            raise ValueError(f"unknown --multiway-methods {unknown}; choose from {','.join(METHODS)}")
        if "open3d_multiway" in methods and baselines.open3d_available():
            print(f"open3d_multiway: skipped ({baselines.open3d_available()})", file=sys.stderr)
            methods.remove("open3d_multiway")
        if a.repeat < 1:
            raise ValueError(f"--repeat must be >= 1, got {a.repeat}")
        runtime.check_outputs(a.output, a.plot)
        files = {os.path.splitext(f)[0]: f for f in os.listdir(a.scans)}
        missing = [n for n in names if n not in files]
        if missing:
            raise ValueError(f"{conf} names scans not in {a.scans}: {missing}")
        clouds = [cloud_io.read_cloud(os.path.join(a.scans, files[n]))[0] for n in names]
        params = loading.load_params(a.checkpoint) if "rpmnet_multiway" in methods else None
    except (ValueError, OSError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2

    truth = np.stack([true[n] for n in names])
    fns = {"rpmnet_multiway": lambda: scan_alignment.align_scans(
        clouds, params=params, options=options_lib.ScanOptions(seed=a.seed)).poses,
           "open3d_multiway": lambda: baselines.open3d_multiway(clouds, a.baseline_voxel, seed=a.seed)}
    results = {}
    for m in methods:
        runs = [_timed(fns[m]) for _ in range(a.repeat)]
        poses = runs[-1][0]
        errors = pose_errors.pose_errors(poses, truth, clouds)
        results[m] = {"poses": poses, "errors": errors, "seconds": [r[1] for r in runs],
                      "cpu_seconds": [r[2] for r in runs]}

    print(f"{'scan':<12} | " + " | ".join(f"{m + ' deg / mm':>30}" for m in methods))
    for k, n in enumerate(names):
        cells = [f"{results[m]['errors'][k][0]:>12.3f} / {1000 * results[m]['errors'][k][1]:>10.3f}" for m in methods]
        print(f"{n:<12} | " + " | ".join(f"{c:>30}" for c in cells))
    summary = {}
    for m in methods:
        rot = np.array([e[0] for e in results[m]["errors"]])
        rms = np.array([e[1] for e in results[m]["errors"]])
        summary[m] = {"max_rotation_deg": float(np.nanmax(rot)), "max_rms": float(np.nanmax(rms)),
                      "within_0.5deg_1mm": int(np.sum((rot <= 0.5) & (rms <= 1e-3))), "scans": len(names),
                      "seconds": results[m]["seconds"], "cpu_seconds": results[m]["cpu_seconds"]}
        print(f"{m}: {summary[m]['within_0.5deg_1mm']}/{len(names)} scans within 0.5 deg and 1 mm; "
              f"time {' '.join(f'{t:.1f}' for t in summary[m]['seconds'])} s "
              f"(cpu {' '.join(f'{t:.1f}' for t in summary[m]['cpu_seconds'])} s)")
    if a.output:
        with open(a.output, "w") as f:
            json.dump({"scans": names, "summary": summary,
                       "per_scan": {m: [{"scan": n, "rotation_deg": e[0], "rms": e[1]}
                                        for n, e in zip(names, results[m]["errors"])] for m in methods},
                       "poses": {m: results[m]["poses"].tolist() for m in methods}}, f, indent=2)
    if a.plot:
        from rpmnet_jax.cli import plots
        panels = {m: [None if not np.all(np.isfinite(p)) else c @ p[:3, :3].T + p[:3, 3]
                      for c, p in zip(clouds, results[m]["poses"])] for m in methods}
        panels = {"truth (.conf)": [c @ t[:3, :3].T + t[:3, 3] for c, t in zip(clouds, np.linalg.inv(truth[0]) @ truth)],
                  **panels}
        plots.plot_scans(a.plot, panels, names)
    return 0
