"""FPFH: equal to Open3D's, invariant under rigid motion, pair features and histogram sums, ties of the normal
swap, clouds too small for a neighbour."""

import numpy as np
import pytest

from rpmnet_jax.classical import fpfh

from conftest import asymmetric_shape, rotation_about


def _shape(n=600):
    pts, nrm = asymmetric_shape(0, n)
    return pts, nrm


def test_fpfh_equals_open3d():
    o3d = pytest.importorskip("open3d")
    pts, nrm = _shape()
    pc = o3d.geometry.PointCloud()
    pc.points, pc.normals = o3d.utility.Vector3dVector(pts), o3d.utility.Vector3dVector(nrm)
    theirs = np.asarray(o3d.pipelines.registration.compute_fpfh_feature(
        pc, o3d.geometry.KDTreeSearchParamHybrid(radius=0.3, max_nn=64)).data).T
    np.testing.assert_allclose(fpfh.fpfh(pts, nrm, 0.3, 64), theirs, atol=1e-9)  # both float64: round-off of sums


def test_fpfh_is_invariant_under_rigid_motion():
    pts, nrm = _shape()
    rot = rotation_about([1.0, 2.0, -0.5], 170.0)
    moved = fpfh.fpfh(pts @ rot.T + [0.3, -2.0, 5.0], nrm @ rot.T, 0.3, 64)
    still = fpfh.fpfh(pts, nrm, 0.3, 64)
    # float64 round-off of the moved points (bins sum to 100 per block); α = ±π lie in bins 0 and 10 (the
    # wrap-around): rounding moves pairs at the branch cut between them
    np.testing.assert_allclose(moved[:, 1:10], still[:, 1:10], atol=1e-6)
    np.testing.assert_allclose(moved[:, 11:], still[:, 11:], atol=1e-6)
    np.testing.assert_allclose(moved[:, 0] + moved[:, 10], still[:, 0] + still[:, 10], atol=1e-6)


def test_pair_features_are_zero_for_coincident_points_and_bins_sum_to_100():
    p = np.zeros((2, 3))
    n = np.array([[0.0, 0, 1], [0, 1, 0]])
    np.testing.assert_array_equal(fpfh.pair_features(p[0], n[0], p[1], n[1]), np.zeros(4))
    pts, nrm = _shape(300)
    idx, _, valid = fpfh.neighbours(pts, 0.3, 32)
    hist = fpfh.spfh(pts, nrm, idx, valid).reshape(-1, 3, fpfh.BINS)
    has = valid[:, 1:].any(axis=1)
    np.testing.assert_allclose(hist[has].sum(axis=-1), 100.0)


def test_the_normal_swap_ties_as_open3d():
    """Open3D swaps when ``acos(|a1|) > acos(|a2|)``: two cosines one ulp apart with one arccos do not swap."""
    x = 1e-9
    y = np.nextafter(x, 1.0)
    assert np.arccos(x) == np.arccos(y)
    assert not fpfh._swaps(x, y) and not fpfh._swaps(y, x)
    assert fpfh._swaps(0.2, 0.3) and not fpfh._swaps(0.9, 0.1)


def test_one_neighbour_and_one_point_give_empty_histograms_of_33_bins():
    """``max_nn=1`` (each point's only neighbour is itself) and a one-point cloud: ``(N, 33)`` zeros, as Open3D
    gives a point without neighbours (SciPy returns ``(N,)`` for ``k=1``: it must not broadcast to ``(N, N)``)."""
    pts, nrm = _shape(50)
    got = fpfh.fpfh(pts, nrm, 0.3, max_nn=1)
    assert got.shape == (50, 33)
    np.testing.assert_array_equal(got, 0.0)
    idx, d2, valid = fpfh.neighbours(pts, 0.3, 1)
    assert idx.shape == d2.shape == valid.shape == (50, 1)
    np.testing.assert_array_equal(idx[:, 0], np.arange(50))
    one = fpfh.fpfh(pts[:1], nrm[:1], 0.3)
    assert one.shape == (1, 33)
    np.testing.assert_array_equal(one, 0.0)
    with pytest.raises(ValueError, match="max_nn"):
        fpfh.neighbours(pts, 0.3, 0)


def test_the_grid_search_finds_the_k_d_tree_s_neighbours():
    """The hybrid search by radius cells: itself first, then the same rows at the same distances as the k-d
    tree's (in any order), for points with more and with fewer neighbours than ``max_nn`` (a sparse outlier
    among them), and the tree for a cloud whose extent would need too many cells."""
    from rpmnet_jax.geometry import kdtree

    rng = np.random.default_rng(7)
    pts = np.concatenate([rng.normal(size=(600, 3)) * [0.3, 0.2, 0.1], [[3.0, 3.0, 3.0]]])
    for max_nn in (1, 16, 128):
        g_idx, g_d2, g_valid = fpfh.neighbours(pts, 0.25, max_nn)
        t_idx, t_d2, t_valid = fpfh.neighbours(pts, 0.25, max_nn, tree=kdtree.KdTree(pts))
        np.testing.assert_array_equal(g_idx[:, 0], np.arange(len(pts)))
        np.testing.assert_array_equal(g_valid, t_valid)
        np.testing.assert_array_equal(np.sort(g_idx, axis=1), np.sort(t_idx, axis=1))
        order = np.argsort(g_idx, axis=1), np.argsort(t_idx, axis=1)
        np.testing.assert_allclose(np.take_along_axis(g_d2, order[0], 1), np.take_along_axis(t_d2, order[1], 1),
                                   rtol=1e-12, atol=1e-15)
    assert fpfh.neighbours(pts, 0.25, 16)[2][-1].sum() == 1  # the outlier: itself only
    far = np.concatenate([pts, [[1e7, 0.0, 0.0]]])  # 4e7 cells along x: the tree searches, nearest first
    idx, d2, _ = fpfh.neighbours(far, 0.25, 8)
    np.testing.assert_array_equal(np.sort(idx[:-1], axis=1), np.sort(fpfh.neighbours(pts, 0.25, 8)[0], axis=1))
    assert np.all(np.diff(d2, axis=1)[idx[:, 1:] != np.arange(len(far))[:, None]] >= 0)
