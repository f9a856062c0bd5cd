"""Seconds per pair of the default :func:`rpmnet_jax.align` beside Open3D's recipe (``ransac_icp``, ``fgr_icp``),
same pairs, same process, one method after the other.

    python benchmarks/align_time.py --data-root ../shared/data/modelnet40_real_subset [--dataset noisy]
        [--points 1024] [--pairs 20] [--rot-mag 45] [--methods rpmnet_auto,ransac_icp,fgr_icp] [--threads N]

Pairs: the first ``--pairs`` of the test file (``--split val``) in the given protocol, ``--points`` per cloud;
one warm-up pair per method pays for compilation (ours: also once through the network's local and global paths) and is not counted. Prints one JSON line: per method the
median, mean and max seconds per pair and the median rotation error; for ours also the median of each stage
(``Alignment.timings``) and how often each start won; the ratio of our median to ``ransac_icp``'s; the
environment. Run it with nothing else on the machine.
"""

from __future__ import annotations

import argparse
import time

import bench_utils

OPEN3D = {"ransac_icp": "ransac", "fgr_icp": "fgr"}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    bench_utils.test_file_arguments(p, dataset="noisy", pairs=20, rot_mag=45.0)
    p.add_argument("--points", type=int, default=1024)
    p.add_argument("--methods", default="rpmnet_auto,ransac_icp,fgr_icp")
    a = p.parse_args()
    bench_utils.pin(a.threads)
    import numpy as np

    from rpmnet_jax import data
    from rpmnet_jax.ops import se3
    from rpmnet_jax.pairwise import alignment, options
    from rpmnet_jax.weights import loading

    ds = data.ModelNet40(a.data_root, "val", a.dataset, num_points=a.points, rot_mag=a.rot_mag)
    pairs = []
    for i in range(min(a.pairs + 1, len(ds))):
        item = ds[i]
        s, r = (np.asarray(item[k], np.float64) for k in ("points_src", "points_ref"))
        pairs.append((s, r, np.asarray(item["transform_gt"], np.float64)))
    record = {"task": "align_per_pair", "set": a.data_root.rstrip("/").split("/")[-1], "dataset": a.dataset,
              "points": a.points, "pairs": len(pairs) - 1, "rot_mag": a.rot_mag}
    params = loading.load_params(None)
    for method in a.methods.split(","):
        seconds, errors, runs = [], [], []
        for i, (s, r, gt) in enumerate(pairs):
            t0 = time.perf_counter()
            if method == "rpmnet_auto":
                res = alignment.align(s[:, :3], r[:, :3], s[:, 3:6], r[:, 3:6], params=params,
                                      network_options=options.NetworkOptions(max(len(s), len(r))))
                transform = res.transform
            else:
                from rpmnet_jax.evaluation import baselines

                transform = baselines.global_then_icp(s[None], r[None], OPEN3D[method])[0]
            elapsed = time.perf_counter() - t0
            if i == 0:  # warm-up: first imports and every compilation (the network's local and global paths too)
                if method == "rpmnet_auto":
                    bench_utils.warm_align(s[:, :3], r[:, :3], s[:, 3:6], r[:, 3:6], params=params,
                                           num_points=max(len(s), len(r)))
                continue
            seconds.append(elapsed)
            errors.append(float(se3.rotation_angle_deg(np.asarray(transform)[:3, :3] @ gt[:3, :3].T)))
            if method == "rpmnet_auto":
                runs.append(res)
        record[method] = {"seconds_median": float(np.median(seconds)), "seconds_mean": float(np.mean(seconds)),
                          "seconds_max": float(np.max(seconds)), "error_deg_median": float(np.median(errors))}
        if runs:
            stages = sorted({k for x in runs for k in x.timings if k != "total"})
            record[method]["stages_median"] = {k: float(np.median([x.timings.get(k, 0.0) for x in runs]))
                                               for k in stages}
            record[method]["starts_won"] = {k: sum(x.init == k for x in runs) for k in ("local", "classical", "global")}
    if "rpmnet_auto" in record and "ransac_icp" in record:
        record["ratio_to_ransac_icp"] = {k: record["rpmnet_auto"][k] / record["ransac_icp"][k]
                                         for k in ("seconds_median", "seconds_mean")}
    bench_utils.emit({**record, **bench_utils.environment()})


if __name__ == "__main__":
    main()
