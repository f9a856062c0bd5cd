"""Own-cloud registration (``align``): rigid answers in the caller's units, scores, determinism, stray points,
too few points, the options objects; the ``rpmnet-register`` CLI and its errors."""


import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import rpmnet_jax
from conftest import rotation_error_deg, synthetic_shape
from rpmnet_jax.weights import loading


@pytest.mark.parametrize("centering", ["separate", "common"])
def test_transform_is_rigid_and_in_callers_units(random_weights, centering):
    """A similarity applied to both inputs conjugates the answer: rotation unchanged, translation mapped."""
    src, src_n = synthetic_shape(seed=2, n=800)
    ref = src @ Rotation.from_euler("z", 30, degrees=True).as_matrix().T + 0.1
    kw = dict(checkpoint=random_weights, network_options=rpmnet_jax.NetworkOptions(256, 2, centering=centering),
              init="local")
    a = rpmnet_jax.align(src, ref, src_n, None, **kw)
    k, off = 250.0, np.array([1e3, -50.0, 7.0])
    b = rpmnet_jax.align(src * k + off, ref * k + off, src_n, None, **kw)
    rot = a.transform[:3, :3]
    # the network's rotations are float32 (measured orthogonality and determinant defects: 5e-7)
    np.testing.assert_allclose(rot @ rot.T, np.eye(3), atol=1e-5)
    assert abs(np.linalg.det(rot) - 1) < 1e-5
    np.testing.assert_allclose(b.transform[:3, :3], rot, atol=2e-4)  # float32 runs of the same clouds: 3e-7
    # 0.5 = 2e-3 of the 250× scale: float32 unit-sphere translations, scaled back (measured 3.5e-4)
    np.testing.assert_allclose(b.transform[:3, 3], k * a.transform[:3, 3] + off - rot @ off, atol=0.05 * k * 1e-2 * 4)
    # the same float64 product (measured: identical)
    np.testing.assert_allclose(b.aligned, (src * k + off) @ b.transform[:3, :3].T + b.transform[:3, 3], atol=1e-6)
    assert b.transforms.shape == (2, 4, 4) and 0.0 <= b.confidence <= 1.0


def test_separate_centering_follows_a_shift_of_the_reference(random_weights):
    """Moving the reference by d moves the answer by d (the model sees the same centred clouds)."""
    src, src_n = synthetic_shape(seed=4, n=600)
    ref, ref_n = synthetic_shape(seed=5, n=600)
    d = np.array([300.0, -20.0, 45.0])
    kw = dict(checkpoint=random_weights, network_options=rpmnet_jax.NetworkOptions(200, 2), init="local")
    a = rpmnet_jax.align(src, ref, src_n, ref_n, **kw)
    b = rpmnet_jax.align(src, ref + d, src_n, ref_n, **kw)
    # the network sees identical centred clouds: only float64 round-off of the shift remains (measured 1e-16 and 0)
    np.testing.assert_allclose(b.transform[:3, :3], a.transform[:3, :3], atol=1e-6)
    np.testing.assert_allclose(b.transform[:3, 3], a.transform[:3, 3] + d, atol=1e-4)
    with pytest.raises(ValueError, match="centering"):
        rpmnet_jax.align(src, ref, src_n, ref_n, checkpoint=random_weights,
                         network_options=rpmnet_jax.NetworkOptions(centering="median"))


def test_refine_none_returns_the_network_answer(random_weights):
    """refine="none": the answer is the network's last iterate, untouched; ICP starts from the same network run and
    moves the answer."""
    src, src_n = synthetic_shape(seed=6, n=900)
    ref, ref_n = synthetic_shape(seed=7, n=900)
    kw = dict(checkpoint=random_weights, network_options=rpmnet_jax.NetworkOptions(300), init="local")
    raw = rpmnet_jax.align(src, ref, src_n, ref_n, refine="none", **kw)
    assert raw.transforms.shape == (5, 4, 4)
    np.testing.assert_array_equal(raw.transform, raw.transforms[-1])
    assert raw.num_iterations == 0 and raw.converged and raw.init == "local"
    icp = rpmnet_jax.align(src, ref, src_n, ref_n, refine="icp", **kw)
    np.testing.assert_array_equal(icp.transforms, raw.transforms)
    assert icp.num_iterations > 0 and not np.allclose(icp.transform, raw.transform, atol=1e-6)


