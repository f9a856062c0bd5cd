"""Registration metrics of the paper (official names), host-side NumPy/SciPy."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from rpmnet_jax.ops import se3


def _xyz(points) -> np.ndarray:
    return np.asarray(points, np.float64)[..., :3]


def euler_xyz_deg(rot) -> np.ndarray:
    """Extrinsic ``xyz`` Euler angles in degrees of rotation matrices ``(B, 3, 3)``."""
    return Rotation.from_matrix(np.asarray(rot, np.float64)).as_euler("xyz", degrees=True)


def _mean_min_sq_dist(query, target) -> float:
    dist, _ = cKDTree(target).query(query, k=1)
    return float(np.mean(dist**2))


def registration_metrics(pred, gt, points_src, points_ref, points_raw) -> dict:
    """Per-pair metrics ``(B,)``: ``r_mse, r_mae`` (Euler xyz, deg), ``t_mse, t_mae``, ``err_r_deg``,
    ``err_t`` (isotropic) and ``chamfer_dist`` (the paper's modified Chamfer distance against the clean
    cloud ``points_raw``).

    Args:
      pred, gt: ``(B, 3, 4)`` transforms mapping source onto reference.
      points_src, points_ref, points_raw: ``(B, ·, 3)`` or ``(B, ·, 6)`` (xyz used).
    """
    pred, gt = np.asarray(pred, np.float64), np.asarray(gt, np.float64)
    if pred.shape != gt.shape or pred.shape[-2:] != (3, 4) or pred.ndim != 3:
        raise ValueError(f"pred and gt must both be (B, 3, 4), got {pred.shape} and {gt.shape}")
    src, ref, raw = _xyz(points_src), _xyz(points_ref), _xyz(points_raw)
    r_diff = euler_xyz_deg(gt[:, :, :3]) - euler_xyz_deg(pred[:, :, :3])
    t_diff = gt[:, :, 3] - pred[:, :, 3]
    residual = se3.compose(se3.inverse(gt), pred)
    err_r = se3.rotation_angle_deg(residual[:, :, :3])
    err_t = np.linalg.norm(residual[:, :, 3], axis=-1)
    src_moved = se3.apply(pred, src)
    src_clean = se3.apply(se3.compose(pred, se3.inverse(gt)), raw)
    chamfer = np.array([_mean_min_sq_dist(src_moved[b], raw[b]) + _mean_min_sq_dist(ref[b], src_clean[b])
                        for b in range(pred.shape[0])])
    return {"r_mse": np.mean(r_diff**2, 1), "r_mae": np.mean(np.abs(r_diff), 1), "t_mse": np.mean(t_diff**2, 1),
            "t_mae": np.mean(np.abs(t_diff), 1), "err_r_deg": err_r, "err_t": err_t, "chamfer_dist": chamfer}


def summarize_metrics(metrics: dict) -> dict:
    """The official summary: RMSE of ``*_mse``, mean and RMSE of ``err_*``, mean of the rest."""
    out = {}
    for key, values in metrics.items():
        values = np.asarray(values, np.float64)
        if key.endswith("mse"):
            out[key[:-3] + "rmse"] = float(np.sqrt(np.mean(values)))
        elif key.startswith("err"):
            out[key + "_mean"] = float(np.mean(values))
            out[key + "_rmse"] = float(np.sqrt(np.mean(values**2)))
        else:
            out[key] = float(np.mean(values))
    return out


def transform_errors(pred, gt) -> tuple[float, float]:
    """Isotropic rotation error (degrees) and translation error (input units) of one ``(4, 4)`` or
    ``(3, 4)`` transform against the ground truth."""
    residual = se3.compose(se3.inverse(np.asarray(gt, np.float64)[:3]), np.asarray(pred, np.float64)[:3])
    return float(se3.rotation_angle_deg(residual[:, :3])), float(np.linalg.norm(residual[:, 3]))
