import numpy as np

from rpmnet_jax.classical import feature_ransac, fpfh

from conftest import asymmetric_shape, rotation_about, rotation_error_deg


def _pair(degrees, seed=0):
    rng = np.random.default_rng(seed)
    pts, nrm = asymmetric_shape(seed, 1500)
    src_i, ref_i = rng.choice(len(pts), 700, replace=False), rng.choice(len(pts), 700, replace=False)
    rot = rotation_about([0.3, -1.0, 0.6], degrees)
    t = np.array([0.2, -0.1, 0.3])
    src, src_n = pts[src_i] @ rot.T + t, nrm[src_i] @ rot.T  # the source is the reference moved by (rot, t)
    return src, src_n, pts[ref_i], nrm[ref_i], rot.T, -rot.T @ t


def test_ransac_finds_a_large_rotation_and_distinct_alternatives():
    src, src_n, ref, ref_n, gt_rot, gt_t = _pair(170.0)
    corr = feature_ransac.mutual_correspondences(fpfh.fpfh(src, src_n, 0.3, 128), fpfh.fpfh(ref, ref_n, 0.3, 128))
    h = feature_ransac.ransac_hypotheses(src, ref, corr, 0.075, seed=0)
    assert len(h.transforms) >= 2 and np.all(np.diff(h.inliers) <= 0)
    assert rotation_error_deg(h.transforms[0, :3, :3], gt_rot) < 5.0
    assert np.linalg.norm(h.transforms[0, :3, 3] - gt_t) < 0.05
    for i in range(len(h.transforms)):
        for j in range(i):
            assert rotation_error_deg(h.transforms[i, :3, :3], h.transforms[j, :3, :3]) >= 45.0


def test_ransac_is_deterministic_under_a_seed_and_empty_without_correspondences():
    src, src_n, ref, ref_n, _, _ = _pair(60.0, seed=1)
    corr = feature_ransac.mutual_correspondences(fpfh.fpfh(src, src_n, 0.3, 64), fpfh.fpfh(ref, ref_n, 0.3, 64))
    a = feature_ransac.ransac_hypotheses(src, ref, corr, 0.075, seed=3)
    b = feature_ransac.ransac_hypotheses(src, ref, corr, 0.075, seed=3)
    np.testing.assert_array_equal(a.transforms, b.transforms)
    assert len(feature_ransac.ransac_hypotheses(src, ref, corr[:2], 0.075).transforms) == 0


def test_nearest_rows_equal_a_kd_tree():
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(4)
    rows, queries = rng.uniform(0, 100, (300, 33)), rng.uniform(0, 100, (200, 33))
    to_rows, to_queries = feature_ransac.nearest_rows(queries, rows, chunk=64)
    np.testing.assert_array_equal(to_rows, cKDTree(rows).query(queries)[1])
    np.testing.assert_array_equal(to_queries, cKDTree(queries).query(rows)[1])


def test_scored_samples_equal_kabsch_and_direct_distances():
    """The compiled solve (Horn's quaternion) and inlier count against an oracle: Kabsch by SVD, distances moved
    point by point; a sample whose own points miss the distance scores -1."""
    rng = np.random.default_rng(5)
    src_c = rng.uniform(-1, 1, (128, 3))
    rot = rotation_about([0.2, 1.0, -0.4], 130.0)
    ref_c = src_c @ rot.T + [0.1, -0.3, 0.2] + rng.normal(0, 0.02, (128, 3))
    ref_c[:40] = rng.uniform(-1, 1, (40, 3))  # wrong matches
    samples = rng.integers(0, 128, (300, 3))
    samples = samples[(samples[:, 0] != samples[:, 1]) & (samples[:, 1] != samples[:, 2])
                      & (samples[:, 0] != samples[:, 2])]
    t, counts = feature_ransac._score_samples(src_c, ref_c, samples, 0.075)
    for k, sample in enumerate(samples):
        a, b = src_c[sample], ref_c[sample]
        u, _, vh = np.linalg.svd((a - a.mean(0)).T @ (b - b.mean(0)))
        d = np.sign(np.linalg.det(vh.T @ u.T))
        r = vh.T @ np.diag([1.0, 1.0, d]) @ u.T
        np.testing.assert_allclose(t[k, :, :3], r, atol=1e-9)
        np.testing.assert_allclose(t[k, :, 3], b.mean(0) - r @ a.mean(0), atol=1e-9)
        dist = np.linalg.norm(src_c @ r.T + t[k, :, 3] - ref_c, axis=1)
        expected = np.sum(dist <= 0.075) if np.all(dist[sample] <= 0.075) else -1
        assert counts[k] == expected
    assert (counts == -1).any() and (counts > 60).any()


def test_samples_the_edge_checker_rejects_are_never_solved():
    """Correspondences that pair every source point with one tiny triangle: no sample passes the edge-length
    checker, so no sample is solved (its transform stays zero: a solved one holds a rotation) and there is no
    hypothesis; at an edge ratio of 0 the same samples are solved."""
    src, _, _, _, _, _ = _pair(30.0)
    ref = np.repeat(np.array([[0.0, 0, 0], [1e-3, 0, 0], [0, 1e-3, 0]]), 10, axis=0)
    samples = np.array([[0, 10, 20], [1, 11, 21], [5, 15, 25]])
    t, counts = feature_ransac._score_samples(src[:30], ref, samples, 0.075, 0.9)
    assert np.all(counts == -1) and not t.any()
    t, _ = feature_ransac._score_samples(src[:30], ref, samples, 0.075, 0.0)
    np.testing.assert_allclose(np.linalg.det(t[:, :, :3]), 1.0, atol=1e-9)
    corr = np.stack([np.arange(30), np.arange(30)], axis=1)
    h = feature_ransac.ransac_hypotheses(src[:30], ref, corr, 0.075)
    assert len(h.transforms) == 0 and h.num_correspondences == 30