def test_an_unconverged_winner_is_refined_further(random_weights):
    """Every candidate gets ``max_iterations`` per stage; the winner, if it stopped there, continues for
    ``POLISH_FACTOR`` × as many, and ends closer (the random-weights network starts it far off)."""
    from rpmnet_jax.pairwise import candidates
    src, src_n = synthetic_shape(seed=6, n=900)
    rot = Rotation.from_euler("xyz", [12, -8, 10], degrees=True).as_matrix()
    kw = dict(checkpoint=random_weights, network_options=rpmnet_jax.NetworkOptions(300), init="local")
    short = rpmnet_jax.RefineOptions(scales=(1.0,), max_iterations=1)
    a = rpmnet_jax.align(src, src @ rot.T, src_n, src_n @ rot.T, refine_options=short, **kw)
    assert 1 < a.num_iterations <= 1 + candidates.POLISH_FACTOR
    start = a.transforms[-1]
    assert rotation_error_deg(a.transform[:3, :3], rot) < rotation_error_deg(start[:3, :3], rot)


def test_pipeline_results_are_scored_by_nearest_neighbours_and_deterministic(random_weights):
    src, src_n = synthetic_shape(seed=8, n=1500)
    other, _ = synthetic_shape(seed=9, n=1500)  # another sample of the same surface: not every point has a close partner
    ref = other @ Rotation.from_euler("y", 20, degrees=True).as_matrix().T * 3.0 + 5.0
    kw = dict(checkpoint=random_weights, network_options=rpmnet_jax.NetworkOptions(256, 2), init="local", seed=3)
    a = rpmnet_jax.align(src * 3.0, ref, src_n, None, **kw)
    b = rpmnet_jax.align(src * 3.0, ref, src_n, None, **kw)
    np.testing.assert_array_equal(a.transform, b.transform)
    assert a.max_correspondence_distance == pytest.approx(0.05 * np.linalg.norm(ref - ref.mean(0), axis=1).max())
    # the scores by brute force: every source point's nearest reference point, within the distance or not
    from scipy.spatial.distance import cdist
    d = cdist((src * 3.0) @ a.transform[:3, :3].T + a.transform[:3, 3], ref)
    nearest, within = d.min(1), d.min(1) <= a.max_correspondence_distance
    assert 0 < within.sum() < len(src)  # some pairs within the distance, not all
    assert a.fitness == pytest.approx(within.mean(), abs=1e-12)
    assert a.inlier_rmse == pytest.approx(np.sqrt(np.mean(nearest[within] ** 2)), rel=1e-9)
    np.testing.assert_array_equal(a.correspondences, np.stack([np.nonzero(within)[0], d.argmin(1)[within]], 1))
    assert set(a.timings) == set(a.stages) | {"total"}
    assert a.stages == ("prepare", "network", "refine", "score")  # init="local": no classical or global stage
    c = rpmnet_jax.align(src * 3.0, ref, src_n, None, max_correspondence_distance=0.5, **kw)
    assert c.max_correspondence_distance == 0.5
    for bad in (dict(init="everywhere"), dict(refine="gicp"), dict(max_correspondence_distance=-1.0),
                dict(global_options=dict(top_k=3)), dict(refine_options=None)):
        with pytest.raises(ValueError):
            rpmnet_jax.align(src, ref, **{**kw, **bad})


@pytest.mark.parametrize("bad", [dict(top_k=0), dict(hypotheses="dodecahedral"), dict(points=2), dict(iters=0),
                                 dict(polish_points=0), dict(auto_fitness=1.5),
                                 dict(network_fitness=-0.1), dict(network_on_dense=1)])
def test_global_options_are_checked_when_made(bad):
    with pytest.raises(ValueError, match=next(iter(bad))):
        rpmnet_jax.GlobalOptions(**bad)


@pytest.mark.parametrize("bad", [dict(points=2), dict(scales=()), dict(scales=(2.0, 0.0)), dict(max_iterations=0),
                                 dict(tolerance=0.0)])
def test_refine_options_are_checked_when_made(bad):
    with pytest.raises(ValueError, match=next(iter(bad))):
        rpmnet_jax.RefineOptions(**bad)
    assert rpmnet_jax.RefineOptions().icp_kwargs() == {}
    assert rpmnet_jax.RefineOptions(scales=[2, 1], max_iterations=9).icp_kwargs() == dict(scales=(2.0, 1.0),
                                                                                         max_iterations=9)


