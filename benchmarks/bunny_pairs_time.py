"""Seconds per Stanford bunny pair: the default :func:`rpmnet_jax.align` on the full scans beside Open3D's recipe on
the 1,024-point samples ``rpmnet-eval-scans`` prepares (``ransac_icp``) and Open3D's scan recipe on the full scans
(voxel 2 mm first, :func:`rpmnet_jax.evaluation.baselines.open3d_scan_pair`), KISS-Matcher + small_gicp on the
full scans (the same voxel, :func:`~rpmnet_jax.evaluation.baselines.kiss_small_gicp_pair`), and the default ``align``
on the same 1,024-point samples (with their normals) as ``ransac_icp`` (``rpmnet_auto_samples``), same process, one
after the other. The full-scan methods compare with each other, the sample methods with each other.

    python benchmarks/bunny_pairs_time.py [--scans ../shared/data/stanford_bunny] [--repeats 3] [--voxel 0.002]

One warm-up (compilation: the network's local and global paths, Numba, Open3D) is not counted. Prints one JSON line
per pair: per method the median seconds of ``--repeats`` runs and the rotation (degrees) and translation (caller's
units) errors against ``bun.conf``. Run it with nothing else on the machine.
"""

from __future__ import annotations

import argparse
import os
import time

import bench_utils

PAIRS = "bun045:bun000,bun090:bun045,bun000:bun315,bun315:bun270,bun180:bun090,bun270:bun180"


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scans", default="../shared/data/stanford_bunny")
    p.add_argument("--pairs", default=PAIRS)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--voxel", type=float, default=0.002, help="Open3D scan recipe's voxel (metres)")
    a = p.parse_args()
    import numpy as np

    from rpmnet_jax import metrics
    from rpmnet_jax.evaluation import baselines, protocol
    from rpmnet_jax.io import clouds as cloud_io, poses as poses_io
    from rpmnet_jax.pairwise import alignment, prepare
    from rpmnet_jax.weights import loading

    truth = poses_io.read_poses(os.path.join(a.scans, "bun.conf"))
    pairs = [tuple(x.split(":")) for x in a.pairs.split(",") if x]
    clouds = {n: cloud_io.read_cloud(os.path.join(a.scans, n + ".ply"))[0] for pair in pairs for n in pair}
    params = loading.load_params(None)
    ransac = protocol.method_fn("ransac_icp", params)
    first_src, first_ref = (clouds[n] for n in pairs[0])
    bench_utils.warm_align(first_src, first_ref, params=params)  # warm-up: every compilation
    baselines.open3d_scan_pair(first_src, first_ref, a.voxel)
    baselines.kiss_small_gicp_pair(first_src, first_ref, a.voxel)
    for src_name, ref_name in pairs:
        src, ref = clouds[src_name], clouds[ref_name]
        gt = poses_io.relative_motion(truth, src_name, ref_name)
        pair = prepare.prepare_pair(src, ref, None, None, num_points=1024, seed=0)
        s6, r6 = (np.asarray(x[0], np.float64) for x in (pair.src6, pair.ref6))  # the samples, unit-sphere frame
        methods = {"rpmnet_auto": lambda: alignment.align(src, ref, params=params).transform,
                   "rpmnet_auto_samples": lambda: pair.to_callers_units(alignment.align(
                       s6[:, :3], r6[:, :3], s6[:, 3:], r6[:, 3:], params=params).transform[:3]),
                   "ransac_icp": lambda: pair.to_callers_units(np.asarray(ransac(pair.src6, pair.ref6))[0, -1]),
                   "open3d_scan_pair": lambda: baselines.open3d_scan_pair(src, ref, a.voxel),
                   "kiss_small_gicp": lambda: baselines.kiss_small_gicp_pair(src, ref, a.voxel)}
        record = {"task": "bunny_pair", "pair": f"{src_name}:{ref_name}"}
        for name, fn in methods.items():
            seconds = []
            for _ in range(a.repeats):
                t0 = time.perf_counter()
                transform = fn()
                seconds.append(time.perf_counter() - t0)
            err_r, err_t = metrics.transform_errors(np.asarray(transform), gt)
            record[name] = {"seconds_median": float(np.median(seconds)), "err_r_deg": float(err_r),
                            "err_t": float(err_t)}
        bench_utils.emit(record)


if __name__ == "__main__":
    main()
