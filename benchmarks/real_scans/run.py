"""The real-scan benchmark: every set under ``benchmarks/real_scans/data`` (an object scanned on a turntable,
indoor RGB-D frames, an outdoor LiDAR sequence) and the LiDAR set moved into a national grid, registered by
``rpmnet_jax`` and by the anchors a practitioner would pick, in the same run, on the same files:

- pairs (``--task pairs``): overlapping scans of the part (overlap ≥ 30 % at the true poses), each as captured
  (each scan in its own frame) and with the source turned 90–180° about a random axis; methods
  ``rpmnet_jax`` (``rpmnet_jax.align``, defaults), ``open3d`` (Open3D's scan recipe: voxel, normals, FPFH,
  RANSAC with the mutual filter and checkers, Tukey point-to-plane ICP;
  :func:`rpmnet_jax.evaluation.baselines.open3d_scan_pair`), ``kiss_small_gicp`` (KISS-Matcher, then
  small_gicp's GICP; :func:`~rpmnet_jax.evaluation.baselines.kiss_small_gicp_pair`). Success: rotation < 5° and
  translation (the displacement of the source's sensor position) < 2 % of the part's extent.
- scan sets (``--task scans``): the part's scans (at most ``--max-scans``, evenly spaced) in a seeded shuffled
  order; ``rpmnet_jax_scans``
  (``rpmnet_jax.align_scans``, defaults) and ``open3d_multiway`` (Open3D's multiway recipe used order-free:
  the maximum spanning tree of pair fitness as certain edges). Success per scan: rotation < 5° and RMS
  displacement of its points < 2 % of the extent, relative to the first scan (which is not counted).

Every anchor gets the voxel its documentation gives for that kind of data (``sets.VOXEL``); ``rpmnet_jax``
gets no size at all (its defaults). On the national-grid set the anchors get the clouds shifted by one
point of the reference (a viewer's "global shift", which float32 tools and small_gicp's 21-bit voxel keys need;
restored after), ``rpmnet_jax`` the grid coordinates as they are. Where the scans are in their sensors' frames
(RGB-D frames, LiDAR sweeps), Open3D's normals are turned toward the sensor.

Each (set, task, method) runs in a process of its own (peak memory is that process's; the JAX-based method
pays its imports before the clock; every method registers the tune part's first pair before the clock, ours also
every compilation ``align`` can meet: classical, network and global search). Each record names the commit, the
libraries' versions and the machine. One JSON line per run with
the per-pair errors and times; ``--out-md`` writes the table.

    python benchmarks/real_scans/run.py [--part report] [--sets happy_stand,...] [--max-pairs 12] \\
        [--out-jsonl results.jsonl] [--out-md table.md]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.dirname(HERE))

import numpy as np  # noqa: E402

import bench_utils  # noqa: E402  (puts the repository root on sys.path)
import sets  # noqa: E402

PAIR_METHODS = ("rpmnet_jax", "open3d", "kiss_small_gicp")
SCAN_METHODS = ("rpmnet_jax_scans", "open3d_multiway")
MAX_ROTATION_DEG = 5.0
MAX_TRANSLATION_SHARE = 0.02


def shifted(method, shift):
    """``method(src, ref, sensors) -> (4, 4)`` run on clouds (and sensors) moved by ``-shift (3,)``, its answer
    moved back: a viewer's "global shift"."""
    def run(src, ref, sensors):
        local = None if sensors is None else [v - shift for v in sensors]
        return sets.translation(shift) @ method(src - shift, ref - shift, local) @ sets.translation(-shift)
    return run


def pair_method(name: str, s: sets.ScanSet):
    """``register(src (N, 3), ref (M, 3), sensors) -> (4, 4)`` for method ``name`` on set ``s``; ``sensors``:
    the two scans' sensor positions when they are known, else None (only Open3D's recipe uses them: its normals
    are turned toward the sensor)."""
    from rpmnet_jax.evaluation import baselines
    if name == "rpmnet_jax":
        import rpmnet_jax
        return lambda src, ref, sensors: rpmnet_jax.align(src, ref).transform
    method = {"open3d": lambda src, ref, sensors: baselines.open3d_scan_pair(src, ref, s.voxel, viewpoints=sensors),
              "kiss_small_gicp": lambda src, ref, sensors: baselines.kiss_small_gicp_pair(src, ref, s.voxel)}[name]
    return method if s.kind != "georeferenced" else lambda src, ref, sensors: shifted(method, ref[0].copy())(
        src, ref, sensors)