def test_too_few_points_for_icp_ask_for_refine_none(random_weights):
    """Fewer points than ICP needs (``icp.MIN_PAIRS``): the default ``refine="icp"`` is refused up front, naming
    ICP and ``refine='none'``; the network alone (``refine="none", init="local"``) registers them."""
    rng = np.random.default_rng(0)
    turn = Rotation.from_euler("z", 10, degrees=True).as_matrix()
    for n in (4, 5):
        src = rng.normal(size=(n, 3))
        with pytest.raises(ValueError, match=r"ICP.*refine='none'"):
            rpmnet_jax.align(src, src @ turn.T + 0.1, checkpoint=random_weights)
    a = rpmnet_jax.align(src, src @ turn.T + 0.1, checkpoint=random_weights, refine="none", init="local",
                         network_options=rpmnet_jax.NetworkOptions(iters=1))
    rot = a.transform[:3, :3]
    assert np.all(np.isfinite(a.transform)) and a.num_points == (5, 5) and a.aligned.shape == (5, 3)
    np.testing.assert_allclose(rot @ rot.T, np.eye(3), atol=1e-5)  # float32 network answer
    assert a.init == "local" and "network" in a.stages and "classical" not in a.stages


def test_nan_rows_keep_the_callers_row_numbers(random_weights):
    """NaN/inf rows are dropped for the registration, but ``correspondences`` index the caller's arrays and
    ``aligned`` has every source row (NaN rows stay NaN): the same answer as on the pre-cleaned clouds."""
    src, src_n = synthetic_shape(seed=12, n=700)
    ref, _ = synthetic_shape(seed=13, n=650)
    ref = ref @ Rotation.from_euler("z", 15, degrees=True).as_matrix().T
    bad_src, bad_ref = [3, 50, 400], [0, 649]
    src_nan, ref_nan = src.copy(), ref.copy()
    src_nan[bad_src] = np.nan
    ref_nan[bad_ref, 1] = np.inf
    keep_s, keep_r = np.setdiff1d(np.arange(700), bad_src), np.setdiff1d(np.arange(650), bad_ref)
    kw = dict(checkpoint=random_weights, network_options=rpmnet_jax.NetworkOptions(256, 2), init="local")
    with pytest.warns(UserWarning, match="dropped"):
        a = rpmnet_jax.align(src_nan, ref_nan, src_n, None, **kw)
    b = rpmnet_jax.align(src[keep_s], ref[keep_r], src_n[keep_s], None, **kw)
    np.testing.assert_array_equal(a.transform, b.transform)
    assert a.aligned.shape == (700, 3) and np.isnan(a.aligned[bad_src]).all()
    np.testing.assert_array_equal(a.aligned[keep_s], b.aligned)
    assert len(a.correspondences) > 10
    np.testing.assert_array_equal(a.correspondences, np.stack([keep_s[b.correspondences[:, 0]],
                                                               keep_r[b.correspondences[:, 1]]], axis=1))
    pairs = np.linalg.norm(a.aligned[a.correspondences[:, 0]] - ref_nan[a.correspondences[:, 1]], axis=1)
    assert np.all(pairs <= a.max_correspondence_distance)


@pytest.mark.parametrize("cloud", ["source", "reference"])
def test_a_stray_far_point_does_not_change_the_answer(random_weights, cloud):
    """One point 100 radii away, inside the arrays: the same transform (the default pipeline with every
    stage run: classical, local (forced by ``network_fitness=1``) and, forced by ``auto_fitness=1``, the global
    search), the same
    correspondence distance, and the stray is scored as a source point without a partner."""
    src, src_n = synthetic_shape(seed=14, n=600)
    ref, ref_n = synthetic_shape(seed=15, n=600)
    ref = ref @ Rotation.from_euler("x", 40, degrees=True).as_matrix().T + 0.2
    kw = dict(checkpoint=random_weights, network_options=rpmnet_jax.NetworkOptions(iters=2),
              global_options=rpmnet_jax.GlobalOptions(auto_fitness=1.0, network_fitness=1.0))
    clean = rpmnet_jax.align(src, ref, src_n, ref_n, **kw)
    assert {"global", "classical", "network"} <= set(clean.stages)
    pts, nrm = (src, src_n) if cloud == "source" else (ref, ref_n)
    stray = pts.mean(0) + 100 * np.linalg.norm(pts - pts.mean(0), axis=1).max() * np.array([0.6, 0.0, 0.8])
    pts, nrm = np.insert(pts, 123, stray, axis=0), np.insert(nrm, 123, [1.0, 0.0, 0.0], axis=0)
    dirty = (rpmnet_jax.align(pts, ref, nrm, ref_n, **kw) if cloud == "source"
             else rpmnet_jax.align(src, pts, src_n, nrm, **kw))
    np.testing.assert_array_equal(dirty.transform, clean.transform)
    assert dirty.max_correspondence_distance == clean.max_correspondence_distance
    shifted = clean.correspondences.copy()
    shifted[:, 0 if cloud == "source" else 1] += shifted[:, 0 if cloud == "source" else 1] >= 123
    np.testing.assert_array_equal(dirty.correspondences, shifted)
    if cloud == "source":
        assert dirty.fitness == pytest.approx(clean.fitness * 600 / 601, abs=1e-12)


