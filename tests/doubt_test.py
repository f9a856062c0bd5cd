"""The likely-wrong flag (:mod:`rpmnet_jax.pairwise.doubt`): its features on planted cases, the fit's conditioning,
a planted flip flagged and a right answer not, the shipped JSON model against scikit-learn's probabilities, the
``rpmnet-register`` warning."""

import json
import pathlib
import types

import numpy as np
import pytest

import rpmnet_jax
from conftest import asymmetric_shape, rotation_about
from rpmnet_jax.classical import scoring
from rpmnet_jax.ops import se3
from rpmnet_jax.pairwise import alignment, doubt, starts

EXAMPLES = pathlib.Path(__file__).parent / "data" / "doubt_examples.json"


def _answer(rot, score, fitness, rmse, init, support):
    t = np.eye(4)
    t[:3, :3] = rot
    return alignment.Answer(t, score, fitness, rmse, init, support)


def test_features_of_a_planted_pair_of_answers():
    """Two answers 180° apart: the second's share, the gap, the starts' agreement are read off."""
    flip = rotation_about([0, 0, 1], 180.0)
    a = types.SimpleNamespace(
        candidates=(_answer(np.eye(3), 0.6, 0.9, 0.01, "classical", ("classical", "local", "classical")),
                    _answer(flip, 0.3, 0.8, 0.02, "global", ("global",))),
        fitness=0.85, inlier_rmse=0.012, max_correspondence_distance=0.05, information=np.eye(6), confidence=0.4,
        init="classical", stages=("prepare", "classical", "refine", "network", "score"), converged=True,
        ambiguous=False)
    f = dict(zip(doubt.FEATURES, doubt.features(a, np.zeros(3), 1.0)))
    assert f["tight"] == 0.6 and f["fitness_dense"] == 0.9 and f["fitness"] == 0.85
    assert f["second_share"] == pytest.approx(0.5) and f["second_gap"] == pytest.approx(1.0)
    assert f["second_fitness_share"] == pytest.approx(0.8 / 0.9) and f["tight_share"] == pytest.approx(0.6 / 0.9)
    assert f["rmse_dense"] == pytest.approx(0.2) and f["rmse"] == pytest.approx(0.24)
    assert f["support"] == pytest.approx(np.log1p(3)) and f["support_margin"] == pytest.approx(0.5)
    assert f["agree"] == 1.0 and f["confidence"] == 0.4 and f["converged"] == 1.0 and f["ambiguous"] == 0.0
    assert f["conditioning"] == 0.0  # the identity information: perfectly conditioned
    one = a.candidates[:1]
    g = dict(zip(doubt.FEATURES, doubt.features(types.SimpleNamespace(**{**vars(a), "candidates": one}),
                                                np.zeros(3), 1.0)))
    assert g["second_share"] == 0.0 and g["second_gap"] == 0.0 and g["distinct"] == pytest.approx(np.log1p(1))


def test_conditioning_sees_a_sliding_plane_and_ignores_where_the_cloud_lies():
    """A plane slides along itself (log ratio at the floor); a box does not, and moving it far from the origin
    changes nothing (the rotation is measured about the inliers' centre)."""
    rng = np.random.default_rng(0)
    plane = np.c_[rng.uniform(-1, 1, (400, 2)), np.zeros(400)]
    up = np.tile([0.0, 0.0, 1.0], (400, 1))
    corr = np.c_[np.arange(400), np.arange(400)]
    flat = scoring.plane_fit(plane, plane + 1e-3 * rng.normal(size=plane.shape), up, np.eye(4), corr).information
    assert doubt.conditioning(flat, plane.mean(0), 1.0)[0] < -6
    pts, nrm = asymmetric_shape(n=900)
    noisy = pts + 1e-3 * rng.normal(size=pts.shape)
    corr = np.c_[np.arange(len(pts)), np.arange(len(pts))]
    near = doubt.conditioning(scoring.plane_fit(pts, noisy, nrm, np.eye(4), corr).information, pts.mean(0), 0.5)
    off = np.array([500.0, -300.0, 40.0])
    far = doubt.conditioning(scoring.plane_fit(pts + off, noisy + off, nrm, np.eye(4), corr).information,
                             pts.mean(0) + off, 0.5)
    assert near[0] > -3
    np.testing.assert_allclose(far, near, atol=1e-4)


