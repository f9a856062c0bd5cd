"""Evaluate on real range scans with ground-truth poses: the Stanford bunny (``bun.conf`` layout).

    python -m experiments.eval_scans --scans PATH/stanford_bunny [--methods rpmnet,icp,fgr,rpm,identity]

Each pair ``A:B`` registers scan A onto scan B. Both go through the same preparation as ``rpmnet-register``
(each centred on its centroid, one common scale into the unit sphere, ``--num-points`` random points,
PCA normals); every method registers the prepared pair and its answer is mapped back to metres. The ground
truth is ``T_B^-1 T_A`` with ``T_X = [[R_X^T, t_X], [0, 1]]`` from the ``bmesh`` lines. Prints a table and
writes ``--output`` (JSON with per-pair errors). The pipeline methods (``rpmnet_icp``, ``rpmnet_auto``,
``rpmnet_global``) run :func:`rpmnet_jax.align` on the full scans, exactly as ``rpmnet-register`` does.

    python -m experiments.eval_scans --scans PATH/stanford_bunny --multiway [--plot merged.png]

``--multiway`` registers all scans of the ``.conf`` (in its order) into the first one's frame with
:func:`rpmnet_jax.align_scans` and with Open3D's multiway recipe (:func:`rpmnet_jax.evaluation.baselines.open3d_multiway`)
in the same run, and prints per scan the rotation error (°) of its pose relative to the first scan and the
RMS displacement (mm, for scans in metres) of its points from their true place, and each method's time.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

import numpy as np

DEFAULT_PAIRS = "bun045:bun000,bun090:bun045,bun000:bun315,bun315:bun270,bun180:bun090,bun270:bun180"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scans", required=True, help="folder with the scans (.ply) and bun.conf")
    p.add_argument("--conf", default="bun.conf", help="pose file inside --scans")
    p.add_argument("--pairs", default=DEFAULT_PAIRS, help="comma-separated SRC:REF scan names")
    p.add_argument("--methods", default="rpmnet,rpmnet_auto,rpmnet_global,ransac_icp,fgr_icp,fgr,icp,identity",
                   help="rpmnet (the network alone), rpmnet_icp / rpmnet_auto / rpmnet_global (rpmnet-register's "
                        "pipeline with a local, automatic or global start, ICP-refined on the full scans), ransac_icp / fgr_icp (Open3D: FPFH + RANSAC or FGR, then point-to-plane ICP), icp, fgr, "
                        "rpm, identity")
    p.add_argument("--checkpoint", default=None, help="weights for rpmnet (default: shipped model)")
    p.add_argument("--num-points", type=int, default=1024)
    p.add_argument("--iters", type=int, default=5)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--output", default=None, help="write the per-pair results as JSON")
    p.add_argument("--multiway", action="store_true", help="register all scans together (see above)")
    p.add_argument("--multiway-methods", default="rpmnet_multiway,open3d_multiway",
                   help="with --multiway: rpmnet_multiway (align_scans), open3d_multiway (Open3D's recipe)")
    p.add_argument("--baseline-voxel", type=float, default=0.002,
                   help="with --multiway: voxel size of Open3D's recipe in the scans' units (default 0.002: 2 mm)")
    p.add_argument("--repeat", type=int, default=1, help="with --multiway: runs of each method (times of each kept)")
    p.add_argument("--plot", default=None, help="with --multiway: PNG of the merged scans of each method, by scan")
    a = p.parse_args(argv)
    if a.multiway:
        from rpmnet_jax.cli import eval_multiway
        return eval_multiway.run(a)

    from rpmnet_jax import metrics
    from rpmnet_jax.evaluation import protocol
    from rpmnet_jax.io import clouds as cloud_io, poses as poses_io
    from rpmnet_jax.pairwise import alignment, options, prepare
    from rpmnet_jax.weights import loading
    try:
        poses = poses_io.read_poses(os.path.join(a.scans, a.conf))
        pairs = [tuple(x.split(":")) for x in a.pairs.split(",") if x]
        if any(len(x) != 2 or x[0] not in poses or x[1] not in poses for x in pairs):
            raise ValueError(f"--pairs must be SRC:REF names from {sorted(poses)}")
        names = [m for m in a.methods.split(",") if m]
        unknown = [m for m in names if m not in protocol.METHODS]
        if unknown:
            raise ValueError(f"unknown methods {unknown}; choose from {','.join(protocol.METHODS)}")
        params = loading.load_params(a.checkpoint) if any(m in protocol.NETWORK_METHODS for m in names) else None
    except (ValueError, FileNotFoundError, OSError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    methods = {}
    for name in names:
        if name in protocol.PIPELINES:  # the whole pipeline, on the full scans
            methods[name] = None
            continue
        try:
            methods[name] = protocol.method_fn(name, params, num_iters=a.iters)
        except RuntimeError as e:
            print(f"{name}: skipped ({e})", file=sys.stderr)

    results = []
    for src_name, ref_name in pairs:
        src, src_n = cloud_io.read_cloud(os.path.join(a.scans, src_name + ".ply"))
        ref, ref_n = cloud_io.read_cloud(os.path.join(a.scans, ref_name + ".ply"))
        pair = prepare.prepare_pair(src, ref, src_n, ref_n, num_points=a.num_points, seed=a.seed)
        gt = poses_io.relative_motion(poses, src_name, ref_name)
        size = float(np.linalg.norm(src.max(0) - src.min(0)))
        row = {"pair": f"{src_name}:{ref_name}", "gt_rotation_deg": metrics.transform_errors(gt, np.eye(4))[0],
               "size": size}
        for name, fn in methods.items():
            t0 = time.perf_counter()
            if fn is None:
                network = options.NetworkOptions(points=a.num_points, iters=a.iters)
                result = alignment.align(src, ref, src_n, ref_n, params=params, network_options=network, seed=a.seed,
                                         **protocol.PIPELINES[name])
                pred = result.transform
            else:
                pred = pair.to_callers_units(np.asarray(fn(pair.src6, pair.ref6))[0, -1])
            seconds = time.perf_counter() - t0
            err_r, err_t = metrics.transform_errors(pred, gt)
            row[name] = {"err_r_deg": err_r, "err_t": err_t, "seconds": seconds}
        results.append(row)

    names = list(methods)
    print(f"{'pair':<16} {'GT rot':>7} | " + " | ".join(f"{n + ' deg/mm':>18}" for n in names))
    for r in results:
        cells = [f"{r[n]['err_r_deg']:>8.2f} / {1000 * r[n]['err_t']:>7.2f}" for n in names]
        print(f"{r['pair']:<16} {r['gt_rotation_deg']:>7.1f} | " + " | ".join(f"{c:>18}" for c in cells))
    summary = {n: {"err_r_deg_median": float(np.median([r[n]["err_r_deg"] for r in results])),
                   "err_t_median": float(np.median([r[n]["err_t"] for r in results])),
                   "success_5deg": float(np.mean([r[n]["err_r_deg"] < 5 for r in results]))} for n in names}
    print(json.dumps(summary))
    if a.output:
        with open(a.output, "w") as f:
            json.dump({"pairs": results, "summary": summary, "num_points": a.num_points}, f, indent=2)
    return 0


def entry() -> None:
    """Console script ``rpmnet-eval-scans``."""
    from rpmnet_jax.cli import runtime
    runtime.run(main)


if __name__ == "__main__":
    entry()