def test_deterministic_under_a_seed_and_the_global_screen_follows_it(random_weights):
    from rpmnet_jax.pairwise import global_search, prepare

    src, src_n = synthetic_shape(seed=16, n=500)
    ref, _ = synthetic_shape(seed=17, n=500)
    kw = dict(checkpoint=random_weights, network_options=rpmnet_jax.NetworkOptions(256, 2), init="global", seed=4)
    a, b = rpmnet_jax.align(src, ref, src_n, None, **kw), rpmnet_jax.align(src, ref, src_n, None, **kw)
    np.testing.assert_array_equal(a.transform, b.transform)
    np.testing.assert_array_equal(a.correspondences, b.correspondences)
    pair = prepare.prepare_pair(src, ref, src_n, None, num_points=256)
    dense = prepare.dense_clouds(pair, 5000, 0, prepare.RowNormals(pair.ref, pair.ref_normals))
    params = loading.load_params(random_weights)
    opts = rpmnet_jax.GlobalOptions(points=64)  # fewer than the 256 prepared: the seed picks which
    screen = lambda seed: np.stack([s.network_transforms for s in global_search.screen_hypotheses(
        params, pair, dense, rpmnet_jax.RPMNetConfig(), opts, 0.05, seed)])
    first = screen(0)
    np.testing.assert_array_equal(screen(0), first)
    assert not np.allclose(screen(1), first)


def _sliding_box_crops(rng, n: int):
    """Two overlapping crops of a box's surface (the source's x > -0.2, the reference's x < 0.2), the reference turned
    and moved: a pair that slides along the box, so its classical answer is ambiguous (``n`` points drawn each)."""
    half = np.array([1.0, 0.6, 0.3])

    def surface():
        p = rng.uniform(-1, 1, size=(n, 3)) * half
        axis = rng.integers(0, 3, n)
        p[np.arange(n), axis] = np.sign(rng.normal(size=n)) * half[axis]
        return p

    src, ref = surface(), surface()
    src, ref = src[src[:, 0] > -0.2], ref[ref[:, 0] < 0.2]
    rot = Rotation.from_euler("xyz", [20, 30, 40], degrees=True).as_matrix()
    return src, ref @ rot.T + [0.1, 0.2, 0.3]


def test_auto_keeps_the_classical_answer_of_dense_clouds_and_runs_the_network_on_sparse_ones():
    """An ambiguous classical answer runs the network on crops of 1,024-point size (the paper's inputs), not on
    dense clouds (both at least DENSE_FACTOR x the network's samples: scans), unless ``network_on_dense``."""
    from rpmnet_jax.pairwise import starts
    rng = np.random.default_rng(0)
    src, ref = _sliding_box_crops(rng, 12_000)
    assert min(len(src), len(ref)) >= starts.DENSE_FACTOR * rpmnet_jax.NetworkOptions().points
    kept = rpmnet_jax.align(src, ref)
    assert kept.ambiguous and "network" not in kept.timings and kept.init == "classical"
    asked = rpmnet_jax.align(src, ref, global_options=rpmnet_jax.GlobalOptions(network_on_dense=True))
    assert asked.ambiguous and "network" in asked.timings
    sparse_src, sparse_ref = (c[rng.choice(len(c), 1500, replace=False)] for c in (src, ref))
    assert "network" in rpmnet_jax.align(sparse_src, sparse_ref).timings
