"""Fit the likely-wrong model shipped as ``rpmnet_jax/weights/doubt.json`` (:mod:`rpmnet_jax.pairwise.doubt`),
from pairs of TRAINING files only.

    python -m experiments.fit_doubt collect --minutes 55 [--cache /tmp/rpmnet_doubt/train.jsonl]
    python -m experiments.fit_doubt collect-scans --minutes 30 [--cache ...] [--meshes 12]
    python -m experiments.fit_doubt collect-real --part tune [--cache .../real_tune.jsonl]
    python -m experiments.fit_doubt fit [--cache train.jsonl,real_tune.jsonl] [--output rpmnet_jax/weights/doubt.json]

``collect`` runs the default ``align`` on pairs made from the train files of ``--data-roots`` (all categories),
round-robin over :data:`CONFIGS` (partial and noisy, any orientation and ±45°, the paper's crop at 1,024 points and
a harder one: 512 points, 50% kept per cloud, where the default is wrong far more often) ten pairs at a time, until
``--minutes`` are spent; each answer goes to the JSON-lines ``--cache`` with its true error (pairs already there are
skipped, so it resumes). ``collect-scans`` adds pairs of simulated range scans
(:func:`experiments.network_trust.scan_pairs`: full density and 1,024 points) of the Poisson meshes of ``--meshes``
seeded train-file rows of ``real_meshes_train`` (never the rows ``network_trust`` checks the trust rule on, nor the
bunny), each pair answered twice: by the default ``align`` and by ``init="classical"`` (the answer ``auto`` keeps
when it trusts it; on scans it is mostly wrong, which the crops alone never show the model). ``collect-real``
adds scenes and real scans (:func:`real_jobs`): the TUNE parts of the real-scan benchmark (an object's range scans,
indoor RGB-D frames, outdoor LiDAR sweeps) and the simulated room's seed-0 stations, answered both ways; ``--part
report`` records the report parts and the room's seed 1 for ``experiments.eval_doubt --kinds``. ``fit`` (needs
scikit-learn: ``pip install -e ".[fit]"``) fits a logistic regression on the standardised features, maps its
out-of-fold scores to probabilities by Platt scaling (a shape's, or a scanned mesh's, pairs in one fold), picks the
threshold (the lowest on a 0.05 grid whose out-of-fold flags take at most 2% of the right answers of the paper's
settings) and writes plain numbers as JSON (no pickle), plus a small parity fixture for the tests.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
import zlib

import numpy as np

DATA_ROOTS = "../shared/data/modelnet40_real_subset,../shared/data/real_meshes_train"
# (setting, protocol, rot_mag, num_points, keep, seed): the paper's crop and a harder one
CONFIGS = (("std", "partial", 180.0, 1024, 0.7, 1), ("hard", "partial", 180.0, 512, 0.5, 2),
           ("std", "partial", 45.0, 1024, 0.7, 3), ("hard", "partial", 45.0, 512, 0.5, 4),
           ("std", "noisy", 180.0, 1024, 0.7, 5), ("std", "noisy", 45.0, 1024, 0.7, 6))
CHUNK = 10
SCAN_SEED = 7  # picks the scanned train-file rows
SCAN_INITS = ("auto", "classical")
FIXTURE = os.path.join("tests", "data", "doubt_examples.json")


def collect(a) -> None:
    from rpmnet_jax import data
    from rpmnet_jax.evaluation import doubt_records
    from rpmnet_jax.weights import loading
    params = loading.load_params(None)
    stop = time.time() + 60 * a.minutes
    sets = []
    for root in a.data_roots.split(","):
        names = data.ModelNet40(root, "train", "partial").class_names
        for setting, protocol, rot, n, keep, seed in CONFIGS:
            ds = data.ModelNet40(root, "train", protocol, num_points=n, rot_mag=rot, partial_keep=(keep, keep),
                                 seed=seed, categories=names)
            order = np.random.RandomState(seed).permutation(len(ds))
            sets.append((os.path.basename(os.path.normpath(root)), setting, seed, ds, order))
    for start in range(0, max(len(s[4]) for s in sets), CHUNK):
        for name, setting, seed, ds, order in sets:
            if time.time() > stop:
                return
            doubt_records.collect(ds, order[start:start + CHUNK], params, a.cache, progress=False, set=name,
                                  split="train", seed=seed, setting=setting)
        rows = doubt_records.read(a.cache)
        print(json.dumps({"pairs": len(rows), "wrong": int(doubt_records.labels(rows).sum()),
                          "minutes_left": round((stop - time.time()) / 60, 1)}), flush=True)


def scan_rows(count: int) -> list:
    """``count`` seeded rows of the train file of ``fit_edge_doubt.DATA_ROOT``, none of ``fit_edge_doubt.TRAIN_ROWS``
    (the meshes ``experiments.network_trust`` checks the trust rule on)."""
    from experiments import fit_edge_doubt
    rows = [r for r in range(len(fit_edge_doubt.shape_ids(fit_edge_doubt.DATA_ROOT)))
            if r not in fit_edge_doubt.TRAIN_ROWS]
    return sorted(np.random.RandomState(SCAN_SEED).choice(rows, count, replace=False).tolist())


def collect_scans(a) -> None:
    from experiments import network_trust
    from rpmnet_jax.evaluation import doubt_records
    from rpmnet_jax.weights import loading
    params = loading.load_params(None)
    stop = time.time() + 60 * a.minutes

    def jobs(row):
        for _, i, j, kind, src, ref, gt in network_trust.scan_pairs([row], 12):
            for init in SCAN_INITS:
                meta = {"set": "scans", "split": "train", "protocol": init, "rot_mag": None, "seed": row,
                        "setting": kind, "idx": 100 * i + j, "group": f"scans/{row}"}
                yield doubt_records.Job(meta, lambda src=src, ref=ref, gt=gt, init=init:
                                        (src, ref, None, None, gt, {"init": init}, {}))

    for row in scan_rows(a.meshes):
        if time.time() > stop:
            return
        doubt_records.collect_jobs(jobs(row), params, a.cache, progress=False, deadline=stop)
        rows = doubt_records.read(a.cache)
        print(json.dumps({"mesh": row, "pairs": len(rows), "wrong": int(doubt_records.labels(rows).sum()),
                          "minutes_left": round((stop - time.time()) / 60, 1)}), flush=True)


REAL_MAX_PAIRS = {"tune": 45, "report": 12}  # pairs per set: every overlapping tune pair; the benchmark's report pairs
ROOM_SEEDS = {"tune": 0, "report": 1}  # the simulated room's station pairs (rpmnet_jax.simulation.rooms)


def real_jobs(part: str, inits=SCAN_INITS):
    """:class:`doubt_records.Job` s of the real-scan benchmark's ``part`` (``benchmarks/real_scans``: an object's range
    scans, indoor RGB-D frames, outdoor LiDAR sweeps; its overlapping pairs as captured and with the source turned, as
    its ``run.py`` registers them) and of the simulated room's 15 station pairs (seed :data:`ROOM_SEEDS`), each
    answered with every init of ``inits``. ``setting`` is the data's kind, ``group`` its set (one fold each)."""
    import sys
    from rpmnet_jax.evaluation import doubt_records
    from rpmnet_jax.simulation import rooms
    sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "benchmarks",
                                    "real_scans"))
    import sets

    def job(meta, src, ref, truth):
        for init in inits:
            yield doubt_records.Job({**meta, "protocol": init}, lambda src=src, ref=ref, truth=truth, init=init:
                                    (src, ref, None, None, truth, {"init": init}, {}))

    for name in sets.available():
        s = sets.load(name, part)
        for k, (a, b) in enumerate(sets.pairs(s, REAL_MAX_PAIRS[part])):
            truth = np.linalg.inv(s.poses[b]) @ s.poses[a]
            for mode in ("captured", "turned"):
                src, motion = (s.clouds[a], np.eye(4)) if mode == "captured" else sets.turn(s.clouds[a], seed=k)
                meta = {"set": name, "split": part, "rot_mag": None, "seed": 0, "setting": s.kind, "group": name,
                        "idx": 2 * (len(s.names) * a + b) + (mode == "turned"), "mode": mode}
                yield from job(meta, src, s.clouds[b], truth @ np.linalg.inv(motion))
    stations = rooms.stations(ROOM_SEEDS[part])
    for a in range(len(stations)):
        for b in range(a + 1, len(stations)):
            truth = np.linalg.inv(stations[b].pose) @ stations[a].pose
            meta = {"set": "room", "split": part, "rot_mag": None, "seed": ROOM_SEEDS[part], "setting": "room",
                    "group": "room", "idx": 2 * (len(stations) * a + b), "mode": "captured"}
            yield from job(meta, stations[a].points, stations[b].points, truth)


