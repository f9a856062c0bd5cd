"""Fit the edge doubt model shipped as ``rpmnet_jax/weights/edge_doubt.json`` (:mod:`rpmnet_jax.multiway.edge_doubt`)
from simulated range scans of TRAINING meshes only (never the Stanford bunny: it is the evaluation set).

    python -m experiments.fit_edge_doubt collect --minutes 5 [--cache TMPDIR/rpmnet_edge_doubt/train.jsonl]
    python -m experiments.fit_edge_doubt fit [--cache ...] [--output rpmnet_jax/weights/edge_doubt.json]

``collect`` makes a mesh of each of :data:`TRAIN_ROWS` (rows of the train file of ``--data-root``) by Poisson
reconstruction of its 2,048 points and normals (:mod:`rpmnet_jax.data.poisson`, Open3D), scaled to a seeded box
diagonal in 0.15–0.3 (metres, like the bunny's 0.25), simulates each of :data:`SETS` of range scans of it
(:func:`rpmnet_jax.simulation.range_scans.simulate`) and records every distinct classical answer of every pair as
``align_scans`` makes them (:func:`rpmnet_jax.evaluation.edge_doubt_records.simulated_set`) in the JSON-lines
``--cache``, then does the same for :data:`RING_SETS` (:func:`rpmnet_jax.data.synthetic.ring_views` of synthetic
shapes ~0.2 across, 0.5 mm noise), a set at a time until ``--minutes`` are spent (sets already there are
skipped: it resumes). ``fit``
(scikit-learn: ``pip install -e ".[fit]"``) fits a logistic regression on the standardised features with grouped
cross-validation (a mesh's edges in one fold), maps the out-of-fold scores to probabilities by Platt scaling, sets
``threshold`` (likely wrong; default 0.5: more likely wrong than right) and picks ``reject_threshold`` (the bar to
keep an edge out of the pose graph: the lowest on a 0.05 grid whose out-of-fold flags take at most
``--max-flagged-right``, 2%, of the right edges that pass align_scans' good rule), and writes plain numbers as JSON,
plus a small parity fixture for the tests.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time

import numpy as np

DATA_ROOT = "../shared/data/real_meshes_train"
# rows of the train file (train_shape_ids.txt) → a short name: classic models, animals, props, buildings
TRAIN_ROWS = {1346: "cow", 1343: "dino", 1371: "beetle", 1367: "rocker_arm", 1379: "fertility",
              1347: "triceratops", 849: "horse", 814: "animal_lion", 174: "bull_statue", 163: "anvil",
              923: "brit_house_01", 934: "celt_broch", 251: "barrel_props", 1350: "mushroom", 1140: "stupa",
              1338: "turbine"}  # anvil, celt_broch and the last four are near-symmetric: flips pass the good rule
SETS = ((16, 200, 0.0005, 0), (12, 160, 0.0005, 1), (20, 240, 0.0005, 2))  # (scans, image size, noise, sim seed)
# rings of partial views round synthetic shapes (rpmnet_jax.data.synthetic; boxes, cylinders, superquadrics, tori,
# tables: many with 180° symmetries, where a flip overlaps more than the right answer): (label, views, seed); the
# tests' ring shape (label 36) is left out
RING_SETS = tuple((label, views, 1000 + 10 * label + views) for label in (0, 1, 2, 3, 4, 6, 7, 11, 12, 13, 14, 16, 21, 22, 26, 31)
                  for views in (5, 7))
RING_NOISE = 0.0005
SIZES = (0.15, 0.3)  # box diagonal of a mesh, uniform per mesh (seeded by its row)
FIXTURE = os.path.join("tests", "data", "edge_doubt_examples.json")
THRESHOLD = 0.5  # likely wrong: more likely wrong than right (the probabilities are calibrated)
MAX_FLAGGED_RIGHT = 0.02  # the rejection bar flags at most this share of the right good edges out of fold


def meshes(root, rows) -> dict:
    """``{row: (vertices, faces)}``: the Poisson meshes of train-file ``rows``, each at its seeded size."""
    from rpmnet_jax.data import poisson
    sizes = [np.random.default_rng(r).uniform(*SIZES) for r in rows]
    return dict(zip(rows, poisson.shape_meshes(root, "train", rows, sizes)))


def shape_ids(root) -> list:
    from rpmnet_jax.data import modelnet40
    with open(os.path.join(modelnet40.resolve_root(root), "train_shape_ids.txt")) as f:
        return [line.strip() for line in f if line.strip()]


def ring_set(label: int, views: int, seed: int, **meta) -> list:
    """The records (:func:`rpmnet_jax.evaluation.edge_doubt_records.scan_set`) of a ring of ``views`` views of the
    synthetic shape ``label`` (~0.2 across, :func:`rpmnet_jax.data.synthetic.ring_views`), ``RING_NOISE`` of
    Gaussian noise added, all seeded by ``seed``."""
    from rpmnet_jax.data import synthetic
    from rpmnet_jax.evaluation import edge_doubt_records as records
    rng = np.random.default_rng(seed)
    world = synthetic.sample_shape(rng, label, 4000)[:, :3].astype(np.float64) * 0.1
    clouds, poses = synthetic.ring_views(world - world.mean(0), views)
    clouds = [c + rng.normal(scale=RING_NOISE, size=c.shape) for c in clouds]
    return records.scan_set(clouds, poses, set=f"ring_{synthetic.CATEGORY_NAMES[label]}", sim_seed=seed,
                            noise=RING_NOISE, **meta)


def collect(a) -> None:
    from rpmnet_jax.evaluation import edge_doubt_records as records
    stop = time.time() + 60 * a.minutes
    rows = sorted(TRAIN_ROWS)
    done = {(r["mesh"], r["sim_seed"]) for r in records.read(a.cache)}
    todo = [(row, s) for s in SETS for row in rows if (row, s[3]) not in done]
    ids = shape_ids(a.data_root)
    made = meshes(a.data_root, sorted({row for row, _ in todo}))
    for row, (num_scans, size, noise, sim_seed) in todo:
        if time.time() > stop:
            break
        t0 = time.time()
        recs = records.simulated_set(*made[row], num_scans, image_size=size, noise=noise, sim_seed=sim_seed,
                                     set=TRAIN_ROWS[row], mesh=row, shape_id=ids[row], split="train")
        records.append(a.cache, recs)
        y = records.labels(recs)
        print(json.dumps({"mesh": TRAIN_ROWS[row], "sim_seed": sim_seed, "pairs": len(recs), "answers": len(y),
                          "wrong": int(y.sum()), "good_wrong": int((y & records.good(recs)).sum()),
                          "seconds": round(time.time() - t0, 1)}), flush=True)
    for label, views, seed in RING_SETS:
        mesh = f"ring{label}"  # a shape's rings in one fold
        if (mesh, seed) in done or time.time() > stop:
            continue
        t0 = time.time()
        recs = ring_set(label, views, seed, mesh=mesh, split="synthetic")
        records.append(a.cache, recs)
        y = records.labels(recs)
        print(json.dumps({"ring": mesh, "pairs": len(recs), "answers": len(y), "wrong": int(y.sum()),
                          "good_wrong": int((y & records.good(recs)).sum()),
                          "seconds": round(time.time() - t0, 1)}), flush=True)


def fit(a) -> None:
    from rpmnet_jax.evaluation import calibration, edge_doubt_records as records
    from rpmnet_jax.multiway import edge_doubt
    recs = records.read(a.cache)
    x, y, good = records.features(recs), records.labels(recs), records.good(recs)
    groups = np.array([r["mesh"] for r in recs for _ in r["answers"]])
    folds = min(6, len(np.unique(groups)))
    fitted = calibration.fit_logistic_platt(x, y, groups, folds, a.c, 5000)
    scaler, scale, lr, platt = fitted.scaler, fitted.scale, fitted.lr, fitted.platt
    p_oof = calibration.held_out_platt(fitted.scores, y, fitted.fold)
    threshold = a.threshold
    reject = calibration.lowest_bar(p_oof, ~y & good, a.max_flagged_right)  # as many wrong good edges kept out
    spec = {"features": list(edge_doubt.FEATURES), **fitted.spec(), "threshold": threshold, "reject_threshold": reject,
            "wrong_deg": edge_doubt.WRONG_DEG,
            "fitted_on": {"edges": len(y), "wrong": int(y.sum()), "good": int(good.sum()),
                          "good_wrong": int((good & y).sum()), "meshes": sorted({r["set"] for r in recs}),
                          "source": "real_meshes_train train file, Poisson meshes, simulated range scans; "
                                    "rings of views of synthetic shapes",
                          "c": a.c, "folds": folds}}
    with open(a.output, "w") as f:
        json.dump(spec, f)
    for bar in (threshold, reject):
        flagged = p_oof >= bar
        for name, m in (("all", np.ones(len(y), bool)), ("good", good)):
            print(json.dumps({"out_of_fold": name, "bar": bar, "edges": int(m.sum()), "wrong": int(y[m].sum()),
                              "auroc": round(calibration.auroc(p_oof[m], y[m]), 4),
                              "ece": round(calibration.ece(p_oof[m], y[m]), 4),
                              "flagged_wrong": round(float(flagged[m & y].mean()), 4) if (m & y).any() else None,
                              "flagged_right": round(float(flagged[m & ~y].mean()), 4)}))
    for t in (0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9):  # how the bar trades wrong good edges caught for right ones
        f = p_oof >= t
        print(json.dumps({"threshold": t, "flagged_wrong": round(float(f[y].mean()), 4),
                          "flagged_right": round(float(f[~y].mean()), 4),
                          "good_flagged_wrong": round(float(f[good & y].mean()), 4),
                          "good_flagged_right": round(float(f[good & ~y].mean()), 4)}))
    mesh = np.array([r["set"] for r in recs for _ in r["answers"]])
    for bar in (threshold, reject):  # a shape's good edges: (wrong flagged, right flagged) out of fold
        f = p_oof >= bar
        print(json.dumps({"bar": bar, "good_edges_flagged_by_mesh": {
            m: [f"{f[good & y & (mesh == m)].sum()}/{(good & y & (mesh == m)).sum()}",
                f"{f[good & ~y & (mesh == m)].sum()}/{(good & ~y & (mesh == m)).sum()}"] for m in np.unique(mesh)}}))
    print(json.dumps({"coef": dict(zip(edge_doubt.FEATURES, np.round(lr.coef_[0], 3).tolist())),
                      "threshold": threshold, "reject_threshold": reject}))
    pick = np.random.RandomState(0).choice(len(y), size=min(40, len(y)), replace=False)
    os.makedirs(os.path.dirname(FIXTURE), exist_ok=True)
    xs = np.round(x[pick], 6)
    with open(FIXTURE, "w") as f:  # the parity test: scikit-learn's probabilities of these features
        json.dump({"features": xs.tolist(),
                   "p_wrong": platt.predict_proba(lr.decision_function((xs - scaler.mean_) / scale)[:, None])[:, 1]
                   .tolist()}, f)


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("command", choices=("collect", "fit"))
    p.add_argument("--cache", default=os.path.join(tempfile.gettempdir(), "rpmnet_edge_doubt", "train.jsonl"))
    p.add_argument("--data-root", default=DATA_ROOT)
    p.add_argument("--minutes", type=float, default=5.0)
    p.add_argument("--output", default=os.path.join("rpmnet_jax", "weights", "edge_doubt.json"))
    p.add_argument("--c", type=float, default=0.1, help="inverse L2 strength of the logistic regression")
    p.add_argument("--max-flagged-right", type=float, default=MAX_FLAGGED_RIGHT,
                   help="rejection bar: the lowest flagging at most this share of right good training edges")
    p.add_argument("--threshold", type=float, default=THRESHOLD, help="the likely-wrong bar (default 0.5)")
    a = p.parse_args(argv)
    os.makedirs(os.path.dirname(os.path.abspath(a.cache)), exist_ok=True)
    collect(a) if a.command == "collect" else fit(a)


if __name__ == "__main__":
    main()
