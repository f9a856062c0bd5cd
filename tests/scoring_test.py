"""evaluate_registration: fitness, inlier RMSE and correspondences against a brute-force NumPy computation."""

import numpy as np
import pytest

import rpmnet_jax
from rpmnet_jax.geometry import scoring


def _brute_force(src, ref, t, max_dist):
    moved = src @ t[:3, :3].T + t[:3, 3]
    d = np.linalg.norm(moved[:, None, :] - ref[None, :, :], axis=-1)
    nearest = d.argmin(axis=1)
    dmin = d[np.arange(len(src)), nearest]
    inlier = dmin <= max_dist
    rmse = np.sqrt(np.mean(dmin[inlier] ** 2)) if inlier.any() else 0.0
    return inlier.mean(), rmse, np.stack([np.nonzero(inlier)[0], nearest[inlier]], 1)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_matches_brute_force(seed):
    rng = np.random.default_rng(seed)
    src, ref = rng.uniform(-1, 1, (300, 3)), rng.uniform(-1, 1, (400, 3))
    t = np.eye(4)
    t[:3, :3] = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    if np.linalg.det(t[:3, :3]) < 0:
        t[:3, 0] *= -1
    t[:3, 3] = rng.normal(size=3) * 0.1
    fitness, rmse, corr = _brute_force(src, ref, t, 0.15)
    got = rpmnet_jax.evaluate_registration(src, ref, t, 0.15)
    assert got.fitness == pytest.approx(fitness)
    assert got.inlier_rmse == pytest.approx(rmse)
    np.testing.assert_array_equal(got.correspondences, corr)
    assert 0.0 < got.fitness < 1.0  # the case is not trivial


def test_identical_clouds_and_no_inliers():
    rng = np.random.default_rng(0)
    pts = rng.uniform(-1, 1, (100, 3))
    same = scoring.evaluate_registration(pts, pts, np.eye(4), 1e-6)
    assert same.fitness == 1.0 and same.inlier_rmse == 0.0
    np.testing.assert_array_equal(same.correspondences, np.stack([np.arange(100)] * 2, 1))
    far = np.eye(4)
    far[:3, 3] = 100.0
    none = scoring.evaluate_registration(pts, pts, far, 0.1)
    assert none.fitness == 0.0 and none.inlier_rmse == 0.0 and none.correspondences.shape == (0, 2)


def test_bad_input():
    pts = np.zeros((5, 3))
    with pytest.raises(ValueError, match="max_distance"):
        scoring.evaluate_registration(pts, pts, np.eye(4), 0.0)
    with pytest.raises(ValueError, match="transform"):
        scoring.evaluate_registration(pts, pts, np.eye(3), 0.1)
    with pytest.raises(ValueError, match="source"):
        scoring.evaluate_registration(np.zeros((0, 3)), pts, np.eye(4), 0.1)
