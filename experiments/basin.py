"""The network's basin: registration error against the size of the initial rotation.

    python -m experiments.basin --data-root PATH/modelnet40_ply_hdf5_2048 --pairs 48 --out basin.json

Pairs of the protocol's deterministic split (``--split val``: test files) with their rotation replaced by
one of a fixed angle about a random axis (translation, crop and noise as the protocol draws them). Prints,
per angle, the median and the share of pairs under 5° of the network alone (``refine="none"``): the basin
``init="global"`` must cover with its rotation hypotheses.
"""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np


def _rotation(axis: np.ndarray, deg: float) -> np.ndarray:
    from scipy.spatial.transform import Rotation
    return Rotation.from_rotvec(np.radians(deg) * axis / np.linalg.norm(axis)).as_matrix()


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--data-root", required=True)
    p.add_argument("--dataset", default="partial", choices=("clean", "noisy", "partial"))
    p.add_argument("--split", default="val", choices=("val", "test"))
    p.add_argument("--pairs", type=int, default=48)
    p.add_argument("--angles", default="0,15,30,45,60,75,90,120,150,180")
    p.add_argument("--checkpoint", default=None)
    p.add_argument("--num-points", type=int, default=1024)
    p.add_argument("--out", default=None)
    a = p.parse_args(argv)

    from rpmnet_jax import data, registration
    from rpmnet_jax import metrics
    from rpmnet_jax.weights import loading

    ds = data.ModelNet40(a.data_root, a.split, a.dataset, num_points=a.num_points, rot_mag=0.0)
    idx = np.linspace(0, len(ds) - 1, min(a.pairs, len(ds))).astype(int)
    params = loading.load_params(a.checkpoint)
    fn = registration.jitted(field="transforms")
    rng = np.random.default_rng(0)
    axes = rng.normal(size=(len(idx), 3))
    rows = []
    for angle in [float(x) for x in a.angles.split(",")]:
        errs = []
        for k, i in enumerate(idx):
            s = ds[int(i)]
            rot = _rotation(axes[k], angle)
            src = s["points_src"].copy()
            src[:, :3] = src[:, :3] @ rot.T
            src[:, 3:] = src[:, 3:] @ rot.T
            gt = s["transform_gt"].astype(np.float64)
            gt = np.concatenate([gt[:, :3] @ rot.T, gt[:, 3:]], axis=1)  # maps the rotated source
            pred = np.asarray(fn(params, src[None], s["points_ref"][None])[-1])
            m = metrics.registration_metrics(pred, gt[None], src[None], s["points_ref"][None], s["points_raw"][None])
            errs.append(float(m["err_r_deg"][0]))
        errs = np.array(errs)
        rows.append({"angle_deg": angle, "median_err_deg": float(np.median(errs)),
                     "under_5deg": float(np.mean(errs < 5)), "under_10deg": float(np.mean(errs < 10))})
        print(json.dumps(rows[-1]), flush=True)
    if a.out:
        with open(a.out, "w") as f:
            json.dump({"pairs": len(idx), "dataset": a.dataset, "rows": rows}, f, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