def run_pairs(s: sets.ScanSet, method: str, max_pairs: int, warm: sets.ScanSet) -> dict:
    """Registers the set's pairs as captured and turned; per pair the errors and seconds."""
    register = pair_method(method, s)
    if method == "rpmnet_jax":  # every compilation align can meet (classical, network, global search)
        bench_utils.warm_align(warm.clouds[0], warm.clouds[1])
    register(warm.clouds[0], warm.clouds[1], None)  # first-call costs, on the tune part
    rows = []
    for k, (a, b) in enumerate(sets.pairs(s, max_pairs)):
        truth = np.linalg.inv(s.poses[b]) @ s.poses[a]
        for mode in ("captured", "turned"):
            src, motion = (s.clouds[a], np.eye(4)) if mode == "captured" else sets.turn(s.clouds[a], seed=k)
            origin = motion[:3, :3] @ s.origins[a] + motion[:3, 3]  # the source frame's origin, as given
            t0 = time.perf_counter()
            estimate = register(src, s.clouds[b], (origin, s.origins[b]) if s.sensors else None)
            seconds = time.perf_counter() - t0
            rot, trans = sets.errors(estimate, truth @ np.linalg.inv(motion), origin)
            rows.append({"pair": [s.names[a], s.names[b]], "mode": mode, "rotation_deg": rot,
                         "translation": trans, "seconds": seconds})
    return {"rows": rows}


def run_scans(s: sets.ScanSet, method: str, warm: sets.ScanSet, seed: int = 0) -> dict:
    """Registers the part's scans in a shuffled order; per scan the errors, and the seconds of the run."""
    from rpmnet_jax.evaluation import pose_errors
    order = np.random.default_rng(seed).permutation(len(s.names))
    clouds = [s.clouds[i] for i in order]
    if method == "rpmnet_jax_scans":
        import rpmnet_jax
        rpmnet_jax.align_scans(warm.clouds[:3])  # compilation, on the tune part
        # the sensors where they are known (Open3D's recipe gets them too), else the library's own rule
        viewpoints = [s.origins[i] for i in order] if s.sensors else "auto"
        t0 = time.perf_counter()
        poses = rpmnet_jax.align_scans(clouds, viewpoints=viewpoints).poses
    else:
        from rpmnet_jax.evaluation import baselines
        shift = clouds[0][0].copy() if s.kind == "georeferenced" else np.zeros(3)
        t0 = time.perf_counter()
        poses = sets.translation(shift) @ baselines.open3d_multiway([c - shift for c in clouds], s.voxel) @ \
            sets.translation(-shift)
    seconds = time.perf_counter() - t0
    errors = pose_errors.pose_errors(poses, s.poses[order], clouds)
    return {"seconds": seconds, "first": s.names[order[0]],  # the frame: its own errors are 0 by definition
            "rows": [{"scan": s.names[i], "rotation_deg": r, "translation": t}
                     for i, (r, t) in list(zip(order, errors))[1:]]}


def summary(record: dict) -> dict:
    """Success share, median errors and seconds (per pair, or per run) of one worker's ``rows``."""
    rows, extent = record["rows"], record["extent"]
    rot = np.array([r["rotation_deg"] for r in rows], float)
    trans = np.array([r["translation"] for r in rows], float)
    ok = (rot < MAX_ROTATION_DEG) & (trans < MAX_TRANSLATION_SHARE * extent)  # NaN (left out) counts as wrong
    out = {"n": len(rows), "success": float(np.mean(ok)) if len(rows) else float("nan"),
           "median_rotation_deg": float(np.nanmedian(rot)) if np.isfinite(rot).any() else float("nan"),
           "median_translation": float(np.nanmedian(trans)) if np.isfinite(trans).any() else float("nan")}
    if record["task"] == "pairs":
        out["seconds_per_pair"] = statistics.mean(r["seconds"] for r in rows)
        for mode in ("captured", "turned"):
            out[f"success_{mode}"] = float(np.mean([o for o, r in zip(ok, rows) if r["mode"] == mode]))
    else:
        out["seconds"] = record["seconds"]
    return out


