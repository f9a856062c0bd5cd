"""Pairwise edges between scans: ICP from a start a few degrees off recovers a known transform, so does FPFH +
RANSAC at any angle, an edge's measured quality tells the truth from a wrong pose, so does the predicted overlap,
and batched network calls give each pair's own answer."""

import numpy as np
import pytest

import rpmnet_jax
from conftest import asymmetric_shape, cropped_pair, rotation_about, rotation_error_deg
from rpmnet_jax.pair_edges import edges
from rpmnet_jax.multiway import sizes
from rpmnet_jax.weights import loading

MAX_DISTANCE = 0.05  # the default correspondence distance: 5% of the unit radius


def _turned(transform, degrees, axis=(1.0, 1.0, 0.0), shift=(0.0, 0.0, 0.0)):
    step = np.eye(4)
    step[:3, :3], step[:3, 3] = rotation_about(axis, degrees), shift
    return transform @ step


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_icp_edge_recovers_a_known_transform(seed):
    scans, truth = cropped_pair(seed)
    start = _turned(truth, 6.0, shift=(0.03, 0.0, -0.03))  # a network-sized error
    e = edges.icp_edge(scans, 0, 1, start, MAX_DISTANCE, np.random.default_rng(0), num_points=256)
    assert (e.source, e.target, e.stage) == (0, 1, "refine")
    # measured 0.06-0.45° and 0.003 over these seeds: 256 of 420 source points on samples ~0.05 apart
    assert rotation_error_deg(e.transform[:3, :3], truth[:3, :3]) < 1.0
    assert np.linalg.norm(e.transform[:3, 3] - truth[:3, 3]) < 0.01
    # the acceptance rule of align_scans (right answers <= 0.06x on the bunny)
    assert e.plane_residual <= sizes.OBJECT_PLANE_RESIDUAL * MAX_DISTANCE


@pytest.mark.parametrize("degrees", [40.0, 150.0])
def test_classical_edge_recovers_a_known_transform_at_any_angle(degrees):
    scans, truth = cropped_pair(0)
    turn = np.eye(4)
    turn[:3, :3] = rotation_about([0.3, 1.0, -0.2], degrees - 40.0)  # scan 1 turned further: 40° or 150° in all
    moved = edges.make_scan(scans[1].points @ turn[:3, :3].T, scans[1].normals @ turn[:3, :3].T, 0.3, seed=1)
    scans = [edges.make_scan(scans[0].points, scans[0].normals, 0.3, seed=0), moved]
    truth = turn @ truth
    assert scans[0].features.shape == (len(scans[0].keypoints), 33)  # every point of a small scan at voxel 0
    found = edges.classical_edges(scans, 0, 1, MAX_DISTANCE, 0.075, np.random.default_rng(0), num_points=256,
                                  max_plane_residual=0.1)
    e = found[0]  # the best answer first
    assert (e.source, e.target, e.stage) == (0, 1, "classical") and 1 <= len(found) <= 3  # the identity, 2 RANSAC
    assert rotation_error_deg(e.transform[:3, :3], truth[:3, :3]) < 1.0
    assert np.linalg.norm(e.transform[:3, 3] - truth[:3, 3]) < 0.01
    without = edges.make_scan(scans[0].points, scans[0].normals)
    assert without.features is None and without.keypoints is None  # no radius: no features


def test_measure_tells_the_truth_from_a_wrong_pose():
    scans, truth = cropped_pair(0)
    right = edges.measure(scans, 0, 1, truth, MAX_DISTANCE, "network")
    wrong = edges.measure(scans, 0, 1, _turned(truth, 20.0), MAX_DISTANCE, "network")
    assert right.stage == "network" and right.information.shape == (6, 6)
    assert right.fitness > 0.5 > wrong.fitness  # the crops overlap by ~60%: measured 0.58 at the truth
    assert 0 < right.inlier_rmse < MAX_DISTANCE
    assert right.plane_residual < 0.2 * wrong.plane_residual
    # an asymmetric shape holds all 6 directions: positive definite
    assert np.linalg.eigvalsh(0.5 * (right.information + right.information.T)).min() > 0


def test_measure_on_every_kth_point_estimates_the_whole_scan():
    """Scored on every 4th point (``num_points`` a quarter of the scan's 4,200, 3 mm noise): the fitness, RMSE and
    residual of the whole scan to a few per cent (measured 0.4%, 1%, 7%), the information scaled back to all the
    points (9%); ``num_points`` at or above the scan's size: the same edge as without."""
    scans, truth = cropped_pair(0, 12000)
    rng = np.random.default_rng(0)
    scans = [edges.make_scan(s.points + rng.normal(0.0, 0.003, s.points.shape), s.normals) for s in scans]
    whole = edges.measure(scans, 0, 1, truth, 0.05, "joint")
    quarter = edges.measure(scans, 0, 1, truth, 0.05, "joint", num_points=len(scans[0].points) // 4)
    assert abs(quarter.fitness - whole.fitness) < 0.02 and quarter.inlier_rmse == pytest.approx(whole.inlier_rmse, 0.05)
    assert quarter.plane_residual == pytest.approx(whole.plane_residual, rel=0.1)
    assert np.linalg.norm(quarter.information - whole.information) < 0.15 * np.linalg.norm(whole.information)
    same = edges.measure(scans, 0, 1, truth, 0.05, "joint", num_points=len(scans[0].points))
    assert same.fitness == whole.fitness and np.array_equal(same.information, whole.information)


def test_predicted_overlap_is_larger_at_the_true_pose():
    scans, truth = cropped_pair(1)
    at_truth = edges.predicted_overlap(scans, 0, 1, truth, MAX_DISTANCE)
    assert at_truth > 0.5  # the crops' overlap (measured 0.58)
    assert at_truth > 2 * edges.predicted_overlap(scans, 0, 1, _turned(truth, 90.0, axis=(0, 0, 1)), MAX_DISTANCE)
    # either direction: the larger share of the two scans
    assert at_truth == edges.predicted_overlap(scans, 1, 0, np.linalg.inv(truth), MAX_DISTANCE)


def test_batched_network_calls_give_each_pair_its_own_answer(random_weights):
    """Three pairs in one padded call of 4 equal three calls of one pair each (random weights: the batching,
    not the model, is under test)."""
    cfg = rpmnet_jax.RPMNetConfig()
    params = loading.load_params(random_weights)
    scans = []
    for k in range(3):
        pts, nrm = asymmetric_shape(k, 300)
        rot = rotation_about([1.0, k, 0.5], 10.0 * k)
        scans.append(edges.make_scan(pts @ rot.T + 0.1 * k, nrm @ rot.T))
    pairs = [(0, 1), (0, 2), (1, 2)]
    kw = dict(cfg=cfg, num_points=64, num_iters=1, seed=0)
    batched = edges.network_starts(params, scans, pairs, batch_size=4, **kw)
    one_by_one = np.concatenate([edges.network_starts(params, scans, [p], batch_size=1, **kw) for p in pairs])
    assert batched.shape == (3, 4, 4)
    np.testing.assert_allclose(batched, one_by_one, rtol=0, atol=1e-5)  # float32 round-off (measured 8e-7)
    assert not np.allclose(batched[0], batched[1], atol=1e-3)  # the pairs' answers differ: none is a padding copy
    np.testing.assert_allclose(batched[:, 3], np.broadcast_to([0.0, 0.0, 0.0, 1.0], (3, 4)))
