"""Records of a scan set's pair edges: JSON-safe, every pair once with its true motion, answers that rebuild into the
edges' features, errors measured against the truth, align_scans' good rule."""

import json

import numpy as np

from conftest import ring_scans
from rpmnet_jax.evaluation import edge_doubt_records as records
from rpmnet_jax.multiway import edge_doubt


def test_scan_set_records_every_pair_with_its_truth_and_answers(tmp_path):
    clouds, poses = ring_scans(4, asymmetric=True)
    ticks = []
    recs = records.scan_set(clouds, poses, tick=lambda done, total: ticks.append((done, total)), set="ring")
    recs = json.loads(json.dumps(recs))  # JSON-safe
    assert [(r["i"], r["j"]) for r in recs] == [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)]
    assert ticks[-1] == (6, 6) and all(r["set"] == "ring" and r["num_scans"] == 4 for r in recs)
    assert all(r["candidate"] for r in recs)  # 4 scans: every pair is a candidate
    for r in recs:
        np.testing.assert_allclose(r["truth"], np.linalg.inv(poses[r["j"]]) @ poses[r["i"]], atol=1e-12)
        for a in r["answers"]:
            assert a["error_deg"] == records.rotation_error_deg(a["transform"], r["truth"])
    # neighbours on the ring overlap most: the best answer of (0, 1) is right, and measured so
    best = recs[0]["answers"][0]
    assert best["error_deg"] < edge_doubt.WRONG_DEG and best["fitness"] > 0.3
    flat = records.answers(recs)
    n = sum(len(r["answers"]) for r in recs)
    assert len(flat) == n and records.features(recs).shape == (n, len(edge_doubt.FEATURES))
    assert records.labels(recs).tolist() == [a["error_deg"] > 5.0 for r in recs for a in r["answers"]]
    e = flat[0][2]
    np.testing.assert_allclose(records.features(recs)[0],
                               edge_doubt.features(e, recs[0]["max_distance"], records.edges_of(recs[0])))
    assert records.good(recs)[0] == (e.fitness >= 0.3 and e.plane_residual <= 0.1 * recs[0]["max_distance"])
    path = tmp_path / "r.jsonl"
    records.append(str(path), recs[:2])
    records.append(str(path), recs[2:])
    assert records.read(str(path)) == recs and records.read(str(tmp_path / "none.jsonl")) == []


def test_rotation_error_is_the_angle_between_the_rotations():
    a, b = np.eye(4), np.eye(4)
    b[:3, :3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]
    b[:3, 3] = [5, 5, 5]  # translation plays no part
    assert np.isclose(records.rotation_error_deg(a, b), 90.0) and records.rotation_error_deg(b, b) < 1e-6
