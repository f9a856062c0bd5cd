"""Wall seconds of the first ``rpmnet-register-scans`` after an install (empty Numba and XLA caches) against the
runs after it (both caches filled), each a fresh process, same scans.

    python benchmarks/cold_start.py FOLDER [--warm 2] [--repo PATH]

``FOLDER``: the scans (every point-cloud file in it, by name; e.g. ``python -m experiments.make_range_scans
--mesh ../shared/data/stanford_bunny/bun_zipper_res2.ply --scans 15 --seed 0 --shuffle --out scans15``).
``--repo``: the checkout whose code runs (default this one; another commit's ``git worktree`` for a before/after
on the same machine). A cold start is a fresh temporary folder for Numba's cache (``NUMBA_CACHE_DIR``) and for
XLA's (``RPMNET_COMPILATION_CACHE``); the warm runs reuse both. Prints one JSON line: ``cold_seconds``, each
warm run's seconds, ``ratio`` (cold over the fastest warm run) and each run's stage times as the CLI printed them.
"""

from __future__ import annotations

import argparse
import importlib.metadata
import json
import os
import re
import subprocess
import sys
import tempfile
import time

import bench_utils


def run_once(repo: str, folder: str, caches: str) -> dict:
    env = dict(os.environ, PYTHONPATH=repo, NUMBA_CACHE_DIR=os.path.join(caches, "numba"),
               RPMNET_COMPILATION_CACHE=os.path.join(caches, "xla"))
    cmd = [sys.executable, "-m", "rpmnet_jax.cli.register_scans", folder, "--out-poses",
           os.path.join(caches, "poses.conf")]
    t0 = time.perf_counter()
    done = subprocess.run(cmd, env=env, capture_output=True, text=True, cwd=caches)
    seconds = time.perf_counter() - t0
    if done.returncode:
        sys.exit(f"rpmnet-register-scans failed: {done.stderr.strip().splitlines()[-1:]}")
    stages = re.search(r"time [\d.]+ s \((.*)\)", done.stdout)
    return {"seconds": round(seconds, 2), "stages": stages.group(1).split("  ") if stages else None}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("folder")
    p.add_argument("--warm", type=int, default=2, help="warm runs after the cold one (default 2)")
    p.add_argument("--repo", default=bench_utils.REPO)
    a = p.parse_args()
    if a.warm < 1:
        p.error(f"--warm must be at least 1, got {a.warm}")
    folder, repo = os.path.abspath(a.folder), os.path.abspath(a.repo)
    with tempfile.TemporaryDirectory() as caches:
        cold = run_once(repo, folder, caches)
        warm = [run_once(repo, folder, caches) for _ in range(a.warm)]
    versions = {name: importlib.metadata.version(name) for name in ("numba", "jax")}
    print(json.dumps({"task": "cold_start", "commit": bench_utils.commit(repo), "set": os.path.basename(folder),
                      "scans": sum(1 for f in os.listdir(folder) if f.endswith((".ply", ".pcd", ".npy", ".xyz"))),
                      "cold_seconds": cold["seconds"], "warm_seconds": [w["seconds"] for w in warm],
                      "ratio": round(cold["seconds"] / min(w["seconds"] for w in warm), 2),
                      "cold_stages": cold["stages"], "warm_stages": [w["stages"] for w in warm],
                      **versions, **bench_utils.environment()}))


if __name__ == "__main__":
    main()
