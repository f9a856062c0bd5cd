"""evaluate_registration: fitness, inlier RMSE and correspondences against a brute-force NumPy computation;
plane_fit: the information matrix against finite differences."""

import numpy as np
import pytest

import rpmnet_jax
from conftest import random_pose
from rpmnet_jax.classical import scoring


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


def test_plane_fit_information_is_the_right_perturbation_jacobian():
    """``information = JᵀJ / σ²`` with ``J`` the finite-difference Jacobian of the residuals under ``T·Exp(ξ)``."""
    import gtsam

    rng = np.random.default_rng(0)
    src = rng.uniform(-1, 1, size=(200, 3))
    normals = rng.normal(size=(200, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    t = random_pose(rng)
    ref = src @ t[:3, :3].T + t[:3, 3] + 0.01 * rng.normal(size=(200, 3))
    corr = np.stack([np.arange(200), np.arange(200)], axis=1)
    fit = scoring.plane_fit(src, ref, normals, t, corr)
    eps = 1e-6
    jac = np.stack([(scoring.plane_fit(src, ref, normals, t @ gtsam.Pose3.Expmap(eps * np.eye(6)[k]).matrix(),
                                       corr).residuals - fit.residuals) / eps for k in range(6)], axis=1)
    # forward differences at eps = 1e-6 on unit-sized points: truncation ~eps relative, entries ~1/σ² = 1e4
    np.testing.assert_allclose(fit.information, jac.T @ jac / np.mean(fit.residuals ** 2), rtol=1e-4, atol=1e-3)
    empty = scoring.plane_fit(src, ref, normals, t, np.zeros((0, 2), int))
    np.testing.assert_array_equal(empty.information, np.zeros((6, 6)))
    assert empty.residuals.shape == (0,)


def test_balanced_fitness_weighs_each_normal_direction_the_same():
    """Ground (900 points, normals up) that fits and two walls (100 points each, normals along x and y) that do
    not: plain fitness 0.82, balanced 1/3; a direction with fewer than MIN_BUCKET points does not count."""
    rng = np.random.default_rng(0)
    up, x, y = np.eye(3)[2], np.eye(3)[0], np.eye(3)[1]
    jitter = lambda n, d: d + rng.normal(scale=0.02, size=(n, 3))
    normals = np.concatenate([jitter(900, up), jitter(100, x), jitter(100, y)])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    inlier = np.r_[np.ones(900, bool), np.zeros(200, bool)]
    assert inlier.mean() == pytest.approx(900 / 1100)
    assert scoring.balanced_fitness(normals, np.flatnonzero(inlier)) == pytest.approx(1 / 3)
    assert scoring.balanced_fitness(normals, np.arange(1100)) == 1.0
    assert scoring.balanced_fitness(normals, np.zeros(0, int)) == 0.0
    few = np.tile(-up, (scoring.MIN_BUCKET - 1, 1))  # a handful of points facing down, not fitting: not counted
    assert scoring.balanced_fitness(np.concatenate([normals, few]), np.flatnonzero(inlier)) == pytest.approx(1 / 3)
    assert scoring.balanced_fitness(np.zeros((0, 3)), np.zeros(0, int)) == 0.0
    spread = scoring._directions(scoring.NORMAL_DIRECTIONS)  # the buckets: unit, spread (no two within 25 deg)
    np.testing.assert_allclose(np.linalg.norm(spread, axis=1), 1.0)
    cos = spread @ spread.T
    assert cos[~np.eye(len(spread), dtype=bool)].max() < np.cos(np.radians(25))
