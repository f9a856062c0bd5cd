"""How much of the default :func:`rpmnet_jax.align`'s mean time per pair the network costs, and how little it would
cost with a perfect trigger: ``init="classical"`` (no network) and the default ``init="auto"`` on the same pairs,
same process, one after the other.

    python benchmarks/network_need.py --data-root ../shared/data/real_meshes_train [--dataset partial]
        [--rot-mag 180] [--pairs 160]

Pairs: the first ``--pairs`` of the test file (``--split val``), at the protocol's size (``num_points`` = the
larger cloud, as ``benchmarks/align_time.py``). A pair *needs* the network when its classical answer is more than
5° off. The bound is the mean time of a pipeline that runs the network exactly there: the classical time on every
pair plus, on the pairs that need it, the default's time instead. Prints one JSON line: per mode the mean and
median seconds, the share of answers within 5° and the median error; how many pairs ran the network's local start
and its global search; how many needed it and how many of those the default rescued; the bound. One warm-up pair
pays for compilation (both network paths) and is not counted. Run it with nothing else on the machine.
"""

from __future__ import annotations

import argparse
import time

import bench_utils

WRONG_DEG = 5.0


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    bench_utils.test_file_arguments(p, dataset="partial", pairs=160, rot_mag=180.0)
    a = p.parse_args()
    bench_utils.pin(a.threads)
    import numpy as np

    from rpmnet_jax import data
    from rpmnet_jax.ops import se3
    from rpmnet_jax.pairwise import alignment, options
    from rpmnet_jax.weights import loading

    ds = data.ModelNet40(a.data_root, "val", a.dataset, rot_mag=a.rot_mag)
    params = loading.load_params(None)
    rows = []  # per pair: (classical s, classical error, auto s, auto error, local ran, global ran)
    for i in range(min(a.pairs + 1, len(ds))):
        item = ds[i]
        s, r = (np.asarray(item[k], np.float64) for k in ("points_src", "points_ref"))
        gt = np.asarray(item["transform_gt"], np.float64)
        row = []
        for init in ("classical", "auto"):
            t0 = time.perf_counter()
            res = alignment.align(s[:, :3], r[:, :3], s[:, 3:6], r[:, 3:6], params=params, init=init,
                                  network_options=options.NetworkOptions(max(len(s), len(r))))
            row += [time.perf_counter() - t0, float(se3.rotation_angle_deg(res.transform[:3, :3] @ gt[:3, :3].T))]
        row += ["network" in res.stages, "global" in res.stages]
        if i == 0:  # warm-up: every compilation, the network's local and global paths too
            bench_utils.warm_align(s[:, :3], r[:, :3], s[:, 3:6], r[:, 3:6], params=params,
                                   num_points=max(len(s), len(r)))
            continue
        rows.append(row)
    t = np.array([[x[0], x[1], x[2], x[3]] for x in rows])
    need = t[:, 1] > WRONG_DEG
    summary = lambda sec, err: {"seconds_mean": float(sec.mean()), "seconds_median": float(np.median(sec)),
                                "share_within_5deg": float(np.mean(err <= WRONG_DEG)),
                                "error_deg_median": float(np.median(err))}
    record = {"task": "network_need", "set": a.data_root.rstrip("/").split("/")[-1], "dataset": a.dataset,
              "rot_mag": a.rot_mag, "pairs": len(rows), "classical": summary(t[:, 0], t[:, 1]),
              "auto": summary(t[:, 2], t[:, 3]), "local_runs": int(sum(x[4] for x in rows)),
              "global_runs": int(sum(x[5] for x in rows)), "need_network": int(need.sum()),
              "rescued": int(np.sum(need & (t[:, 3] <= WRONG_DEG))),
              "bound_seconds_mean": float((t[:, 0].sum() + (t[need, 2] - t[need, 0]).sum()) / len(rows))}
    bench_utils.emit({**record, **bench_utils.environment()})


if __name__ == "__main__":
    main()
