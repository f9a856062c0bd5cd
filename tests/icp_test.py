"""Robust point-to-plane ICP: convergence, robustness to partiality and outliers, no harm to good answers,
precision on real shapes at least Open3D's."""

import numpy as np
import pytest

from conftest import DATA, asymmetric_shape, require, rotation_about, rotation_error_deg
from rpmnet_jax.classical import icp


def _motion(deg, axis, trans):
    t = np.eye(4)
    t[:3, :3] = rotation_about(axis, deg)
    t[:3, 3] = trans
    return t


def _crop(pts, direction, keep=0.7):
    d = pts @ np.asarray(direction, np.float64)
    return d >= np.quantile(d, 1 - keep)


@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize("source_normals", [False, True])
def test_converges_from_10_degrees_on_clean_clouds(seed, source_normals):
    pts, nrm = asymmetric_shape(seed, 4000)
    gt = _motion(10.0, [0.2, 1.0, -0.4], [0.1, 0.0, 0.0])  # maps src onto ref
    src = (pts[::2] - gt[:3, 3]) @ gt[:3, :3]  # src = gt^-1(ref), other samples of the same surface
    src_n = nrm[::2] @ gt[:3, :3] if source_normals else None  # creases included: the update must settle
    res = icp.point_to_plane_icp(src, pts[1::2], nrm[1::2], np.eye(4), 0.02,  # starts 10° and 0.1 off
                                    src_normals=src_n)
    # noise-free: measured 0.0003-0.018° and 4e-6-1.3e-4 (the sampling gap of two halves of 4,000 points)
    assert rotation_error_deg(res.transform[:3, :3], gt[:3, :3]) < 0.1
    assert np.linalg.norm(res.transform[:3, 3] - gt[:3, 3]) < 1e-3
    assert res.converged and res.num_iterations > 1