def collect_real(a) -> None:
    from rpmnet_jax.evaluation import doubt_records
    from rpmnet_jax.weights import loading
    inits = SCAN_INITS if a.part == "tune" else ("auto",)  # the report part: the answers align gives
    new = doubt_records.collect_jobs(real_jobs(a.part, inits), loading.load_params(None), a.cache, progress=False)
    rows = doubt_records.read(a.cache)
    print(json.dumps({"part": a.part, "new": len(new), "pairs": len(rows),
                      "wrong": int(doubt_records.labels(rows).sum())}))


def fit(a) -> None:
    from rpmnet_jax.evaluation import calibration, doubt_records
    from rpmnet_jax.pairwise import doubt
    rows = [r for path in a.cache.split(",") for r in doubt_records.read(path)]
    x, y = doubt_records.features(rows), doubt_records.labels(rows)
    groups = np.array([zlib.crc32(r.get("group", f"{r['set']}/{r['idx']}").encode()) % 10
                       for r in rows])  # a shape (a scanned mesh) in one fold
    fitted = calibration.fit_logistic_platt(x, y, groups, 5, a.c, 2000)
    scaler, scale, lr, platt = fitted.scaler, fitted.scale, fitted.lr, fitted.platt
    p_oof = calibration.held_out_platt(fitted.scores, y, groups % 5)
    setting = np.array([r["setting"] for r in rows])
    threshold = (a.threshold if a.threshold is not None
                 else calibration.lowest_bar(p_oof, ~y & (setting == "std"), MAX_FLAGGED_RIGHT))
    spec = {"features": list(doubt.FEATURES), **fitted.spec(), "threshold": threshold, "wrong_deg": doubt.WRONG_DEG,
            "fitted_on": {"pairs": len(y), "wrong": int(y.sum()), "sources": sorted({r["set"] for r in rows}),
                          "split": "train", "c": a.c}}
    with open(a.output, "w") as f:
        json.dump(spec, f)
    flagged = p_oof >= threshold
    for name, m in (("all", np.ones(len(y), bool)), *((s, setting == s) for s in sorted(set(setting)))):
        print(json.dumps({"out_of_fold": name, "pairs": int(m.sum()), "wrong": int(y[m].sum()),
                          "auroc": round(calibration.auroc(p_oof[m], y[m]), 4),
                          "ece": round(calibration.ece(p_oof[m], y[m]), 4),
                          "flagged_wrong": round(float(flagged[m & y].mean()), 4) if (m & y).any() else None,
                          "flagged_right": round(float(flagged[m & ~y].mean()), 4)}))
    for t in (0.2, 0.3, 0.4, 0.5, 0.6):  # how the bar trades wrong answers caught for right ones flagged
        f = p_oof >= t
        print(json.dumps({"threshold": t, "flagged_wrong": round(float(f[y].mean()), 4),
                          "flagged_right": round(float(f[~y].mean()), 4),
                          "flagged_right_std": round(float(f[~y & (setting == "std")].mean()), 4)}))
    print(json.dumps({"coef": dict(zip(doubt.FEATURES, np.round(lr.coef_[0], 3).tolist()))}))
    pick = np.random.RandomState(0).choice(len(y), size=min(40, len(y)), replace=False)
    model = doubt.Model(spec)
    os.makedirs(os.path.dirname(FIXTURE), exist_ok=True)
    with open(FIXTURE, "w") as f:  # the parity test: sklearn's probabilities of these features
        json.dump({"features": np.round(x[pick], 6).tolist(),
                   "p_wrong": platt.predict_proba(lr.decision_function(
                       (np.round(x[pick], 6) - scaler.mean_) / scale)[:, None])[:, 1].tolist(),
                   "p_numpy": model.probability(np.round(x[pick], 6)).tolist()}, f)


