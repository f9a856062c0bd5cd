"""Registration metrics against independently written formulas and hand-made cases."""

import math

import numpy as np
import pytest

from rpmnet_jax import metrics
from rpmnet_jax.ops import se3


def _rot(axis: str, deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return {"x": np.array([[1, 0, 0], [0, c, -s], [0, s, c]]),
            "y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
            "z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])}[axis]


def _transform(rot, trans) -> np.ndarray:
    return np.concatenate([rot, np.reshape(trans, (3, 1))], axis=1)


def _random_rotation(rng) -> np.ndarray:
    return se3.quaternion_to_matrix(rng.normal(size=4))


def _euler_xyz_deg(r) -> np.ndarray:
    """Extrinsic x-then-y-then-z angles: R = Rz(c) Ry(b) Rx(a) (away from gimbal lock)."""
    a = math.atan2(r[2, 1], r[2, 2])
    b = -math.asin(np.clip(r[2, 0], -1, 1))
    c = math.atan2(r[1, 0], r[0, 0])
    return np.degrees([a, b, c])


def _angle_deg(r) -> float:
    """Rotation angle from the axis-angle form: |v| where sin(|v|) and cos(|v|) come from R."""
    skew = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    return math.degrees(math.atan2(0.5 * np.linalg.norm(skew), 0.5 * (np.trace(r) - 1)))


def _chamfer(src, ref, raw, pred, gt) -> float:
    """Brute-force modified Chamfer distance with full 4x4 matrices."""
    p, g = np.eye(4), np.eye(4)
    p[:3], g[:3] = pred, gt
    moved = src @ p[:3, :3].T + p[:3, 3]
    back = p @ np.linalg.inv(g)
    clean = raw @ back[:3, :3].T + back[:3, 3]
    d1 = ((moved[:, None] - raw[None]) ** 2).sum(-1).min(1).mean()
    d2 = ((ref[:, None] - clean[None]) ** 2).sum(-1).min(1).mean()
    return d1 + d2


def test_random_transforms_match_independent_formulas():
    rng = np.random.default_rng(0)
    batch = 6
    gt = np.stack([_transform(_random_rotation(rng), rng.uniform(-0.5, 0.5, 3)) for _ in range(batch)])
    pred = np.stack([_transform(_random_rotation(rng), rng.uniform(-0.5, 0.5, 3)) for _ in range(batch)])
    raw = rng.normal(size=(batch, 50, 3))
    src = raw[:, :40] + 0.01 * rng.normal(size=(batch, 40, 3))
    ref = np.einsum("bij,bnj->bni", gt[:, :, :3], raw[:, 10:]) + gt[:, None, :, 3]
    m = metrics.registration_metrics(pred, gt, src, ref, raw)
    for b in range(batch):
        e_gt, e_pred = _euler_xyz_deg(gt[b, :, :3]), _euler_xyz_deg(pred[b, :, :3])
        np.testing.assert_allclose(m["r_mae"][b], np.abs(e_gt - e_pred).mean(), rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(m["r_mse"][b], ((e_gt - e_pred) ** 2).mean(), rtol=1e-9, atol=1e-9)
        dt = gt[b, :, 3] - pred[b, :, 3]
        np.testing.assert_allclose(m["t_mae"][b], np.abs(dt).mean(), rtol=1e-12)
        np.testing.assert_allclose(m["t_mse"][b], (dt**2).mean(), rtol=1e-12)
        residual = gt[b, :, :3].T @ pred[b, :, :3]
        np.testing.assert_allclose(m["err_r_deg"][b], _angle_deg(residual), atol=1e-6)
        np.testing.assert_allclose(m["err_t"][b], np.linalg.norm(gt[b, :, :3].T @ dt), rtol=1e-9)
        np.testing.assert_allclose(m["chamfer_dist"][b], _chamfer(src[b], ref[b], raw[b], pred[b], gt[b]),
                                   rtol=1e-9)


def test_identity_prediction_of_identity_is_zero_error_and_chamfer_floor():
    rng = np.random.default_rng(1)
    raw = rng.normal(size=(1, 30, 3))
    eye = np.eye(3, 4)[None]
    m = metrics.registration_metrics(eye, eye, raw, raw, raw)
    for key in ("r_mse", "r_mae", "t_mse", "t_mae", "err_r_deg", "err_t", "chamfer_dist"):
        assert m[key][0] == pytest.approx(0.0, abs=1e-9), key


@pytest.mark.parametrize("axis", ["x", "y", "z"])
def test_half_turn_is_180_degrees(axis):
    rot = _rot(axis, 180.0)
    gt, pred = np.eye(3, 4)[None], _transform(rot, np.zeros(3))[None]
    pts = np.random.default_rng(2).normal(size=(1, 10, 3))
    m = metrics.registration_metrics(pred, gt, pts, pts, pts)
    assert m["err_r_deg"][0] == pytest.approx(180.0, abs=1e-5)
    assert m["err_t"][0] == pytest.approx(0.0, abs=1e-12)


def test_hand_made_values():
    # 90 degrees about x, translation error (0.3, 0, 0): Euler diff (90, 0, 0).
    gt = np.eye(3, 4)[None]
    pred = _transform(_rot("x", 90.0), [0.3, 0.0, 0.0])[None]
    pts = np.zeros((1, 1, 3))
    m = metrics.registration_metrics(pred, gt, pts, pts, pts)
    assert m["r_mae"][0] == pytest.approx(30.0)
    assert m["r_mse"][0] == pytest.approx(8100.0 / 3)
    assert m["err_r_deg"][0] == pytest.approx(90.0)
    assert m["t_mae"][0] == pytest.approx(0.1)
    assert m["t_mse"][0] == pytest.approx(0.03)
    assert m["err_t"][0] == pytest.approx(0.3)

    # Pure shift of 0.1 on a two-point cloud: each Chamfer term is 0.01.
    raw = np.array([[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]])
    shifted = _transform(np.eye(3), [0.1, 0.0, 0.0])[None]
    m = metrics.registration_metrics(shifted, gt, raw, raw, raw)
    assert m["chamfer_dist"][0] == pytest.approx(0.02)


def test_summary_follows_the_official_reduction():
    per_pair = {"r_mse": np.array([1.0, 9.0]), "err_r_deg": np.array([3.0, 4.0]), "chamfer_dist": np.array([1, 3.0])}
    s = metrics.summarize_metrics(per_pair)
    assert s == pytest.approx({"r_rmse": math.sqrt(5.0), "err_r_deg_mean": 3.5,
                               "err_r_deg_rmse": math.sqrt(12.5), "chamfer_dist": 2.0})


def test_accepts_six_columns_and_rejects_bad_shapes():
    pts = np.random.default_rng(3).normal(size=(2, 8, 6))
    eye = np.broadcast_to(np.eye(3, 4), (2, 3, 4))
    m = metrics.registration_metrics(eye, eye, pts, pts, pts)
    np.testing.assert_allclose(m["chamfer_dist"], 0.0, atol=1e-12)
    with pytest.raises(ValueError, match="pred and gt"):
        metrics.registration_metrics(eye[:, :, :3], eye[:, :, :3], pts, pts, pts)


def test_transform_errors_of_a_known_motion():
    """``transform_errors`` of ``(4, 4)`` matrices: a 12° turn about z and a (0, 0.3, 0.4) shift against the
    identity."""
    pred = np.eye(4)
    pred[:3, :3] = _rot("z", 12.0)
    pred[:3, 3] = [0.0, 0.3, 0.4]
    err_r, err_t = metrics.transform_errors(pred, np.eye(4))
    assert err_r == pytest.approx(12.0) and err_t == pytest.approx(0.5)
