"""The edge doubt model (:mod:`rpmnet_jax.multiway.edge_doubt`): the lever read off an information matrix, features
of planted answers, finite features of a degenerate fit, the shipped JSON against scikit-learn's probabilities, a
90°-off edge flagged and the right one not, the scans that rest on flagged edges."""

import json
import pathlib
import types

import numpy as np
import pytest

from conftest import cropped_pair, rotation_about
from rpmnet_jax.classical import scoring
from rpmnet_jax.multiway import edge_doubt
from rpmnet_jax.pair_edges import edges
from rpmnet_jax.pairwise import doubt

EXAMPLES = pathlib.Path(__file__).parent / "data" / "edge_doubt_examples.json"
MAX_DISTANCE = 0.05


def _edge(rot_deg=0.0, fitness=0.8, information=None, plane=0.002, rmse=0.02):
    t = np.eye(4)
    t[:3, :3] = rotation_about([0, 0, 1], rot_deg)
    return types.SimpleNamespace(transform=t, fitness=fitness, inlier_rmse=rmse, plane_residual=plane,
                                 information=np.eye(6) if information is None else information)


def test_lever_finds_the_points_centre_and_spread_from_the_information_alone():
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(600, 3)) * [0.1, 0.05, 0.08] + [1.0, -2.0, 0.5]
    nrm = rng.normal(size=(600, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    corr = np.c_[np.arange(600), np.arange(600)]
    info = scoring.plane_fit(pts, pts + 1e-3 * rng.normal(size=pts.shape), nrm, np.eye(4), corr).information
    centre, radius = edge_doubt.lever(info)
    spread = np.sqrt(np.mean(np.sum((pts - pts.mean(0)) ** 2, axis=1)))
    # the least-squares pivot lies within a few percent of the spread of the points' mean: random normals
    assert np.linalg.norm(centre - pts.mean(0)) < 0.1 * spread
    assert radius == pytest.approx(spread, rel=0.1)
    # so the conditioning is the one-pair model's about the true centre and spread
    np.testing.assert_allclose(doubt.conditioning(info, centre, radius),
                               doubt.conditioning(info, pts.mean(0), spread), atol=0.02)


def test_features_read_the_pairs_other_answers():
    best, flip = _edge(0.0, 0.8), _edge(180.0, 0.6, rmse=0.03)
    f = dict(zip(edge_doubt.FEATURES, edge_doubt.features(flip, MAX_DISTANCE, [best, flip])))
    assert f["rank"] == 1.0 and f["other_fitness"] == 0.8 and f["fitness_margin"] == pytest.approx(-0.2)
    assert f["other_gap"] == pytest.approx(1.0) and f["distinct"] == pytest.approx(np.log1p(2))
    assert f["plane"] == pytest.approx(0.04) and f["rmse"] == pytest.approx(0.6) and f["good"] == 1.0
    assert f["rmse_excess"] == pytest.approx(0.2) and f["rmse_margin"] == pytest.approx(0.2)
    g = dict(zip(edge_doubt.FEATURES, edge_doubt.features(best, MAX_DISTANCE, [best, flip])))
    assert g["rank"] == 0.0 and g["fitness_margin"] == pytest.approx(0.2)
    assert g["rmse_excess"] == 0.0 and g["rmse_margin"] == pytest.approx(-0.2)
    alone = dict(zip(edge_doubt.FEATURES, edge_doubt.features(best, MAX_DISTANCE)))
    assert alone["other_fitness"] == 0.0 and alone["other_gap"] == 0.0 and alone["distinct"] == pytest.approx(
        np.log1p(1))
    assert alone["rmse_excess"] == 0.0 and alone["rmse_margin"] == 0.0
    assert dict(zip(edge_doubt.FEATURES, edge_doubt.features(_edge(plane=0.01), MAX_DISTANCE)))["good"] == 0.0


@pytest.mark.parametrize("information", [np.zeros((6, 6)), np.diag([1.0, 1, 1, 0, 0, 0]),
                                         np.diag([0.0, 0, 0, 1, 1, 1])])
def test_features_are_finite_for_a_degenerate_fit(information):
    e = _edge(information=information, plane=np.inf, fitness=0.0, rmse=0.0)
    f = edge_doubt.features(e, MAX_DISTANCE, [e])
    assert f.shape == (len(edge_doubt.FEATURES),) and np.all(np.isfinite(f))
    assert 0.0 <= edge_doubt.p_wrong(e, MAX_DISTANCE, [e]) <= 1.0


def test_shipped_model_loads_and_matches_scikit_learn():
    model = edge_doubt.load()
    spec = json.loads(pathlib.Path(edge_doubt.MODEL_PATH).read_text())
    assert 0 < model.threshold <= model.reject_threshold < 1 and spec["wrong_deg"] == edge_doubt.WRONG_DEG
    examples = json.loads(EXAMPLES.read_text())
    p = model.probability(np.asarray(examples["features"]))
    assert np.all((p >= 0) & (p <= 1))
    np.testing.assert_allclose(p, examples["p_wrong"], atol=1e-9)
    with pytest.raises(ValueError, match="features"):
        edge_doubt.Model({**spec, "features": spec["features"][::-1]})


def test_a_90_degree_off_edge_is_flagged_and_the_right_one_is_not():
    scans, truth = cropped_pair(0, 1600)
    turn = np.eye(4)
    turn[:3, :3] = rotation_about([1.0, 1.0, 0.0], 90.0)
    right = edges.measure(scans, 0, 1, truth, MAX_DISTANCE, "classical")
    wrong = edges.measure(scans, 0, 1, truth @ turn, MAX_DISTANCE, "classical")
    answers = [right, wrong]
    p_right = edge_doubt.p_wrong(right, MAX_DISTANCE, answers)
    p_wrong = edge_doubt.p_wrong(wrong, MAX_DISTANCE, answers)
    threshold = edge_doubt.load().threshold  # measured: 0.03 and 1.00
    assert p_wrong > p_right and p_wrong >= threshold > p_right
    np.testing.assert_allclose(edge_doubt.p_wrong_of_pairs([answers, [], [wrong]], MAX_DISTANCE)[0],
                               [p_right, p_wrong])
    assert [len(q) for q in edge_doubt.p_wrong_of_pairs([answers, [], [wrong]], MAX_DISTANCE)] == [2, 0, 1]


def test_scans_rest_on_flagged_edges_only_where_every_path_crosses_one():
    # 0-1-2 a triangle, 2-3 one edge, 3-4 and 4-5 a chain; 6 joined by nothing
    pairs = [(0, 1), (1, 2), (0, 2), (2, 3), (3, 4), (4, 5)]
    none = edge_doubt.resting_on_flagged(7, pairs, [False] * 6, 0)
    assert not none.any()
    triangle = edge_doubt.resting_on_flagged(7, pairs, [True, False, False, False, False, False], 0)
    assert not triangle.any()  # 1 still reaches 0 through 2
    bridge = edge_doubt.resting_on_flagged(7, pairs, [False, False, False, True, False, False], 0)
    assert bridge.tolist() == [False, False, False, True, True, True, False]
    assert edge_doubt.resting_on_flagged(7, pairs, [False] * 5 + [True], 3).tolist() == [False] * 5 + [True, False]
