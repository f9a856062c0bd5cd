"""Preparing a pair: stray points left out of the centre, scale and samples; estimated normals the same way in
both clouds."""

import numpy as np
import pytest

from rpmnet_jax.data import synthetic
from rpmnet_jax.pairwise import prepare


def _shape(seed=0, n=800, label=36):
    pts = synthetic.sample_shape(np.random.default_rng(seed), label, n)
    return pts[:, :3].astype(np.float64), pts[:, 3:].astype(np.float64)


def test_stray_points_move_neither_centre_nor_scale():
    pts, nrm = _shape()
    ref, ref_n = _shape(seed=1)
    radius = np.linalg.norm(pts - pts.mean(0), axis=1).max()
    strays = pts.mean(0) + radius * np.array([[100.0, 0, 0], [0, -60.0, 0], [0, 0, 250.0]])
    dirty = np.insert(pts, [10, 200, 500], strays, axis=0)
    dirty_n = np.insert(nrm, [10, 200, 500], [[1.0, 0, 0]] * 3, axis=0)
    clean = prepare.prepare_pair(pts, ref, nrm, ref_n, num_points=1024)
    got = prepare.prepare_pair(dirty, ref, dirty_n, ref_n, num_points=1024)
    assert np.count_nonzero(~got.src_core) == 3 and got.ref_core.all()
    np.testing.assert_allclose(got.c_src, clean.c_src, rtol=0, atol=1e-15)
    assert got.scale == clean.scale
    np.testing.assert_array_equal(got.src6, clean.src6)  # the strays are not sampled for the network
    assert np.max(np.abs(got.src6[0, :, :3])) <= 1.0
    common = prepare.prepare_pair(dirty, ref, dirty_n, ref_n, num_points=1024, centering="common")
    assert common.scale == prepare.prepare_pair(pts, ref, nrm, ref_n, num_points=1024, centering="common").scale


def test_estimated_normals_face_the_same_way_in_both_clouds():
    """Without normals, both clouds' network normals agree with the analytic outward ones; both clouds of a
    pair seen from the origin (scans in a sensor's frame) face the origin."""
    pts, truth = _shape(seed=2, n=1500, label=8)  # a torus: the centroid is not inside the surface
    pair = prepare.prepare_pair(pts, pts[::-1] + 0.3, num_points=512, seed=1)
    unit = (pts - pts.mean(0)) / pair.scale  # both clouds' points in the normalised frame
    for cloud6 in (pair.src6[0], pair.ref6[0]):
        xyz_u, n_est = cloud6[:, :3].astype(np.float64), cloud6[:, 3:].astype(np.float64)
        nearest = np.argmin(np.linalg.norm(unit[None] - xyz_u[:, None], axis=2), axis=1)
        assert np.mean(np.sum(n_est * truth[nearest], axis=1) > 0) > 0.98
    # the inside of a bowl (a sphere's upper cap) seen from the origin below it, 5.6 radii away: toward the
    # sensor, which is the opposite of away from the centroid for every point
    rng = np.random.default_rng(3)
    d = rng.normal(size=(4000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    cap = d[d[:, 2] > 0.2] + np.array([0.0, 0.0, 5.0])
    pair = prepare.prepare_pair(cap, cap[::2], num_points=512)
    for cloud6, centre in ((pair.src6[0], pair.c_src), (pair.ref6[0], pair.c_ref)):
        xyz_u, n_est = cloud6[:, :3].astype(np.float64), cloud6[:, 3:].astype(np.float64)
        toward_origin = -centre / pair.scale - xyz_u
        assert np.mean(np.sum(n_est * toward_origin, axis=1) > 0) > 0.99
        outward = xyz_u - xyz_u.mean(0)
        assert np.mean(np.sum(n_est * outward, axis=1) > 0) < 0.05


def test_a_cloud_above_max_points_is_registered_on_a_subset_of_its_rows(monkeypatch):
    """Above ``MAX_POINTS`` rows only a seeded subset is kept (rows into the caller's arrays, in order, NaN rows never
    picked), and ``align`` still moves every row of the caller's source."""
    from rpmnet_jax.pairwise import alignment
    from rpmnet_jax.pairwise.options import NetworkOptions

    monkeypatch.setattr(prepare, "MAX_POINTS", 500)
    pts, nrm = _shape(seed=3, n=2000)
    pts[7] = np.nan
    with pytest.warns(UserWarning, match="dropped 1 points"):
        pair = prepare.prepare_pair(pts, pts, nrm, nrm, num_points=256)
    assert len(pair.src) == len(pair.ref) == 500
    assert np.all(np.diff(pair.src_rows) > 0) and 7 not in pair.src_rows
    np.testing.assert_array_equal(pair.src, pts[pair.src_rows])
    assert not np.array_equal(pair.src_rows, pair.ref_rows)  # each cloud its own subset
    with pytest.warns(UserWarning, match="dropped 1 points"):
        a = alignment.align(pts, pts, nrm, nrm, init="classical",
                            network_options=NetworkOptions(256))
    assert a.aligned.shape == pts.shape and np.isnan(a.aligned[7]).all()
    np.testing.assert_allclose(a.transform, np.eye(4), atol=1e-4)  # two subsets of one cloud: the identity
    assert set(a.correspondences[:, 0]) <= set(prepare.prepare_pair(pts, pts, nrm, nrm, num_points=256).src_rows)


def _dense(src, ref, refine_points=2000):
    pair = prepare.prepare_pair(src, ref, num_points=256)
    return pair, prepare.dense_clouds(pair, refine_points, 0, prepare.RowNormals(pair.ref, None))


def test_a_sensor_s_sweep_is_refined_on_samples_spread_over_space():
    rng = np.random.default_rng(0)
    r, a = rng.uniform(2.0, 50.0, 30_000), rng.uniform(0, 2 * np.pi, 30_000)  # density falling with the range
    sweep = np.stack([r * np.cos(a), r * np.sin(a), rng.normal(0, 0.01, 30_000)], axis=1)
    pair, dense = _dense(sweep, sweep)
    far = np.linalg.norm((dense.src * pair.scale + pair.c_src)[:, :2], axis=1) > 25.0
    assert far.mean() > 0.65  # a random subset: about half beyond 25 m, where 75% of the ground's area lies


def test_an_object_s_even_scan_keeps_its_random_samples():
    pts, _ = _shape(n=8000)
    pair, dense = _dense(pts, pts)
    rows = np.flatnonzero(pair.src_core)
    want = rows[np.sort(np.random.default_rng(1).choice(len(rows), 2000, replace=False))]
    np.testing.assert_allclose(dense.src, pair.to_unit(pair.src[want], "src"))
