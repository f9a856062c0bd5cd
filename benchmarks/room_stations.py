"""A room scanned from six terrestrial-scanner stations (``rpmnet_jax.simulation.rooms``: 10 × 7 × 3 m, columns,
furniture, a door recess, 3 mm noise, each station in its own frame with a random heading): the 15 station pairs
by ``rpmnet_jax.align``, Open3D's scan recipe and KISS-Matcher + small_gicp (5 cm voxel, Open3D's room
tutorials; normals toward the sensor for Open3D), and the six stations in shuffled order by
``rpmnet_jax.align_scans`` and Open3D's multiway recipe (order-free), one JSON line per method.

A pair is right within 1° and 5 cm (measured at the source station); a rectangular room is nearly symmetric under
a half turn, so a wrong answer is mostly that flip. ``likely_wrong`` flags are counted on right and wrong answers.

    python benchmarks/room_stations.py [--methods rpmnet_jax,open3d,kiss_small_gicp,rpmnet_jax_scans,open3d_multiway]
        [--seed 0] [--step 0.6]

``--step``: the scanner's angular step in degrees (0.6: 150,000 points a station; 0.3: ~600,000; 0.165: ~2,000,000),
for how time and peak memory grow with the points per scan.
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import subprocess
import sys
import time

import numpy as np

import bench_utils

VOXEL = 0.05  # Open3D's registration tutorials on RGB-D fragments of rooms
RIGHT_DEG, RIGHT_M = 1.0, 0.05
PAIR_METHODS = ("rpmnet_jax", "open3d", "kiss_small_gicp")
SCAN_METHODS = ("rpmnet_jax_scans", "open3d_multiway")


def _errors(estimate, truth) -> tuple:
    """(rotation °, translation at the source station's sensor) of ``estimate`` against ``truth``."""
    from rpmnet_jax.ops import se3
    d = np.linalg.inv(truth) @ estimate
    return float(se3.rotation_angle_deg(d[:3, :3])), float(np.linalg.norm(d[:3, 3]))


def run(method: str, seed: int, step: float) -> dict:
    from rpmnet_jax.simulation import rooms
    stations = rooms.stations(seed, step)
    clouds, poses = [s.points for s in stations], np.stack([s.pose for s in stations])
    rows = []
    if method in PAIR_METHODS:
        from rpmnet_jax.evaluation import baselines
        import rpmnet_jax
        register = {"rpmnet_jax": lambda a, b: rpmnet_jax.align(a, b),
                    "open3d": lambda a, b: baselines.open3d_scan_pair(a, b, VOXEL, viewpoints=(np.zeros(3),) * 2),
                    "kiss_small_gicp": lambda a, b: baselines.kiss_small_gicp_pair(a, b, VOXEL)}[method]
        if method == "rpmnet_jax":
            bench_utils.warm_align(clouds[0], clouds[1])
        register(clouds[0], clouds[1])  # first-call costs
        for a, b in itertools.combinations(range(len(clouds)), 2):
            t0 = time.perf_counter()
            answer = register(clouds[a], clouds[b])
            seconds = time.perf_counter() - t0
            estimate = answer.transform if hasattr(answer, "transform") else answer
            rot, trans = _errors(estimate, np.linalg.inv(poses[b]) @ poses[a])
            rows.append({"pair": [a, b], "rotation_deg": rot, "translation": trans, "seconds": seconds,
                         "likely_wrong": bool(getattr(answer, "likely_wrong", False)),
                         "p_wrong": float(getattr(answer, "p_wrong", float("nan")))})
        right = [r["rotation_deg"] <= RIGHT_DEG and r["translation"] <= RIGHT_M for r in rows]
        summary = {"right": f"{sum(right)}/{len(rows)}", "seconds_per_pair": float(np.mean([r["seconds"] for r in rows])),
                   "flagged_wrong": f"{sum(r['likely_wrong'] for r, ok in zip(rows, right) if not ok)}/"
                                    f"{len(rows) - sum(right)}",
                   "flagged_right": f"{sum(r['likely_wrong'] for r, ok in zip(rows, right) if ok)}/{sum(right)}"}
    else:
        order = np.random.default_rng(seed).permutation(len(clouds))
        shuffled = [clouds[i] for i in order]
        t0 = time.perf_counter()
        if method == "rpmnet_jax_scans":
            import rpmnet_jax
            result = rpmnet_jax.align_scans(shuffled)  # viewpoints "auto": each station surrounds its origin
            estimate, named = result.poses, set(result.likely_wrong) | set(result.left_out)
        else:
            from rpmnet_jax.evaluation import baselines
            estimate, named = baselines.open3d_multiway(shuffled, VOXEL), set()
        seconds = time.perf_counter() - t0
        truth = np.linalg.inv(poses[order[0]]) @ poses[order]
        for k in range(1, len(order)):
            rot, trans = _errors(estimate[k], truth[k]) if np.all(np.isfinite(estimate[k])) else (np.nan, np.nan)
            rows.append({"station": int(order[k]), "rotation_deg": rot, "translation": trans, "named": k in named})
        right = [r["rotation_deg"] <= RIGHT_DEG and r["translation"] <= RIGHT_M for r in rows]
        summary = {"right": f"{sum(right)}/{len(rows)}", "seconds": seconds,
                   "silently_wrong": sum(not ok and not r["named"] for r, ok in zip(rows, right))}
    return {"benchmark": "room_stations", "method": method, "seed": seed, "step_deg": step,
            "points": [len(c) for c in clouds], "input_mb": sum(c.nbytes for c in clouds) / 2 ** 20,
            "summary": summary, "rows": rows, "peak_rss_mb": bench_utils.peak_rss_mb(),
            "commit": bench_utils.commit(), **bench_utils.environment()}


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--methods", default=",".join(PAIR_METHODS + SCAN_METHODS))
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--step", type=float, default=None, help="angular step, degrees (default the simulator's 0.6)")
    p.add_argument("--worker", default=None, help=argparse.SUPPRESS)
    a = p.parse_args(argv)
    if a.worker:
        from rpmnet_jax.simulation import rooms
        return print(json.dumps(run(a.worker, a.seed, a.step or rooms.STEP_DEG)), flush=True)
    unknown = [m for m in a.methods.split(",") if m not in PAIR_METHODS + SCAN_METHODS]
    if unknown:
        p.error(f"unknown methods {unknown}; choose among {','.join(PAIR_METHODS + SCAN_METHODS)}")
    for method in a.methods.split(","):  # each method in a process of its own: its own imports, its own peak
        step = [] if a.step is None else ["--step", str(a.step)]
        subprocess.run([sys.executable, os.path.abspath(__file__), "--worker", method, "--seed", str(a.seed)] + step,
                       check=False)


if __name__ == "__main__":
    main()
