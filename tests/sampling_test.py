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


def _sweep(n: int, seed: int = 0) -> np.ndarray:
    """A LiDAR-like ground: points at angles and ranges 2-50 m, the density falling with the range (uniform in
    range, so a square metre far away holds far fewer points than one near the sensor)."""
    rng = np.random.default_rng(seed)
    r, a = rng.uniform(2.0, 50.0, n), rng.uniform(0, 2 * np.pi, n)
    return np.stack([r * np.cos(a), r * np.sin(a), rng.normal(0, 0.01, n)], axis=1)


def test_even_indices_weigh_surfaces_by_area_not_by_density():
    points = _sweep(40_000)
    far_area_share = (50.0 ** 2 - 25.0 ** 2) / (50.0 ** 2 - 2.0 ** 2)  # beyond 25 m: 75% of the ground's area
    far = np.linalg.norm(points[:, :2], axis=1) > 25.0
    random_rows = sampling.sample_indices(np.random.default_rng(0), len(points), 2000)
    even = sampling.even_indices(np.random.default_rng(0), points, 2000)
    assert even.shape == (2000,) and np.all(np.diff(even) > 0)  # sorted distinct rows, exactly n
    assert far[random_rows].mean() < 0.55  # a random subset keeps the density: about half of the points
    assert abs(far[even].mean() - far_area_share) < 0.06
    np.testing.assert_array_equal(even, sampling.even_indices(np.random.default_rng(0), points, 2000))  # seeded
    np.testing.assert_array_equal(sampling.even_indices(np.random.default_rng(0), points[:50], 2000), np.arange(50))


def test_even_indices_fall_back_to_a_random_subset_on_duplicated_points():
    points = np.repeat(np.eye(3), 100, axis=0)  # 3 distinct points: no grid has 50 occupied cubes
    idx = sampling.even_indices(np.random.default_rng(0), points, 50)
    np.testing.assert_array_equal(idx, sampling.sample_indices(np.random.default_rng(0), len(points), 50))


def test_spacing_spread_tells_a_sensor_s_falling_density_from_an_even_surface():
    g = np.stack(np.meshgrid(np.arange(100.0), np.arange(100.0)), -1).reshape(-1, 2)
    jitter = np.random.default_rng(0).uniform(-0.2, 0.2, g.shape)
    even_surface = np.column_stack([g + jitter, np.zeros(len(g))])
    assert sampling.spacing_spread(even_surface) < 2.0
    poisson = np.random.default_rng(1).uniform(0, 100, (10_000, 3)) * [1, 1, 0]  # random, evenly dense samples
    assert sampling.spacing_spread(poisson) < 2.0
    assert sampling.spacing_spread(_sweep(30_000)) > 2.5
    assert sampling.spacing_spread(np.zeros((10, 3))) == 1.0  # no distinct points: no spread
