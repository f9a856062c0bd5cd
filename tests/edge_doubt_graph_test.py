"""The pose graph's outcome on planted records: a flipped edge that alone joins a scan places it wrong and the scan is
reported as resting on a flagged edge; rejecting flagged edges leaves the scan out instead; a flipped edge among
consistent ones is rejected by the graph either way."""

import numpy as np

from conftest import random_pose, rotation_about
from rpmnet_jax.evaluation import edge_doubt_graph, edge_doubt_records as records

MAX_DISTANCE = 0.05


def _records(poses, answers):
    """Records of the pairs of ``poses (S, 4, 4)``; ``answers[(i, j)]``: ``[(transform, fitness), ...]`` (all pairs,
    as a scan set's records have them)."""
    out = []
    for (i, j), found in sorted(answers.items()):
        truth = np.linalg.inv(poses[j]) @ poses[i]
        out.append({"i": i, "j": j, "num_scans": len(poses), "max_distance": MAX_DISTANCE, "truth": truth.tolist(),
                    "candidate": True, "set": "planted",
                    "answers": [{"transform": np.asarray(t).tolist(), "fitness": f, "inlier_rmse": 0.01,
                                 "plane_residual": 0.001, "information": (1e4 * np.eye(6)).tolist(),
                                 "stage": "classical", "error_deg": records.rotation_error_deg(t, truth)}
                                for t, f in found]})
    return out


def _flip(t):
    out = np.array(t)
    out[:3, :3] = out[:3, :3] @ rotation_about([0.3, 1.0, 0.2], 150.0)
    return out


def test_rejecting_a_flagged_bridge_leaves_its_scan_out_instead_of_placing_it_wrong():
    rng = np.random.default_rng(0)
    poses = np.stack([random_pose(rng) for _ in range(4)])
    rel = lambda i, j: np.linalg.inv(poses[j]) @ poses[i]
    answers = {(i, j): [(rel(i, j), 0.8)] for i, j in ((0, 1), (0, 2), (1, 2))}
    answers[(2, 3)] = [(_flip(rel(2, 3)), 0.6), (rel(2, 3), 0.1)]  # the right answer fails the good rule
    answers[(0, 3)] = answers[(1, 3)] = []  # no answer: scan 3 hangs on the pair (2, 3)
    recs = _records(poses, answers)
    p = np.array([0.05, 0.05, 0.05, 0.9, 0.3])  # answers() order: (0,1) (0,2) (1,2) (2,3) flip, (2,3) right
    as_is = edge_doubt_graph.outcome(recs, p, threshold=0.5)
    assert (as_is["edges"], as_is["wrong_in"], as_is["wrong_kept"], as_is["placed"]) == (4, 1, 1, 4)
    assert as_is["wrong_poses"] == 1 and (as_is["resting"], as_is["resting_wrong"]) == (1, 1)
    rejected = edge_doubt_graph.outcome(recs, p, threshold=0.5, reject_at=0.5)
    assert (rejected["edges"], rejected["wrong_in"], rejected["placed"], rejected["wrong_poses"]) == (3, 0, 3, 0)
    assert rejected["resting"] == 0 and rejected["right_kept"] == 3


def test_a_flip_among_consistent_edges_is_rejected_by_the_graph():
    rng = np.random.default_rng(1)
    poses = np.stack([random_pose(rng) for _ in range(5)])
    rel = lambda i, j: np.linalg.inv(poses[j]) @ poses[i]
    answers = {(i, j): [(rel(i, j), 0.7)] for i in range(5) for j in range(i + 1, 5)}
    answers[(1, 3)] = [(_flip(rel(1, 3)), 0.9), (rel(1, 3), 0.7)]
    recs = _records(poses, answers)
    p = np.full(sum(len(r["answers"]) for r in recs), 0.05)
    for weigh in (False, True):
        out = edge_doubt_graph.outcome(recs, p, threshold=0.5, weigh=weigh)
        assert (out["edges"], out["wrong_in"], out["wrong_kept"], out["placed"], out["wrong_poses"]) == (
            11, 1, 0, 5, 0)
