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


def test_collect_jobs_skips_recorded_pairs_and_stops_at_the_deadline(tmp_path):
    """Each job's pair is aligned with its keywords and recorded with its meta and extra fields; a second run over
    the same jobs loads and aligns none of them; past the deadline nothing starts."""
    pts, nrm = asymmetric_shape(seed=3, n=1200)
    truth = rotation_about([1, 0, 1], 20.0)
    loaded = []

    def job(idx):
        def load():
            loaded.append(idx)
            return (pts[:800], pts[400:] @ truth.T, nrm[:800], nrm[400:] @ truth.T, np.c_[truth, np.zeros(3)],
                    {"init": "classical"}, {"label": "toy"})
        return doubt_records.Job({"set": "toy", "split": "train", "idx": idx}, load)

    path = str(tmp_path / "r.jsonl")
    new = doubt_records.collect_jobs([job(0), job(1)], None, path, progress=False)
    assert [r["idx"] for r in new] == [0, 1] and loaded == [0, 1]
    assert all(r["label"] == "toy" and r["init"] == "classical" and r["error_deg"] < 1 and r["seconds"] > 0
               for r in new)
    assert doubt_records.collect_jobs([job(0), job(1)], None, path, progress=False) == [] and loaded == [0, 1]
    assert doubt_records.collect_jobs([job(2)], None, path, progress=False, deadline=0.0) == [] and loaded == [0, 1]
    assert [r["idx"] for r in doubt_records.read(path)] == [0, 1]


def test_collect_runs_align_on_a_datasets_pairs_at_its_number_of_points(tmp_path):
    """``collect`` (the fitting and evaluation scripts' path) aligns each dataset pair with the network seeing the
    dataset's number of points, and records the protocol, index and class."""
    pts, nrm = asymmetric_shape(seed=4, n=1000)
    truth = rotation_about([0, 1, 0], 15.0)

    class Pairs:  # the part of data.ModelNet40 that collect reads
        protocol, rot_mag, class_names = "partial", 45.0, ["toy"]

        def __getitem__(self, i):
            src = np.c_[pts[:700], nrm[:700]]
            ref = np.c_[pts[300:] @ truth.T, nrm[300:] @ truth.T]
            return {"points_src": src, "points_ref": ref, "transform_gt": np.c_[truth, np.zeros(3)], "label": 0}

    path = str(tmp_path / "r.jsonl")
    new = doubt_records.collect(Pairs(), [0], None, path, progress=False, set="toy", split="train")
    assert len(new) == 1 and new[0]["idx"] == 0 and new[0]["protocol"] == "partial" and new[0]["label"] == "toy"
    assert new[0]["error_deg"] < 1
