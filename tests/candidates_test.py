"""Choosing among refined starts: the selection score tells a right answer from a near-symmetric flip, distinct
answers are more than ``AMBIGUITY_DEG`` apart, ambiguity is a second answer close to the best's score."""

import numpy as np

from conftest import rotation_about
from rpmnet_jax.data import synthetic
from rpmnet_jax.geometry import kdtree
from rpmnet_jax.pairwise import candidates, prepare


def _tapered_box(rng, n, taper=0.08):
    """``(n, 3)`` points on a 1.2 × 0.6 × 0.4 box whose width grows along x by ``taper`` per unit: turned by 180°
    about z, its side faces move by 0.3 × 2 × taper × |x| (up to 0.029): within the 0.05 distance everywhere,
    beyond the tight 0.4 × 0.05 = 0.02 toward its ends."""
    p = synthetic._box_surface(rng, n, [1.2, 0.6, 0.4])[:, :3]
    p[:, 1] *= 1 + taper * p[:, 0]
    return p


def test_the_selection_score_prefers_the_right_answer_over_a_flip():
    """256 noisy points of a 70% crop against another noisy sample of the surface: at the full distance the flip
    fits every point as well as the truth does; the tight fraction of the distance tells them apart."""
    rng = np.random.default_rng(0)
    src = _tapered_box(rng, 2000)
    d = src @ rng.normal(size=3)
    src = src[d > np.quantile(d, 0.3)]
    src = src[rng.choice(len(src), 256, replace=False)] + rng.normal(scale=0.01, size=(256, 3))
    ref = _tapered_box(rng, 4000) + rng.normal(scale=0.01, size=(4000, 3))
    dense = prepare.DenseClouds(src, ref, np.zeros_like(ref), kdtree.KdTree(ref), np.zeros_like(src))  # normals unused
    flip = np.eye(4)
    flip[:3, :3] = rotation_about([0.0, 0.0, 1.0], 180.0)
    right = candidates.selection_score(dense, np.eye(4), 0.05)
    wrong = candidates.selection_score(dense, flip, 0.05)
    assert right[1] == wrong[1] == 1.0  # the plain fitness cannot tell
    assert right[0] > wrong[0] + 0.05 and right > wrong  # measured 0.66 against 0.55


def _candidate(degrees, score, init="classical"):
    t = np.eye(4)
    t[:3, :3] = rotation_about([0.2, 1.0, -0.3], degrees)
    return candidates.Candidate(t, (score, score, -0.01), init, t[None, :3], 0.5, True, 0)


def test_distinct_drops_a_worse_candidate_within_the_ambiguity_angle():
    near = candidates.AMBIGUITY_DEG - 1.0  # from the best one
    far = candidates.AMBIGUITY_DEG + 1.0
    best, close, apart = _candidate(0.0, 0.9), _candidate(near, 0.8), _candidate(far, 0.7)
    ranked = candidates.distinct([apart, close, best])  # any input order: ranked by score
    assert ranked == [best, apart]
    # ties keep the earlier one
    first, second = _candidate(0.0, 0.5, "local"), _candidate(0.5, 0.5, "global")
    assert candidates.distinct([first, second]) == [first]


def test_is_ambiguous_when_a_second_answer_reaches_the_share_of_the_best():
    share = candidates.AMBIGUITY_SHARE
    best = _candidate(0.0, 0.8)
    assert candidates.is_ambiguous([best, _candidate(90.0, share * 0.8 + 1e-9)])
    assert not candidates.is_ambiguous([best, _candidate(90.0, share * 0.8 - 1e-3)])
    assert not candidates.is_ambiguous([best])
    assert not candidates.is_ambiguous([_candidate(0.0, 0.0), _candidate(90.0, 0.0)])  # nothing fits at all


def _dense_pair():
    """An asymmetric shape and a rotated partial copy, prepared as ``align`` prepares them: ``(inputs, rot)``."""
    from conftest import asymmetric_shape
    pts, nrm = asymmetric_shape(2, 4000)
    rot = rotation_about([0.3, 1.0, 0.2], 30.0)
    return prepare.for_alignment(pts[:3000], pts[1000:] @ rot.T, nrm[:3000], nrm[1000:] @ rot.T, num_points=1024,
                                 sampling="random", seed=0, reestimate_normals=False, centering="separate",
                                 icp=True, dense_points=5000, max_correspondence_distance=None,
                                 relative_distance=0.05), rot


def _start(t44, init="classical"):
    from rpmnet_jax.pairwise import starts
    return starts.Start(init, t44[None, :3], 0.5, t44)


def test_a_refinement_checked_in_pieces_ends_where_one_run_ends():
    """With a bar nothing falls below, the pieces (half a stage, the rest, the fine stage) give one run's answer."""
    from rpmnet_jax import RefineOptions
    inputs, _ = _dense_pair()
    start = np.eye(4)
    start[:3, :3] = rotation_about([1.0, 0.0, 0.0], 8.0)
    for opts in (RefineOptions(), RefineOptions(max_iterations=1)):  # one iteration a stage: no second half
        whole, whole_score = candidates._icp_unless_hopeless(inputs.dense, start, inputs.max_distance_unit, opts,
                                                             None)
        pieces, pieces_score = candidates._icp_unless_hopeless(inputs.dense, start, inputs.max_distance_unit, opts,
                                                               0.0)
        np.testing.assert_allclose(pieces.transform, whole.transform, atol=1e-12)
        assert (pieces.converged, pieces.num_iterations, pieces_score) == (whole.converged, whole.num_iterations,
                                                                           whole_score)


def test_a_hopeless_candidate_after_a_strong_one_stops_early_and_the_strong_one_wins():
    from rpmnet_jax import RefineOptions
    from rpmnet_jax.ops import se3
    inputs, rot = _dense_pair()
    good = np.eye(4)
    good[:3, :3] = rot @ rotation_about([1.0, 0.0, 0.0], 5.0)  # near the truth: refines to a strong answer
    bad = np.eye(4)
    bad[:3, :3] = rot @ rotation_about([0.0, 0.0, 1.0], 150.0)  # far off: it cannot win
    args = (inputs.dense, inputs.max_distance_unit, "icp", RefineOptions())
    never = candidates.refine_starts([_start(good), _start(bad)], *args)
    checked = candidates.refine_starts([_start(good), _start(bad)], *args, strong=0.6)
    assert never[0].score[1] >= 0.6  # the strong one, refined as before
    np.testing.assert_array_equal(checked[0].transform, never[0].transform)
    assert checked[0].score == never[0].score
    assert checked[1].num_iterations < never[1].num_iterations  # the hopeless one stopped early
    assert checked[1].score[0] < candidates.HOPELESS_SHARE * checked[0].score[0]
    assert not checked[1].converged
    assert se3.rotation_angle_deg(checked[0].transform[:3, :3] @ rot.T) < 1.0  # the normalised frame keeps rotations
    # a candidate before any strong one is never checked
    first = candidates.refine_starts([_start(bad), _start(good)], *args, strong=0.6)
    assert first[0].num_iterations == never[1].num_iterations
