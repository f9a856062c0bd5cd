"""A scan campaign into one frame, ours beside Open3D's multiway recipe, on a set with true poses (the files and
``truth.conf`` of ``python -m experiments.make_range_scans``, or any folder of scans with a Stanford ``.conf``).

    python benchmarks/campaign_time.py SET [--conf truth.conf] [--units m] [--limit-scans N] [--skip-open3d]
        [--open3d-voxel V] [--open3d-order free|file] [--open3d-timeout SECONDS] [--repeat 1] [--out-jsonl results.jsonl]

Each side runs in a fresh process of its own, one after the other, on the scans of the ``.conf`` in its order
(file order; for a shuffled set, order says nothing about overlap): ours reads them with
:mod:`rpmnet_jax.io.clouds` and runs :func:`rpmnet_jax.align_scans` (default options; the persistent
compilation cache as ``rpmnet-register-scans`` sets it: ``RPMNET_COMPILATION_CACHE=off`` for a cold start);
Open3D reads them with its own reader and runs :func:`rpmnet_jax.evaluation.baselines.open3d_multiway`
(voxel ``--open3d-voxel``, default 1.5% of the median robust scan radius: 2 mm on the bunny), used order-free:
its certain edges are the maximum spanning tree of the pairs' fitness, every other pair an uncertain loop
closure, so the file order does not matter (``--open3d-order file`` gives it neighbouring files as odometry
edges, as its tutorial does for a sequence: a "file order" result, wrong for shuffled files).

Prints one JSON line per run: ``seconds`` (reading and registration), ``process_seconds`` (the whole process:
start, imports, compilation), the process's peak resident memory (``peak_rss_mb``; ``rss_after_imports_mb``
before any work), pairs registered (ours: ``ScanAlignment.pairs``, the pairs each stage registered, a pair
registered in two stages counted twice, the global placements of single scans not counted; Open3D: every
pair), per scan the rotation error (°) and the RMS displacement of its points from their true place (both
relative to the first placed scan; ×1000 with ``--units m``: mm), worst, mean and the scans within 0.5° and
1 mm; then, with both sides, one line of ratios (ours / Open3D's). A table goes to stderr.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

import bench_utils

WITHIN_DEG, WITHIN_MM = 0.5, 1.0


def scan_files(folder: str, conf: str, limit: int | None = None):
    """``(names, paths, true poses (S, 4, 4))`` of the scans named in ``folder/conf``, in its order."""
    import numpy as np

    from rpmnet_jax.io import clouds, poses as poses_io

    truth = poses_io.read_poses(os.path.join(folder, conf))
    files = {os.path.splitext(f)[0]: f for f in os.listdir(folder) if f.lower().endswith(clouds.FORMATS)}
    names = list(truth)[:limit]
    missing = [n for n in names if n not in files]
    if missing:
        raise SystemExit(f"{conf} names scans that are not in {folder}: {missing[:5]}")
    return names, [os.path.join(folder, files[n]) for n in names], np.stack([truth[n] for n in names])


def run_ours(paths, seed: int, scheduler=None) -> dict:
    """Reads ``paths`` and registers them with :func:`rpmnet_jax.align_scans` (in this process; its tasks on
    ``scheduler``, a Dask scheduler's address, when given)."""
    from rpmnet_jax.cli import runtime

    cache = runtime.enable_compilation_cache()  # as rpmnet-register-scans does; before JAX is imported
    from rpmnet_jax.io import clouds
    from rpmnet_jax.multiway import options, scan_alignment  # imported before the clock starts

    base = bench_utils.peak_rss_mb()
    totals = {}
    t0 = time.perf_counter()
    scans = [clouds.read_cloud(p)[0] for p in paths]
    read_seconds = time.perf_counter() - t0
    r = scan_alignment.align_scans(scans, options=options.ScanOptions(seed=seed), scheduler=scheduler,
                                   progress=lambda stage, done, total: totals.__setitem__(stage, total))
    seconds = time.perf_counter() - t0
    return {"seconds": seconds, "read_seconds": read_seconds, "rss_after_imports_mb": base,
            "peak_rss_mb": bench_utils.peak_rss_mb(), "poses": r.poses.tolist(),
            "pairs_registered": sum(n for stage, n in r.pairs.items() if stage != "global"),
            "pairs_per_stage": r.pairs, "progress_totals": totals, "edges": len(r.edges), "rejected": len(r.rejected),
            "left_out": list(r.left_out), "likely_wrong": list(r.likely_wrong),
            "timings": {k: round(v, 3) for k, v in r.timings.items()}, "compilation_cache": cache is not None,
            "points": int(sum(len(s) for s in scans)), **bench_utils.environment()}


def run_open3d(paths, voxel: float, seed: int, order: str = "free") -> dict:
    """Reads ``paths`` with Open3D and registers them with its multiway recipe (in this process)."""
    import numpy as np
    import open3d as o3d

    from rpmnet_jax.evaluation import baselines

    base = bench_utils.peak_rss_mb()
    t0 = time.perf_counter()
    scans = [np.asarray(o3d.io.read_point_cloud(p).points) for p in paths]
    read_seconds = time.perf_counter() - t0
    poses = baselines.open3d_multiway(  # progress on stderr: how far a run stopped by --open3d-timeout came
        scans, voxel, seed=seed, order=order, progress=lambda done, total: print(f"pairs {done} {total} {time.perf_counter() - t0:.1f}",
                                                                    file=sys.stderr, flush=True))
    seconds = time.perf_counter() - t0
    s = len(scans)
    return {"seconds": seconds, "read_seconds": read_seconds, "rss_after_imports_mb": base,
            "peak_rss_mb": bench_utils.peak_rss_mb(), "poses": poses.tolist(), "pairs_registered": s * (s - 1) // 2,
            "voxel": voxel, "order": order, "open3d": o3d.__version__, "points": int(sum(len(x) for x in scans)),
            **bench_utils.environment()}


def score(poses, truth, clouds, scale: float) -> dict:
    """Per scan errors of ``poses (S, 4, 4)`` against ``truth (S, 4, 4)`` relative to the first placed scan
    (:func:`rpmnet_jax.evaluation.pose_errors.pose_errors`), RMS × ``scale``; worst, mean, scans within."""
    import numpy as np

    from rpmnet_jax.evaluation import pose_errors

    poses = np.asarray(poses, np.float64)
    placed = [k for k in range(len(poses)) if np.all(np.isfinite(poses[k]))]
    if not placed:
        return {"within": 0, "placed": 0}
    order = [placed[0]] + [k for k in range(len(poses)) if k != placed[0]]  # the first placed scan is the frame
    errors = np.full((len(poses), 2), np.nan)
    errors[order] = pose_errors.pose_errors(poses[order], truth[order], [clouds[k] for k in order])
    rot, rms = errors[:, 0], errors[:, 1] * scale
    within = (rot <= WITHIN_DEG) & (rms <= WITHIN_MM)  # NaN (left out) is never within
    return {"rotation_deg": [round(float(x), 4) for x in rot], "rms": [round(float(x), 4) for x in rms],
            "worst_rotation_deg": float(np.nanmax(rot)), "mean_rotation_deg": float(np.nanmean(rot)),
            "worst_rms": float(np.nanmax(rms)), "mean_rms": float(np.nanmean(rms)), "within": int(within.sum()),
            "placed": len(placed)}


def _child(a) -> int:
    _, paths, _ = scan_files(a.set, a.conf, a.limit_scans)
    if a.side == "ours":
        record = run_ours(paths, a.seed, a.scheduler)
    else:
        record = run_open3d(paths, a.open3d_voxel, a.seed, a.open3d_order)
    print(json.dumps(record))
    return 0


def child_run(script: str, argv: list, side: str, extra=(), timeout: float | None = None) -> dict:
    """The last JSON line of ``script argv --side side`` run in a fresh process, with its wall time
    (``process_seconds``); ``error`` (its last stderr line) when it failed; stopped after ``timeout`` seconds:
    ``timed_out`` and ``pairs_done`` (of ``pairs_total``, by then, from its progress lines)."""
    t0 = time.perf_counter()
    try:
        proc = subprocess.run([sys.executable, script, *argv, "--side", side, *extra], capture_output=True,
                              text=True, timeout=timeout)
    except subprocess.TimeoutExpired as stopped:
        err = stopped.stderr.decode() if isinstance(stopped.stderr, bytes) else (stopped.stderr or "")
        done = [line.split() for line in err.splitlines() if line.startswith("pairs ")]
        return {"error": f"stopped after {timeout:.0f} s", "timed_out": True, "process_seconds": timeout,
                "pairs_done": int(done[-1][1]) if done else 0, "pairs_total": int(done[-1][2]) if done else None}
    wall = time.perf_counter() - t0
    lines = proc.stdout.strip().splitlines()
    if proc.returncode or not lines:
        return {"error": (proc.stderr.strip().splitlines() or [f"exit {proc.returncode}"])[-1],
                "process_seconds": wall}
    return {**json.loads(lines[-1]), "process_seconds": wall}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("set", help="folder of scans and their .conf")
    p.add_argument("--conf", default="truth.conf", help="true poses inside SET (default truth.conf)")
    p.add_argument("--units", choices=("m", "mm"), default="m", help="the scans' units (errors are stated in mm)")
    p.add_argument("--limit-scans", type=int, default=None, help="only the first N scans of the .conf")
    p.add_argument("--skip-open3d", action="store_true")
    p.add_argument("--open3d-voxel", type=float, default=None, help="Open3D's voxel size, the scans' units")
    p.add_argument("--open3d-order", choices=("free", "file"), default="free",
                   help="Open3D's certain edges: a spanning tree of pair fitness (free) or neighbouring files (file)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--repeat", type=int, default=1, help="fresh processes per side (default 1)")
    p.add_argument("--out-jsonl", default=None, help="append the JSON lines to this file")
    p.add_argument("--open3d-timeout", type=float, default=None,
                   help="stop Open3D's run after this many seconds (its record says how many pairs it had done)")
    p.add_argument("--side", choices=("ours", "open3d"), default=None, help="(internal) one side, in this process")
    p.add_argument("--scheduler", default=None, help="(internal) ours: the Dask scheduler's address")
    a = p.parse_args(argv)
    if a.side:
        return _child(a)
    import numpy as np

    from rpmnet_jax.geometry import cloud as cloud_lib
    from rpmnet_jax.io import clouds as cloud_io

    names, paths, truth = scan_files(a.set, a.conf, a.limit_scans)
    clouds = [cloud_io.read_cloud(path)[0] for path in paths]
    if a.open3d_voxel is None:
        a.open3d_voxel = 0.015 * float(np.median([cloud_lib.robust_radius(c) for c in clouds]))
    scale = 1000.0 if a.units == "m" else 1.0
    settings = os.path.join(a.set, "settings.json")
    made = json.load(open(settings)) if os.path.exists(settings) else {}
    record = {"task": "scan_campaign", "set": os.path.basename(os.path.normpath(a.set)), "scans": len(names),
              "commit": bench_utils.commit(),
              "image_size": made.get("image_size"), "noise": made.get("noise"), "shuffled": made.get("shuffle"),
              **bench_utils.session("campaign_time.py", argv, bench_utils.available_cpus(), "default")}
    child_argv = [a.set, "--conf", a.conf, "--seed", str(a.seed), "--open3d-voxel", repr(a.open3d_voxel),
                  "--open3d-order", a.open3d_order]
    child_argv += ["--limit-scans", str(a.limit_scans)] if a.limit_scans else []
    results = {}
    for side in ("ours",) + (() if a.skip_open3d else ("open3d",)):
        for k in range(a.repeat):
            out = child_run(os.path.abspath(__file__), child_argv, side,
                            timeout=a.open3d_timeout if side == "open3d" else None)
            if "error" not in out:
                out.update(score(out.pop("poses"), truth, clouds, scale))
                print(f"{side} run {k + 1}: {out['seconds']:.1f} s ({out['process_seconds']:.1f} s process), peak "
                      f"{out['peak_rss_mb']:.0f} MB, {out['pairs_registered']} pairs; {out['within']}/{len(names)} "
                      f"within {WITHIN_DEG} deg and {WITHIN_MM} mm; worst {out['worst_rotation_deg']:.3f} deg / "
                      f"{out['worst_rms']:.3f} mm, mean {out['mean_rotation_deg']:.3f} deg / {out['mean_rms']:.3f} mm",
                      file=sys.stderr)
            results[side] = dict(record, side=side, run=k + 1, **out)
            bench_utils.emit(results[side], a.out_jsonl)
    if "ours" in results and results.get("open3d", {}).get("timed_out") and "error" not in results["ours"]:
        theirs = results["open3d"]
        print(f"open3d: stopped after {a.open3d_timeout:.0f} s at pair {theirs['pairs_done']} of "
              f"{theirs['pairs_total']}", file=sys.stderr)
        bench_utils.emit({"task": "scan_campaign_ratio", "set": record["set"], "scans": len(names),
                          "seconds_ratio_at_most": results["ours"]["process_seconds"] / a.open3d_timeout,
                          "open3d_pairs_done": theirs["pairs_done"], "open3d_pairs_total": theirs["pairs_total"],
                          "target_seconds_ratio": 0.2}, a.out_jsonl)
    if {"ours", "open3d"} <= set(results) and not any("error" in r for r in results.values()):
        ours, theirs = results["ours"], results["open3d"]
        bench_utils.emit({"task": "scan_campaign_ratio", "set": record["set"], "scans": len(names),
                          "seconds_ratio": ours["seconds"] / theirs["seconds"],
                          "process_seconds_ratio": ours["process_seconds"] / theirs["process_seconds"],
                          "peak_rss_ratio": ours["peak_rss_mb"] / theirs["peak_rss_mb"],
                          "target_seconds_ratio": 0.2}, a.out_jsonl)
    if results and all("rotation_deg" in r for r in results.values()):
        sides = list(results)
        print(f"{'scan':<10}" + "".join(f" | {s + ' deg / mm':>24}" for s in sides), file=sys.stderr)
        for k, n in enumerate(names):
            print(f"{n:<10}" + "".join(f" | {results[s]['rotation_deg'][k]:>11.3f} / {results[s]['rms'][k]:>10.3f}"
                                       for s in sides), file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