def test_partial_overlap_and_outliers_do_not_pull_it_off():
    rng = np.random.default_rng(3)
    pts, nrm = asymmetric_shape(5, 8000)
    keep_src, keep_ref = _crop(pts, [1.0, 0.3, 0.1]), _crop(pts, [-0.2, 1.0, 0.4])
    gt = _motion(25.0, [0.5, -0.3, 1.0], [0.2, -0.1, 0.05])
    src = pts[keep_src] + rng.normal(scale=0.01, size=(keep_src.sum(), 3))
    src = np.concatenate([src, rng.uniform(-1, 1, size=(len(src) // 10, 3))])  # 10% outliers
    src = (src - gt[:3, 3]) @ gt[:3, :3]  # src = gt^-1(world): gt maps src onto ref
    ref = pts[keep_ref] + rng.normal(scale=0.01, size=(keep_ref.sum(), 3))
    start = gt @ _motion(6.0, [1.0, 1.0, 0.0], [0.05, 0.0, -0.05])  # a network-sized error
    res = icp.point_to_plane_icp(src, ref, nrm[keep_ref], start, 0.05)
    # the noise-and-partiality bound of the next test (measured here: 0.31° and 0.0018)
    assert rotation_error_deg(res.transform[:3, :3], gt[:3, :3]) < 0.5
    assert np.linalg.norm(res.transform[:3, 3] - gt[:3, 3]) < 0.01


@pytest.mark.parametrize("seed", range(4))
def test_never_makes_a_correct_answer_worse_than_noise(seed):
    """Property: started at the truth on noisy (σ = 0.01), 70%-partial clouds, it stays within the error
    that noise and partiality cause (0.19° mean, 0.32° worst over 8 seeds at this gate)."""
    rng = np.random.default_rng(seed)
    pts, nrm = asymmetric_shape(seed, 6000)
    axis = rng.normal(size=3)
    keep_src, keep_ref = _crop(pts, rng.normal(size=3)), _crop(pts, rng.normal(size=3))
    gt = _motion(rng.uniform(0, 180), axis, rng.uniform(-0.5, 0.5, 3))
    src = (pts[keep_src] + rng.normal(scale=0.01, size=(keep_src.sum(), 3)))
    src = (src - gt[:3, 3]) @ gt[:3, :3]  # inverse of gt
    ref = pts[keep_ref] + rng.normal(scale=0.01, size=(keep_ref.sum(), 3))
    res = icp.point_to_plane_icp(src, ref, nrm[keep_ref], gt, 0.05)
    assert rotation_error_deg(res.transform[:3, :3], gt[:3, :3]) < 0.5
    assert np.linalg.norm(res.transform[:3, 3] - gt[:3, 3]) < 0.01  # the noise's σ


def test_symmetric_planes_ignore_the_sign_of_source_normals():
    rng = np.random.default_rng(7)
    pts, nrm = asymmetric_shape(2, 4000)
    gt = _motion(8.0, [0.3, -1.0, 0.2], [0.03, 0.0, -0.02])
    src = (pts[::2] + rng.normal(scale=0.005, size=(2000, 3)) - gt[:3, 3]) @ gt[:3, :3]
    src_n = nrm[::2] @ gt[:3, :3]
    signs = rng.choice([-1.0, 1.0], size=(2000, 1))
    a = icp.point_to_plane_icp(src, pts[1::2], nrm[1::2], np.eye(4), 0.05, src_normals=src_n)
    b = icp.point_to_plane_icp(src, pts[1::2], -nrm[1::2], np.eye(4), 0.05, src_normals=src_n * signs)
    np.testing.assert_allclose(a.transform, b.transform, atol=1e-9)  # measured: identical
    assert rotation_error_deg(a.transform[:3, :3], gt[:3, :3]) < 0.1  # measured 0.027° (noise σ = 0.005)


def test_tukey_weights():
    r = np.array([0.0, 0.25, -0.5, 0.99, 1.0, -3.0])
    expected = [1.0, (1 - 0.0625) ** 2, 0.5625, (1 - 0.9801) ** 2, 0.0, 0.0]
    np.testing.assert_allclose(icp.tukey_weights(r, 1.0), expected)
    np.testing.assert_allclose(icp.tukey_weights(2 * r, 2.0), icp.tukey_weights(r, 1.0))


@pytest.mark.parametrize("m", [1, 2, 7, 8, 101])
def test_the_gate_median_is_numpys(m):
    values = np.random.default_rng(m).normal(size=m + 5)
    values[::4] = np.inf  # a coarse gate's queries without a partner
    values[1::5] = values[0]  # ties
    assert icp._median(values.copy(), m) == np.median(values[:m])


def test_the_step_solve_is_the_linear_solve():
    rng = np.random.default_rng(0)
    j = rng.normal(size=(40, 6)) * np.array([1e-3, 1e-3, 1e-3, 1.0, 1.0, 1e2])  # badly scaled columns
    a = j.T @ j + 1e-9 * np.trace(j.T @ j) * np.eye(6)
    b = rng.normal(size=6)
    x = icp._solve6(a.copy(), b.copy())
    np.testing.assert_allclose(x, np.linalg.solve(a, b), rtol=1e-9, atol=0)


def test_gates_follow_the_clouds_within_their_bounds():
    """3 median nearest-neighbour distances: a coarse gate from the finest gate up to its scale; a fine gate
    narrower than its scale only for clouds much denser and cleaner than the correspondence distance."""
    from rpmnet_jax.geometry import kdtree

    rng = np.random.default_rng(0)
    pts, _ = asymmetric_shape(4, 8000)
    tree = kdtree.KdTree(pts[1::2])
    dense = pts[::2]  # 3 median nearest-neighbour distances: 0.037
    noisy = dense + rng.normal(scale=0.05, size=dense.shape)  # about 0.12

    def gate(moved, max_distance, scale, neighbours):
        dist = tree.query(moved, k=neighbours, distance_upper_bound=scale * max_distance)[0]
        return icp._gate(dist.reshape(len(moved), neighbours), max_distance, scale)

    assert gate(dense, 0.2, 1.0, 3) == pytest.approx(0.05)  # the floor: a quarter
    assert gate(dense, 0.1, 1.0, 3) == pytest.approx(0.037, abs=1e-3)  # in between
    assert gate(noisy, 0.1, 1.0, 3) == pytest.approx(0.1)  # the stage's gate
    half_apart = np.concatenate([dense, dense + [5.0, 0.0, 0.0]])  # half the source overlaps nothing
    assert gate(half_apart, 0.1, 1.0, 3) == pytest.approx(0.037, abs=1e-3)  # the overlap's
    assert gate(dense, 0.05, 4.0, 1) == pytest.approx(0.05)  # coarse: down to the finest
    assert gate(dense + [0.5, 0.0, 0.0], 0.05, 4.0, 1) == pytest.approx(0.2)  # apart
    assert 0.1 < gate(noisy, 0.02, 8.0, 1) < 0.14  # in between (0.02 .. 0.16)


# Open3D's median rotation error (°) on the pairs and starts of the test below (measured, open3d 0.20.0): the
# bound where Open3D does not import. Ours there: 0.41 / 0.46; the previous refinement (Tukey weights of the
# point distance, one reference point per source point, no source normals): 0.47 / 0.67.
OPEN3D_MEDIAN_DEG = {"modelnet40_real_subset": 0.455, "real_meshes_train": 0.547}


@pytest.mark.parametrize("name", sorted(OPEN3D_MEDIAN_DEG))
def test_ends_at_least_as_close_as_open3d_on_real_shapes(name):
    """On 24 real partial pairs (70% crops, noise 0.01; the protocol's test-file pairs, evenly spread) from
    starts 5° and 0.02 off the truth, the median rotation error of our refinement (the shapes' normals on both
    sides: symmetric planes) is at most that of Open3D's robust point-to-plane ICP (Tukey 0.05, gate 0.05,
    60 iterations: the classical recipe's) from the same starts on the same clouds: computed here when
    Open3D imports, else ``OPEN3D_MEDIAN_DEG``."""
    from rpmnet_jax import data
    from rpmnet_jax.evaluation import baselines

    ds = data.ModelNet40(require(DATA / name, f"the {name} data set"), "val", "partial")
    rng = np.random.default_rng(0)
    have_open3d = baselines.open3d_available() is None
    ours, theirs = [], []
    for i in np.linspace(0, len(ds) - 1, 24).astype(int):
        s = ds[int(i)]
        src, ref = np.asarray(s["points_src"], np.float64), np.asarray(s["points_ref"], np.float64)
        gt = np.vstack([s["transform_gt"], [0.0, 0.0, 0.0, 1.0]])
        start = _motion(5.0, rng.normal(size=3), 0.02 * _unit(rng.normal(size=3))) @ gt
        res = icp.point_to_plane_icp(src[:, :3], ref[:, :3], ref[:, 3:], start, 0.05, src_normals=src[:, 3:])
        ours.append(rotation_error_deg(res.transform[:3, :3], gt[:3, :3]))
        if have_open3d:
            theirs.append(rotation_error_deg(baselines.robust_icp(src, ref, start)[:3, :3], gt[:3, :3]))
    bound = float(np.median(theirs)) if have_open3d else OPEN3D_MEDIAN_DEG[name]
    assert np.median(ours) <= bound, (np.median(ours), bound)


def _unit(v):
    return np.asarray(v, np.float64) / np.linalg.norm(v)


def test_bad_arguments():
    pts = np.random.default_rng(0).uniform(-1, 1, (50, 3))
    with pytest.raises(ValueError, match="max_distance"):
        icp.point_to_plane_icp(pts, pts, pts, np.eye(4), 0.0)
    with pytest.raises(ValueError, match="max_iterations"):
        icp.point_to_plane_icp(pts, pts, pts, np.eye(4), 0.1, max_iterations=0)
    with pytest.raises(ValueError, match="neighbours"):
        icp.point_to_plane_icp(pts, pts, pts, np.eye(4), 0.1, neighbours=0)
    with pytest.raises(ValueError, match="src_normals"):
        icp.point_to_plane_icp(pts, pts, pts, np.eye(4), 0.1, src_normals=pts[:10])