MAX_FLAGGED_RIGHT = 0.02  # the default bar flags at most this share of the right answers of the paper's settings


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("command", choices=("collect", "collect-scans", "collect-real", "fit"))
    p.add_argument("--cache", default=None, help="the records (fit: several, comma-separated; default "
                   "TMPDIR/rpmnet_doubt/train.jsonl, for collect-real real_PART.jsonl: never the training file)")
    p.add_argument("--data-roots", default=DATA_ROOTS)
    p.add_argument("--minutes", type=float, default=55.0)
    p.add_argument("--meshes", type=int, default=12, help="collect-scans: train-file meshes to scan")
    p.add_argument("--part", default="tune", choices=("tune", "report"), help="collect-real: which part")
    p.add_argument("--output", default=os.path.join("rpmnet_jax", "weights", "doubt.json"))
    p.add_argument("--c", type=float, default=0.1, help="inverse L2 strength of the logistic regression")
    p.add_argument("--threshold", type=float, default=None,
                   help="the likely_wrong bar (default: the lowest flagging <= 2%% of right training answers)")
    a = p.parse_args(argv)
    folder = os.path.join(tempfile.gettempdir(), "rpmnet_doubt")
    a.cache = a.cache or os.path.join(folder, f"real_{a.part}.jsonl" if a.command == "collect-real" else "train.jsonl")
    os.makedirs(os.path.dirname(os.path.abspath(a.cache.split(",")[0])), exist_ok=True)
    {"collect": collect, "collect-scans": collect_scans, "collect-real": collect_real, "fit": fit}[a.command](a)


if __name__ == "__main__":
    main()
