"""Joining groups of scans the pose graph left apart (step 3c): a group's ends (``placement.group_ends``) and a
group's frame where two edges from different scans agree (``placement.voted_frame``)."""

import numpy as np

from rpmnet_jax.multiway import candidate_pairs, placement
from rpmnet_jax.pair_edges.edges import Edge


def test_a_streets_group_ends_at_its_first_and_last_station_and_a_corner():
    sensors = {m: np.array([0.0, 0.0, 1.5]) for m in range(16)}  # each scan's sensor in its own coordinates
    street = placement.Group(tuple(range(10, 16)), np.stack([_pose(17.0 * k, 10.0 * k, 0) for k in range(6)]))
    assert placement.group_ends(street, sensors, 15.0) == [10, 15]  # each station turned its own way
    corner = placement.Group((0, 1, 2, 3, 4), np.stack([_pose(0, x, y) for x, y in
                                                        [(0, 0), (10, 0), (20, 0), (20, 10), (20, 20)]]))
    assert placement.group_ends(corner, sensors, 15.0) == [0, 2, 4]  # the corner sees an open arm
    assert placement.group_ends(corner, sensors, 9.0) == [0, 1, 2, 3, 4]  # none within reach of another: each an end
    assert placement.group_ends(placement.Group((7,), np.eye(4)[None]), sensors, 15.0) == [7]


def _edge(i, j, transform, balanced=0.8):
    return Edge(i, j, transform, balanced, 0.0, np.eye(6), 0.0, "classical", balanced_fitness=balanced)


def _pose(yaw_deg, x, y):
    c, s = np.cos(np.radians(yaw_deg)), np.sin(np.radians(yaw_deg))
    out = np.eye(4)
    out[:2, :2] = [[c, -s], [s, c]]
    out[:2, 3] = x, y
    return out


def _scene():
    """Scans 0, 1 placed at their truth; a group of 2 and 3 in its own frame (2 at its origin)."""
    truth = np.stack([_pose(0, 0, 0), _pose(10, 10, 0), _pose(30, 5, 8), _pose(40, 14, 9)])
    poses = np.full((4, 4, 4), np.nan)
    poses[:2] = truth[:2]
    group = placement.Group((2, 3), np.stack([np.eye(4), np.linalg.inv(truth[2]) @ truth[3]]))
    return truth, poses, group


def _true_edge(truth, i, j, balanced=0.8):
    return _edge(i, j, np.linalg.inv(truth[j]) @ truth[i], balanced)


def test_two_agreeing_edges_from_different_scans_place_a_group():
    truth, poses, group = _scene()
    wrong = _edge(2, 0, _pose(180, 50, 0), 0.9)
    edges = [_true_edge(truth, 2, 0), _true_edge(truth, 1, 3), wrong]  # one each way round
    frame, agreeing = placement.voted_frame(poses, group, edges, 1.0, 0.5)
    np.testing.assert_allclose(frame @ group.poses, truth[2:], atol=1e-9)
    assert [(e.source, e.target) for e in agreeing] == [(2, 0), (1, 3)]


def test_one_edge_or_edges_of_one_scan_place_nothing():
    truth, poses, group = _scene()
    assert placement.voted_frame(poses, group, [_true_edge(truth, 2, 0)], 1.0, 0.5) is None
    both_from_2 = [_true_edge(truth, 2, 0), _true_edge(truth, 2, 1)]  # one member: not independent
    assert placement.voted_frame(poses, group, both_from_2, 1.0, 0.5) is None


def test_disagreeing_edges_place_nothing_and_the_best_supported_frame_wins():
    truth, poses, group = _scene()
    off = _edge(3, 1, np.linalg.inv(truth[1]) @ _pose(0, 2, 0) @ truth[3])  # 2 m off
    assert placement.voted_frame(poses, group, [_true_edge(truth, 2, 0), off], 1.0, 0.5) is None
    # a look-alike pair (2, 1) and (3, 0) agreeing on a wrong frame, with less balanced fitness
    lie = _pose(90, 100, 0)
    liars = [_edge(2, 1, np.linalg.inv(truth[1]) @ lie @ truth[2], 0.3),
             _edge(3, 0, np.linalg.inv(truth[0]) @ lie @ truth[3], 0.3)]
    frame, _ = placement.voted_frame(poses, group, liars + [_true_edge(truth, 2, 0), _true_edge(truth, 3, 1)],
                                     1.0, 0.5)
    np.testing.assert_allclose(frame @ group.poses, truth[2:], atol=1e-9)


def test_a_single_scan_needs_two_placed_scans_that_agree():
    truth, poses, _ = _scene()
    single = placement.Group((2,), np.eye(4)[None])
    assert placement.voted_frame(poses, single, [_true_edge(truth, 2, 0)], 1.0, 0.5) is None
    frame, _ = placement.voted_frame(poses, single, [_true_edge(truth, 2, 0), _true_edge(truth, 2, 1)], 1.0, 0.5)
    np.testing.assert_allclose(frame, truth[2], atol=1e-9)
