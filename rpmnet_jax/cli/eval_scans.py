"""Evaluate on real range scans with ground-truth poses: the Stanford bunny (``bun.conf`` layout).

    python -m experiments.eval_scans --scans PATH/stanford_bunny [--methods rpmnet,icp,fgr,rpm,identity]

Each pair ``A:B`` registers scan A onto scan B. Both go through the same preparation as ``rpmnet-register``
(each centred on its centroid, one common scale into the unit sphere, ``--num-points`` random points,
PCA normals); every method registers the prepared pair and its answer is mapped back to metres. The ground
truth is ``T_B^-1 T_A`` with ``T_X = [[R_X^T, t_X], [0, 1]]`` from the ``bmesh`` lines. Prints a table and
writes ``--output`` (JSON with per-pair errors).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

import numpy as np

DEFAULT_PAIRS = "bun045:bun000,bun090:bun045,bun000:bun315,bun315:bun270,bun180:bun090,bun270:bun180"


def read_poses(conf_path: str) -> dict:
    """``{scan name: 4x4 pose}`` from a Stanford ``.conf`` file (``bmesh NAME tx ty tz qx qy qz qw``)."""
    from scipy.spatial.transform import Rotation
    poses = {}
    with open(conf_path) as f:
        for line in f:
            parts = line.split()
            if len(parts) == 9 and parts[0] == "bmesh":
                t, q = np.array(parts[2:5], float), np.array(parts[5:9], float)
                pose = np.eye(4)
                pose[:3, :3] = Rotation.from_quat(q).as_matrix().T
                pose[:3, 3] = t
                poses[os.path.splitext(parts[1])[0]] = pose
    if not poses:
        raise ValueError(f"no 'bmesh' lines in {conf_path}")
    return poses


def errors(pred: np.ndarray, gt: np.ndarray) -> tuple[float, float]:
    """Isotropic rotation error (degrees) and translation error (units of the input) of 4x4 transforms."""
    residual = np.linalg.inv(gt) @ pred
    cos = np.clip((np.trace(residual[:3, :3]) - 1) / 2, -1.0, 1.0)
    return float(np.degrees(np.arccos(cos))), float(np.linalg.norm(residual[:3, 3]))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scans", required=True, help="folder with the scans (.ply) and bun.conf")
    p.add_argument("--conf", default="bun.conf", help="pose file inside --scans")
    p.add_argument("--pairs", default=DEFAULT_PAIRS, help="comma-separated SRC:REF scan names")
    p.add_argument("--methods", default="rpmnet,icp,fgr,rpm,identity")
    p.add_argument("--checkpoint", default=None, help="weights for rpmnet (default: shipped model)")
    p.add_argument("--num-points", type=int, default=1024)
    p.add_argument("--iters", type=int, default=5)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--output", default=None, help="write the per-pair results as JSON")
    a = p.parse_args(argv)

    from rpmnet_jax.evaluation import protocol
    from rpmnet_jax.scans import alignment
    from rpmnet_jax.scans import cloud_io
    from rpmnet_jax.weights import loading
    try:
        poses = read_poses(os.path.join(a.scans, a.conf))
        pairs = [tuple(x.split(":")) for x in a.pairs.split(",") if x]
        if any(len(x) != 2 or x[0] not in poses or x[1] not in poses for x in pairs):
            raise ValueError(f"--pairs must be SRC:REF names from {sorted(poses)}")
        params = loading.load_params(a.checkpoint) if "rpmnet" in a.methods.split(",") else None
    except (ValueError, FileNotFoundError, OSError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    methods = {}
    for name in a.methods.split(","):
        try:
            methods[name] = protocol.method_fn(name, params, num_iters=a.iters)
        except RuntimeError as e:
            print(f"{name}: skipped ({e})", file=sys.stderr)

    results = []
    for src_name, ref_name in pairs:
        src, src_n = cloud_io.read_cloud(os.path.join(a.scans, src_name + ".ply"))
        ref, ref_n = cloud_io.read_cloud(os.path.join(a.scans, ref_name + ".ply"))
        pair = alignment.prepare_pair(src, ref, src_n, ref_n, num_points=a.num_points, seed=a.seed)
        gt = np.linalg.inv(poses[ref_name]) @ poses[src_name]
        size = float(np.linalg.norm(src.max(0) - src.min(0)))
        row = {"pair": f"{src_name}:{ref_name}", "gt_rotation_deg": errors(gt, np.eye(4))[0], "size": size}
        for name, fn in methods.items():
            t0 = time.perf_counter()
            t_unit = np.asarray(fn(pair.src6, pair.ref6))[0, -1]
            seconds = time.perf_counter() - t0
            err_r, err_t = errors(pair.to_callers_units(t_unit), gt)
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
    runtime.use_huge_pages()
    sys.exit(main())


if __name__ == "__main__":
    entry()
