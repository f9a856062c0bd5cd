"""Seconds per pair of the default :func:`rpmnet_jax.align` (``init="auto"``, ICP), stage by stage.

    python benchmarks/align_time.py --data-root ../shared/data/modelnet40_real_subset [--dataset noisy]
        [--points 1024] [--pairs 20] [--rot-mag 45] [--threads N]

Pairs: the first ``--pairs`` of the test file (``--split val``) in the given protocol, ``--points`` per cloud;
one warm-up pair pays for compilation and is not counted. Prints one JSON line: the median and the max of the
total, the median of each stage (``Alignment.timings``), how often each start won, the environment.
"""

from __future__ import annotations

import argparse

import bench_utils


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--data-root", required=True)
    p.add_argument("--dataset", default="noisy", choices=("clean", "noisy", "partial"))
    p.add_argument("--points", type=int, default=1024)
    p.add_argument("--pairs", type=int, default=20)
    p.add_argument("--rot-mag", type=float, default=45.0)
    p.add_argument("--threads", type=int, default=bench_utils.available_cpus(), help="CPUs to run on (default: all)")
    a = p.parse_args()
    bench_utils.pin(a.threads)
    import numpy as np
    from rpmnet_jax import data
    from rpmnet_jax.pairwise import alignment
    from rpmnet_jax.weights import loading

    ds = data.ModelNet40(a.data_root, "val", a.dataset, num_points=a.points, rot_mag=a.rot_mag)
    params = loading.load_params(None)
    runs = []
    for i in range(min(a.pairs + 1, len(ds))):
        s, r = (np.asarray(ds[i][k], np.float64) for k in ("points_src", "points_ref"))
        res = alignment.align(s[:, :3], r[:, :3], s[:, 3:6], r[:, 3:6], params=params,
                              num_points=max(len(s), len(r)))
        if i > 0:
            runs.append(res)
    stages = sorted({k for x in runs for k in x.timings})
    record = {"task": "align_default", "dataset": a.dataset, "points": a.points, "pairs": len(runs),
              "rot_mag": a.rot_mag,
              "seconds_median": float(np.median([x.timings["total"] for x in runs])),
              "seconds_max": float(np.max([x.timings["total"] for x in runs])),
              "stages_median": {k: float(np.median([x.timings.get(k, 0.0) for x in runs])) for k in stages},
              "starts_won": {k: sum(x.init == k for x in runs) for k in ("local", "classical", "global")}}
    bench_utils.emit({**record, **bench_utils.environment()})


if __name__ == "__main__":
    main()
