"""How the second-best distinct answer of the default ``align`` scores against the best, on rotationally
symmetric real shapes and on the ordinary ones: the measurement behind ``candidates.AMBIGUITY_SHARE``.

    python -m experiments.ambiguity --data-root ../shared/data/modelnet40_real_subset [--rot-mag 180]
        [--stride 5] [--protocols partial,noisy] [--output ambiguity.json]

Symmetric: every bottle, bowl, cone and cup of the train file (seeded draws; surfaces of revolution: the network saw
them in training, which does not matter here: the question is whether their answers are told apart from a
unique one; only where the data has those categories). Ordinary: every ``--stride``-th pair of the test file (airplanes, bathtubs). Both protocols
(partial, noisy). Prints one JSON line per group: for each share in ``SHARES`` the fraction of pairs whose
second distinct answer reaches it (ambiguous at that share), and, for the ordinary pairs, how many of those
had a wrong best answer (> 5°) or a right one; writes the per-pair rows to ``--output``.
"""

from __future__ import annotations

import argparse
import json

import numpy as np

SYMMETRIC = ("bottle", "bowl", "cone", "cup")
SHARES = (0.8, 0.85, 0.9, 0.95)


def _rows(ds, indices, params, group):
    from rpmnet_jax import metrics
    from rpmnet_jax.pairwise import alignment, options
    out = []
    for i in indices:
        d = ds[int(i)]
        s, r = np.asarray(d["points_src"], np.float64), np.asarray(d["points_ref"], np.float64)
        a = alignment.align(s[:, :3], r[:, :3], s[:, 3:6], r[:, 3:6], params=params,
                            network_options=options.NetworkOptions(max(len(s), len(r))))
        err = lambda t: metrics.transform_errors(t[:3], d["transform_gt"])[0]
        scores = [c.score for c in a.candidates]
        out.append({"group": group, "protocol": ds.protocol, "idx": int(i), "label": ds.class_names[d["label"]],
                    "error_deg": float(err(a.transform)), "distinct": len(a.candidates),
                    "second_share": float(scores[1] / scores[0]) if len(scores) > 1 and scores[0] > 0 else 0.0,
                    "candidate_errors_deg": [float(err(c.transform)) for c in a.candidates],
                    "scores": scores, "fitness": [c.fitness for c in a.candidates],
                    "rmse": [c.inlier_rmse for c in a.candidates], "ambiguous": a.ambiguous})
    return out


def summarize(rows) -> dict:
    shares = np.array([r["second_share"] for r in rows])
    wrong = np.array([r["error_deg"] > 5.0 for r in rows])
    out = {"pairs": len(rows), "wrong_best": int(wrong.sum())}
    for s in SHARES:
        flagged = shares >= s
        out[f"ambiguous_at_{s}"] = float(flagged.mean()) if len(rows) else 0.0
        out[f"flagged_wrong_at_{s}"] = int((flagged & wrong).sum())
        out[f"flagged_right_at_{s}"] = int((flagged & ~wrong).sum())
    return out


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--data-root", required=True)
    p.add_argument("--rot-mag", type=float, default=180.0)
    p.add_argument("--stride", type=int, default=5)
    p.add_argument("--protocols", default="partial,noisy")
    p.add_argument("--output", default="ambiguity.json")
    a = p.parse_args(argv)
    from rpmnet_jax import data
    from rpmnet_jax.weights import loading
    params = loading.load_params(None)
    rows = []
    protocols = a.protocols.split(",")
    names = data.ModelNet40(a.data_root, "val", protocols[0]).class_names
    for protocol in protocols:
        if set(SYMMETRIC) <= set(names):
            sym = data.ModelNet40(a.data_root, "train", protocol, rot_mag=a.rot_mag, seed=0,
                                  categories=list(SYMMETRIC))
            rows += _rows(sym, range(len(sym)), params, "symmetric")
        ordinary = data.ModelNet40(a.data_root, "val", protocol, rot_mag=a.rot_mag)
        rows += _rows(ordinary, range(0, len(ordinary), a.stride), params, "ordinary")
    for group in ("symmetric", "ordinary"):
        for protocol in protocols:
            sel = [r for r in rows if r["group"] == group and r["protocol"] == protocol]
            print(json.dumps({"group": group, "protocol": protocol, "rot_mag": a.rot_mag, **summarize(sel)}))
    with open(a.output, "w") as f:
        json.dump(rows, f, indent=1)


if __name__ == "__main__":
    main()
