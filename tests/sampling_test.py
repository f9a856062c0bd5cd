"""Fewer points: one per voxel (means per cube), random subsets, farthest-point subsets against a brute-force
oracle."""

import numpy as np
import pytest

from rpmnet_jax.geometry import sampling


def test_voxel_downsample_means_per_cube():
    pts = np.array([[0.1, 0.1, 0.1], [0.3, 0.3, 0.3], [1.2, 0.1, 0.1], [1.4, 0.1, 0.1]])
    nrm = np.array([[0, 0, 1.0], [0, 1.0, 0], [1.0, 0, 0], [1.0, 0, 0]])
    got, got_n = sampling.voxel_downsample(pts, nrm, 1.0)
    order = np.argsort(got[:, 0])
    np.testing.assert_allclose(got[order], [[0.2, 0.2, 0.2], [1.3, 0.1, 0.1]])
    np.testing.assert_allclose(got_n[order], [[0, 2 ** -0.5, 2 ** -0.5], [1, 0, 0]], atol=1e-12)  # float64 round-off
    assert sampling.voxel_downsample(pts, None, 1.0)[1] is None
    with pytest.raises(ValueError, match="voxel_size"):
        sampling.voxel_downsample(pts, None, 0.0)


def test_voxel_downsample_keeps_a_normal_where_the_cube_s_normals_cancel():
    """Opposite normals in one cube sum to zero: the cube's first normal is kept (unit length), not NaN."""
    pts = np.array([[0.1, 0.1, 0.1], [0.2, 0.2, 0.2]])
    nrm = np.array([[0.0, 0.0, 2.0], [0.0, 0.0, -2.0]])
    got, got_n = sampling.voxel_downsample(pts, nrm, 1.0)
    np.testing.assert_allclose(got, [[0.15, 0.15, 0.15]])
    np.testing.assert_array_equal(got_n, [[0.0, 0.0, 1.0]])


@pytest.mark.parametrize("side", [0.05, 1e-9])  # 1e-9: more than 2^62 cubes, the rows' own sort
def test_cube_ids_order_cubes_as_their_integer_coordinates(side):
    """One id per cube, ordered as the cubes' (x, y, z) lexicographically: ``np.unique`` of the ids gives the
    cubes, their first rows and counts that ``np.unique(..., axis=0)`` gives of the coordinates."""
    rng = np.random.default_rng(3)
    pts = rng.uniform(-1.0, 2.0, size=(3000, 3))
    pts[1500:] = pts[:1500] + rng.uniform(0, 1e-12, size=(1500, 3))  # cubes shared by several rows
    keys = np.floor((pts - pts.min(axis=0)) / side).astype(np.int64)
    want = np.unique(keys, axis=0, return_index=True, return_inverse=True, return_counts=True)[1:]
    got = np.unique(sampling.cube_ids(pts, side), return_index=True, return_inverse=True, return_counts=True)[1:]
    for w, g in zip(want, got):
        np.testing.assert_array_equal(g.ravel(), w.ravel())


def test_sample_indices_are_sorted_distinct_rows():
    rng = np.random.default_rng(0)
    idx = sampling.sample_indices(rng, 100, 30)
    assert idx.shape == (30,) and np.all(np.diff(idx) > 0) and idx.min() >= 0 and idx.max() < 100
    np.testing.assert_array_equal(sampling.sample_indices(rng, 20, 30), np.arange(20))  # all rows when fewer
    a = sampling.sample_indices(np.random.default_rng(1), 100, 30)
    np.testing.assert_array_equal(a, sampling.sample_indices(np.random.default_rng(1), 100, 30))  # seeded


def test_farthest_point_indices_equal_a_brute_force_oracle():
    rng = np.random.default_rng(2)
    pts = rng.uniform(-1, 1, size=(200, 3))
    got = sampling.farthest_point_indices(pts, 16, np.random.default_rng(3))
    first = np.random.default_rng(3).integers(len(pts))  # the same first point
    chosen = [first]
    for _ in range(15):  # each next point: the largest distance to its nearest chosen point, by full pairwise distances
        d = np.linalg.norm(pts[:, None] - pts[chosen][None], axis=-1).min(axis=1)
        chosen.append(int(np.argmax(d)))
    np.testing.assert_array_equal(got, np.sort(chosen))