def _box(rng, n, half=(0.5, 0.3, 0.18)):
    """``points, normals (n, 3)`` on the faces of a box with three different sides: it fits itself turned 180°
    about each axis."""
    half = np.asarray(half)
    area = np.array([half[1] * half[2], half[0] * half[2], half[0] * half[1]])
    axis, sign = rng.choice(3, n, p=area / area.sum()), rng.choice([-1.0, 1.0], n)
    points = rng.uniform(-1, 1, (n, 3)) * half
    points[np.arange(n), axis] = sign * half[axis]
    normals = np.zeros((n, 3))
    normals[np.arange(n), axis] = sign
    return points, normals


def _planted(monkeypatch, src, ref, rotations):
    """``align`` (classical only, no network) of ``src (points, normals)`` onto ``ref`` turned by ``TRUTH``, whose
    classical hypotheses are ``rotations`` (normalised frame; the clouds' centres coincide), and its error (deg)."""
    hyps = []
    for rot in rotations:
        t = np.eye(4)
        t[:3, :3] = rot
        hyps.append(starts.Start("classical", t[None, :3], 0.3, t))
    monkeypatch.setattr(starts, "classical_starts", lambda pair, count, seed: hyps)
    a = rpmnet_jax.align(src[0], ref[0] @ TRUTH.T, src[1], ref[1] @ TRUTH.T, init="classical")
    return a, float(se3.rotation_angle_deg(a.transform[:3, :3].T @ TRUTH))


TRUTH = rotation_about([1, 2, 3], 70.0)


def test_a_right_answer_is_not_flagged_and_a_planted_flip_is(monkeypatch):
    """An asymmetric shape from the truth: right, ``p_wrong`` near 0. A box planted with its flip (the truth turned
    180° about an axis, which fits exactly as well) beside the truth: whichever wins is a coin toss, and the flag
    must say so."""
    rng = np.random.default_rng(0)
    pts, nrm = asymmetric_shape(seed=3, n=3000)
    i, j = rng.choice(len(pts), 1200, replace=False), rng.choice(len(pts), 1200, replace=False)
    right, err = _planted(monkeypatch, (pts[i], nrm[i]), (pts[j], nrm[j]), [TRUTH])
    assert err < 1 and right.p_wrong < 0.02 and not right.likely_wrong
    flip = TRUTH @ rotation_about([0, 0, 1], 180.0)
    toss, err = _planted(monkeypatch, _box(rng, 1500), _box(rng, 1500), [flip, TRUTH])
    assert min(err, abs(180 - err)) < 1 and toss.ambiguous and len(toss.candidates) == 2
    assert toss.likely_wrong and toss.p_wrong > 5 * right.p_wrong + 0.1


def test_shipped_model_gives_scikit_learns_probabilities():
    """The JSON model evaluated with NumPy reproduces the fitted scikit-learn model's probabilities on stored
    examples (saved by ``experiments/fit_doubt.py`` beside the model)."""
    ex = json.loads(EXAMPLES.read_text())
    model = doubt.load()
    p = model.probability(np.asarray(ex["features"]))
    np.testing.assert_allclose(p, ex["p_wrong"], atol=1e-9)
    assert 0.0 < model.threshold < 1.0 and np.ptp(p) > 0.1  # not a constant model


def test_a_model_of_other_features_is_refused(tmp_path):
    spec = json.loads(pathlib.Path(doubt.MODEL_PATH).read_text())
    spec["features"] = spec["features"][:-1]
    path = tmp_path / "m.json"
    path.write_text(json.dumps(spec))
    with pytest.raises(ValueError, match="features"):
        doubt.load(str(path))


@pytest.mark.parametrize("threshold", [0.0, 1.1])
def test_register_cli_warns_when_likely_wrong_and_writes_p_wrong(tmp_path, capsys, monkeypatch, threshold):
    from rpmnet_jax.cli import register
    model = doubt.load()
    monkeypatch.setattr(doubt, "load", lambda path=None: types.SimpleNamespace(
        probability=model.probability, threshold=threshold))
    pts, nrm = asymmetric_shape(seed=1, n=900)
    src, ref = tmp_path / "src.npy", tmp_path / "ref.npy"
    np.save(src, np.c_[pts, nrm])
    np.save(ref, np.c_[pts @ rotation_about([0, 0, 1], 20.0).T, nrm @ rotation_about([0, 0, 1], 20.0).T])
    out_t, out_c = tmp_path / "t.json", tmp_path / "c.json"
    code = register.main([str(src), str(ref), "--init", "classical", "--out-transform", str(out_t),
                          "--out-candidates", str(out_c)])
    err = capsys.readouterr().err
    assert code == 0 and ("likely wrong" in err) == (threshold == 0.0)
    for path in (out_t, out_c):
        written = json.loads(path.read_text())
        assert 0.0 <= written["p_wrong"] <= 1.0 and written["likely_wrong"] == (threshold == 0.0)
