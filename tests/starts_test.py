"""Where refinement starts: the classical FPFH + RANSAC hypotheses find a known rotation of an asymmetric shape,
the identity start, the network's confidence of a match matrix."""

import jax.numpy as jnp
import numpy as np
import pytest

from conftest import asymmetric_shape, rotation_about, rotation_error_deg
from rpmnet_jax.pairwise import prepare, starts


@pytest.mark.parametrize("seed", [0, 2, 3])
def test_classical_starts_find_a_known_rotation(seed):
    """Two disjoint samples of an asymmetric shape, one turned by 130° and moved: the best hypothesis (in the
    normalised frame, mapped back to the caller's units) lies within the 10° ICP converges from (icp_test;
    measured 2.7-4.3° and 0.02-0.06 here: a 3-point RANSAC sample of 256 noise-free points), the others are
    distinct."""
    pts, nrm = asymmetric_shape(seed, 512)
    rot, t = rotation_about([0.3, -1.0, 0.6], 130.0), np.array([0.5, -0.2, 1.0])
    pair = prepare.prepare_pair(pts[::2], pts[1::2] @ rot.T + t, nrm[::2], nrm[1::2] @ rot.T, num_points=256)
    found = starts.classical_starts(pair, 4, seed=0)
    assert 1 <= len(found) <= 4 and all(s.init == "classical" for s in found)
    best = pair.to_callers_units(found[0].transform[:3])
    assert rotation_error_deg(best[:3, :3], rot) < 10.0
    assert np.linalg.norm(best[:3, 3] - t) < 0.2  # radius 1: 10° moves the rim by 0.17
    shares = [s.confidence for s in found]
    assert shares == sorted(shares, reverse=True) and 0.0 < shares[-1] <= shares[0] <= 1.0
    for s in found:
        np.testing.assert_array_equal(s.network_transforms, s.transform[None, :3])  # its own single iterate
        for other in found:
            if other is not s:
                assert rotation_error_deg(s.transform[:3, :3], other.transform[:3, :3]) >= 45.0


@pytest.mark.parametrize("dense", [False, True])
def test_dense_clouds_take_their_hypotheses_from_a_voxel_grid(monkeypatch, dense):
    """Clouds of at least DENSE_FACTOR × the network's samples (each) get their hypotheses from a voxel grid of
    the whole clouds, and find the rotation from it; sparser ones from the samples, as before."""
    pts, nrm = asymmetric_shape(1, 12000 if dense else 1600)
    rot, t = rotation_about([0.3, -1.0, 0.6], 100.0), np.array([0.5, -0.2, 1.0])
    pair = prepare.prepare_pair(pts[::2], pts[1::2] @ rot.T + t, nrm[::2], nrm[1::2] @ rot.T, num_points=256)
    grids = []
    made = starts._voxel_grids
    monkeypatch.setattr(starts, "_voxel_grids", lambda *a: grids.extend(made(*a)[0]) or made(*a))
    found = starts.classical_starts(pair, 4, seed=0)
    assert len(grids) == (2 if dense else 0)
    if dense:  # one point per occupied cube: far fewer than the cloud, far more than the samples
        assert all(256 < len(g[0]) < 6000 and g[1].shape == g[0].shape for g in grids)
    best = pair.to_callers_units(found[0].transform[:3])
    assert rotation_error_deg(best[:3, :3], rot) < 10.0


def test_a_large_grid_is_a_coarser_grid(monkeypatch):
    """Beyond GRID_POINTS cubes the grid coarsens (feature matching compares every pair) and stays even: at most
    that many points, one per coarser cube, none closer than the fine cube, the same cube for both clouds; the
    FPFH radius and RANSAC's distance follow the cube."""
    pts, nrm = asymmetric_shape(1, 12000)
    pair = prepare.prepare_pair(pts[::2], pts[1::2], nrm[::2], nrm[1::2], num_points=256)
    (full, _), voxel = starts._voxel_grids(pair)
    assert voxel == starts.VOXEL and len(full[0]) > 500
    monkeypatch.setattr(starts, "GRID_POINTS", 500)
    grids, voxel = starts._voxel_grids(pair)
    assert voxel > starts.VOXEL and all(500 >= len(g) > 250 and n.shape == g.shape for g, n in grids)
    coarse = grids[0][0]
    gaps = np.linalg.norm(coarse[:, None] - coarse[None], axis=-1) + np.eye(len(coarse)) * 9
    assert gaps.min() > 0.5 * starts.VOXEL  # one point per coarse cube: no two share a fine one
    seen = {}

    class Seen(Exception):
        pass

    def from_clouds(*args, **kwargs):
        seen.update(kwargs)
        raise Seen

    monkeypatch.setattr(starts.feature_ransac, "from_clouds", from_clouds)
    with pytest.raises(Seen):
        starts.classical_starts(pair, 4, seed=0)
    assert seen["radius"] == 5 * voxel and seen["max_distance"] == 1.5 * voxel


def test_identity_start():
    s = starts.identity_start()
    assert s.init == "identity" and s.confidence == 0.0
    np.testing.assert_array_equal(s.transform, np.eye(4))
    np.testing.assert_array_equal(s.network_transforms, np.eye(4)[None, :3])


def test_confidence_is_the_mean_inlier_mass():
    perm = np.eye(5)[[2, 0, 4, 1, 3]]
    assert starts.confidence(perm) == 1.0
    assert starts.confidence(np.zeros((5, 7))) == 0.0
    half = np.zeros((4, 6))
    half[:2, :2] = np.eye(2)  # 2 of 4 rows and 2 of 6 columns matched: (0.5 + 1/3) / 2
    assert starts.confidence(half) == pytest.approx((0.5 + 2 / 6) / 2)
    batch = np.stack([perm, np.zeros((5, 5))])[None]  # (1, 2, 5, 5): any leading axes, NumPy or JAX
    np.testing.assert_allclose(starts.confidence(batch), [[1.0, 0.0]])
    np.testing.assert_allclose(starts.confidence(jnp.asarray(batch)), [[1.0, 0.0]])