def worker(a) -> None:
    s, warm = sets.load(a.set, a.part), sets.load(a.set, "tune" if a.part != "tune" else "report")
    if a.task == "scans" and len(s.names) > a.max_scans:
        s = sets.subset(s, np.round(np.linspace(0, len(s.names) - 1, a.max_scans)).astype(int))
    result = (run_pairs(s, a.method, a.max_pairs, warm) if a.task == "pairs" else run_scans(s, a.method, warm))
    record = {"set": s.name, "kind": s.kind, "part": a.part, "task": a.task, "method": a.method,
              "scans": len(s.names), "voxel": s.voxel, "extent": s.extent, **result,
              "peak_rss_mb": bench_utils.peak_rss_mb(), "commit": bench_utils.commit(), "versions": _versions(a.method),
              **bench_utils.environment()}
    record["summary"] = summary(record)
    print(json.dumps(record), flush=True)


def _versions(method: str) -> dict:
    """Versions of the libraries this method ran."""
    from importlib import metadata
    names = {"rpmnet_jax": ["jax"], "rpmnet_jax_scans": ["jax"], "open3d": ["open3d"], "open3d_multiway": ["open3d"],
             "kiss_small_gicp": ["kiss_matcher", "small_gicp"]}[method]
    return {n: metadata.version(n) for n in ["numpy", *names]}


def table(records: list) -> str:
    """The markdown table: one row per set and task, one column group per method."""
    lines = ["| set (kind) | task | method | success | median rot. ° | median transl. | s per pair / run | peak MB |",
             "|---|---|---|---|---|---|---|---|"]
    for r in records:
        if "error" in r:
            lines.append(f"| {r['set']} | {r['task']} | {r['method']} | error: {r['error'][:80]} | | | | |")
            continue
        m = r["summary"]
        time_cell = (f"{m['seconds_per_pair']:.2f}" if r["task"] == "pairs" else f"{m['seconds']:.1f}")
        lines.append(f"| {r['set']} ({r['kind']}, {r['scans']} scans) | {r['task']} ({m['n']}) | {r['method']} | "
                     f"{100 * m['success']:.0f}% | {m['median_rotation_deg']:.3f} | {m['median_translation']:.4g} | "
                     f"{time_cell} | {r['peak_rss_mb']:.0f} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--sets", default=None, help="comma-separated set names (default: every set and the grid one)")
    p.add_argument("--part", default="report", choices=("tune", "report", "all"))
    p.add_argument("--tasks", default="pairs,scans")
    p.add_argument("--methods", default=",".join(PAIR_METHODS + SCAN_METHODS))
    p.add_argument("--max-pairs", type=int, default=12, help="pairs per set (each as captured and turned)")
    p.add_argument("--max-scans", type=int, default=10, help="scans per scan set (evenly spaced in the part)")
    p.add_argument("--out-jsonl", default=None)
    p.add_argument("--out-md", default=None)
    p.add_argument("--table-from", default=None, help="only print (and --out-md) the table of this JSON-lines file")
    p.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--set", help=argparse.SUPPRESS)
    p.add_argument("--task", help=argparse.SUPPRESS)
    p.add_argument("--method", help=argparse.SUPPRESS)
    a = p.parse_args(argv)
    if a.worker:
        return worker(a)
    if a.table_from:
        with open(a.table_from) as f:
            records = [json.loads(line) for line in f if line.strip()]
        if a.out_md:
            with open(a.out_md, "w") as f:
                f.write(table(records))
        return print(table(records))
    names = a.sets.split(",") if a.sets else sets.available() + [
        n + "@grid" for n in sets.available() if sets.kind(n) == sets.GEOREFERENCED_FROM]
    if not names:
        raise SystemExit("no sets under benchmarks/real_scans/data")
    methods, records = a.methods.split(","), []
    for name in names:
        for task in a.tasks.split(","):
            for method in (m for m in methods if m in (PAIR_METHODS if task == "pairs" else SCAN_METHODS)):
                cmd = [sys.executable, os.path.abspath(__file__), "--worker", "--set", name, "--part", a.part,
                       "--task", task, "--method", method, "--max-pairs", str(a.max_pairs),
                       "--max-scans", str(a.max_scans)]
                records.append(bench_utils.run_worker(cmd, dict(os.environ), {"set": name, "task": task,
                                                                               "method": method}, a.out_jsonl))
    if a.out_md:
        with open(a.out_md, "w") as f:
            f.write(table(records))
    print(table(records), file=sys.stderr)


if __name__ == "__main__":
    main()
