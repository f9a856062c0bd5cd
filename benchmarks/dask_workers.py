"""A scan campaign through a real Dask cluster on this machine: one ``dask worker`` against two (or any counts),
end to end, stage by stage, with the same poses.

    python benchmarks/dask_workers.py SET [--conf truth.conf] [--workers 1,2] [--units m] [--out-jsonl results.jsonl]

``SET``: a folder of scans and their true poses (``python -m experiments.make_range_scans`` or
``experiments.make_site``). For each worker count a ``dask scheduler`` process and that many ``dask worker``
processes start (one thread each, their Numba, BLAS and XLA pools sized to it:
:func:`rpmnet_jax.pair_edges.pair_engine.worker_environment`), then ``benchmarks/campaign_time.py``'s own side
reads the scans and runs :func:`rpmnet_jax.align_scans` with ``scheduler=`` the address, in a fresh process; the
cluster stops after each count. One JSON line per count: seconds (reading and registration), seconds per stage
(``ScanAlignment.timings``), the caller's peak resident memory and each worker's, the scans within 0.5° and 1 mm of
the truth; then one line with each count's speed-up over the first, end to end and per stage, and the largest
rotation (°) and translation between its poses and the first count's.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time

import bench_utils
import campaign_time

CAMPAIGN = os.path.join(os.path.dirname(os.path.abspath(__file__)), "campaign_time.py")


class Processes:
    """A ``dask scheduler`` and ``workers`` ``dask worker`` processes of one thread each, on this machine."""

    def __init__(self, workers: int, folder: str):
        from rpmnet_jax.pair_edges import pair_engine

        bin_dir, file = os.path.dirname(sys.executable), os.path.join(folder, "scheduler.json")
        env = dict(os.environ, JAX_PLATFORMS="cpu", **pair_engine.worker_environment(1))
        quiet = {"stdout": subprocess.DEVNULL, "stderr": subprocess.DEVNULL, "env": env}
        self.procs = [subprocess.Popen([os.path.join(bin_dir, "dask"), "scheduler", "--host", "127.0.0.1", "--port",
                                        "0", "--no-dashboard", "--scheduler-file", file], **quiet)]
        try:  # a scheduler or worker that does not come up leaves no process behind
            deadline = time.time() + 60
            while not os.path.exists(file) and time.time() < deadline:
                time.sleep(0.1)
            time.sleep(0.2)  # the file is written whole, then read
            self.address = json.load(open(file))["address"]
            self.procs += [subprocess.Popen([os.path.join(bin_dir, "dask"), "worker", "--nthreads", "1", "--no-nanny",
                                             "--no-dashboard", "--name", f"w{k}", "--scheduler-file", file], **quiet)
                           for k in range(workers)]
            with self.client() as client:
                client.wait_for_workers(workers, timeout=120)
        except BaseException:
            self.close()
            raise

    def client(self):
        import distributed

        return distributed.Client(self.address, timeout="30s")

    def worker_peaks_mb(self) -> list:
        """Each worker's peak resident memory, MiB."""
        with self.client() as client:
            return sorted(client.run(_peak_rss_mb).values())

    def close(self) -> None:
        for p in self.procs[::-1]:
            p.kill()
            p.wait(timeout=30)


def _peak_rss_mb() -> float:
    """In a worker (``client.run``; this script's functions travel by value, ``bench_utils`` is not there):
    :func:`bench_utils.peak_rss_mb`."""
    import resource

    return round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)  # KiB on Linux


def largest_difference(a, b) -> tuple:
    """``(degrees, distance)``: the largest rotation and translation between ``a`` and ``b (S, 4, 4)`` over the
    scans placed in both."""
    import numpy as np

    from rpmnet_jax.ops import se3

    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    both = np.isfinite(a[:, 0, 0]) & np.isfinite(b[:, 0, 0])
    if not both.any():
        return float("nan"), float("nan")
    degrees = [se3.rotation_angle_deg(ra[:3, :3].T @ rb[:3, :3]) for ra, rb in zip(a[both], b[both])]
    return float(max(degrees)), float(np.linalg.norm(a[both, :3, 3] - b[both, :3, 3], axis=1).max())


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("set", help="folder of scans and their .conf")
    p.add_argument("--conf", default="truth.conf", help="true poses inside SET (default truth.conf)")
    p.add_argument("--workers", default="1,2", help="worker counts, comma-separated (default 1,2)")
    p.add_argument("--units", choices=("m", "mm"), default="m", help="the scans' units (errors are stated in mm)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out-jsonl", default=None, help="append the JSON lines to this file")
    a = p.parse_args(argv)
    from rpmnet_jax.io import clouds as cloud_io

    counts = [int(c) for c in a.workers.split(",") if c]
    names, paths, truth = campaign_time.scan_files(a.set, a.conf)
    clouds = [cloud_io.read_cloud(path)[0] for path in paths]
    base = {"task": "dask_workers", "set": os.path.basename(os.path.normpath(a.set)), "scans": len(names),
            "commit": bench_utils.commit(), **bench_utils.session("dask_workers.py", argv, bench_utils.available_cpus(),
                                                                  "default")}
    runs = []
    for count in counts:
        folder = tempfile.mkdtemp(prefix="dask_workers_")
        cluster = Processes(count, folder)
        try:
            out = campaign_time.child_run(CAMPAIGN, [a.set, "--conf", a.conf, "--seed", str(a.seed), "--scheduler",
                                                     cluster.address], "ours")
            out["worker_peak_rss_mb"] = cluster.worker_peaks_mb()
        finally:
            cluster.close()
            shutil.rmtree(folder, ignore_errors=True)
        record = dict(base, workers=count, **out)
        if "error" not in out:
            poses = record.pop("poses")
            record.update({k: v for k, v in campaign_time.score(poses, truth, clouds, 1000.0 if a.units == "m"
                                                                else 1.0).items() if k not in ("rotation_deg", "rms")})
            runs.append((count, poses, record))
        bench_utils.emit(record, a.out_jsonl)
    if len(runs) >= 2:
        (first, first_poses, one), rest = runs[0], runs[1:]
        for count, poses, other in rest:
            degrees, distance = largest_difference(first_poses, poses)
            stages = {k: round(one["timings"][k] / other["timings"][k], 3) for k in one["timings"]
                      if other["timings"].get(k)}
            bench_utils.emit({"task": "dask_workers_speedup", "set": base["set"], "workers": [first, count],
                              "seconds_speedup": one["seconds"] / other["seconds"],
                              "process_seconds_speedup": one["process_seconds"] / other["process_seconds"],
                              "stage_speedups": stages, "largest_pose_difference_deg": degrees,
                              "largest_pose_difference": distance, "target_speedup": 1.6}, a.out_jsonl)
    return 0 if len(runs) == len(counts) else 1


if __name__ == "__main__":
    sys.exit(main())
