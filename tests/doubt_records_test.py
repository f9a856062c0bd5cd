"""A record of an alignment gives back the features the alignment itself gives, and its errors."""

import json

import numpy as np

import rpmnet_jax
from conftest import asymmetric_shape, rotation_about
from rpmnet_jax.evaluation import doubt_records
from rpmnet_jax.pairwise import doubt


def test_record_round_trips_the_features_and_measures_the_error(tmp_path):
    pts, nrm = asymmetric_shape(seed=2, n=1500)
    truth = rotation_about([0, 1, 1], 25.0)
    a = rpmnet_jax.align(pts[:900], pts[600:] @ truth.T + 0.2, nrm[:900], nrm[600:] @ truth.T, init="classical")
    gt = np.c_[truth, [0.2, 0.2, 0.2]]
    rec = json.loads(json.dumps(doubt_records.record(a, gt, set="toy", idx=3)))  # JSON-safe
    np.testing.assert_allclose(doubt_records.features([rec])[0], doubt.features(a, *doubt.lever(a)), atol=1e-12)
    assert rec["error_deg"] < 1 and rec["set"] == "toy" and len(rec["candidate_errors_deg"]) == len(a.candidates)
    assert doubt_records.labels([rec, {**rec, "error_deg": 7.0}]).tolist() == [False, True]
    path = tmp_path / "r.jsonl"
    path.write_text(json.dumps(rec) + "\n")
    assert doubt_records.read(str(path)) == [rec] and doubt_records.read(str(tmp_path / "none.jsonl")) == []
