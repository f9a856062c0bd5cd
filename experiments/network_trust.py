"""When may ``init="auto"`` keep a weak classical answer without running the network? The measurement behind
``auto.stands`` and ``options.NETWORK_DOUBT``.

    python -m experiments.network_trust [--data-roots ../shared/data/modelnet40_real_subset,...]
        [--meshes 16] [--scans 12] [--output network_trust.jsonl] [--bars 0.05,0.1,0.15,0.2]
    python -m experiments.network_trust --input network_trust.jsonl --bars 0.05,0.1,0.15,0.2

Runs ``align(init="classical")`` (the answer ``auto`` would keep) on two kinds of pairs and records, per pair, its
rotation error, fitness, ``p_wrong`` and number of distinct candidates:

- crops: every partial test pair of each data root, ±45° and any orientation (the public accuracy rows);
- range scans: simulated range scans (:func:`rpmnet_jax.simulation.range_scans.simulate`, 12 per mesh, 240 × 240, 0.5 mm
  noise) of Poisson meshes of TRAINING shapes (``experiments.fit_edge_doubt.TRAIN_ROWS``; never the bunny), every
  pair whose view directions lie 40–120° apart, at full density and sampled to 1,024 points.

Prints one JSON line per kind, bar and rule: of the weak answers (a classical hypothesis found, its refined answer's
fitness below ``network_fitness`` or ambiguous; with none found ``auto`` runs the network anyway) how many each
rule trusts and how many of those are more than 5° off, per ``p_wrong`` bar (``--bars``; default the shipped
``GlobalOptions().network_doubt``). The rules: the doubt model alone (``p_wrong`` below the bar, fitness at least
``auto.DOUBT_FLOOR``, not ambiguous: the default); the same answer also unopposed (one distinct candidate: every
classical hypothesis ended in it); and unopposed or decided by RANSAC (fewer than ``GlobalOptions.classical``
hypotheses were worth refining: the default while the doubt model was fitted on crops alone).
"""

from __future__ import annotations

import argparse
import itertools
import json
import os

import numpy as np

VIEW_ANGLES = (40.0, 120.0)
SAMPLE = 1024


def _record(a, gt, **meta) -> dict:
    from rpmnet_jax.ops import se3
    return {**meta, "error_deg": float(se3.rotation_angle_deg(a.transform[:3, :3] @ gt[:3, :3].T)),
            "fitness": float(a.fitness), "p_wrong": float(a.p_wrong), "ambiguous": bool(a.ambiguous),
            "distinct": len(a.candidates), "starts": sum(len(c.support) for c in a.candidates), "init": a.init}


def crop_records(root: str):
    from rpmnet_jax import data
    from rpmnet_jax.pairwise import alignment, options
    for rot in (45.0, 180.0):
        ds = data.ModelNet40(root, "val", "partial", rot_mag=rot)
        for i in range(len(ds)):
            d = ds[i]
            s, r = (np.asarray(d[k], np.float64) for k in ("points_src", "points_ref"))
            a = alignment.align(s[:, :3], r[:, :3], s[:, 3:6], r[:, 3:6], init="classical",
                                network_options=options.NetworkOptions(max(len(s), len(r))))
            yield _record(a, np.asarray(d["transform_gt"], np.float64), kind="crops", set=root, rot_mag=rot, idx=i)


def scan_pairs(rows, num_scans: int):
    """``(row, i, j, kind, src (N, 3), ref (M, 3), gt (4, 4))`` for simulated range scans (``num_scans`` per mesh,
    240 × 240, 0.5 mm noise) of the Poisson meshes of train-file ``rows`` of ``fit_edge_doubt.DATA_ROOT``: every pair
    whose view directions lie :data:`VIEW_ANGLES` apart, at full density (``kind`` "scans") and sampled to
    :data:`SAMPLE` points ("scans_1024"); ``gt`` maps scan ``i`` onto scan ``j``."""
    from experiments import fit_edge_doubt
    from rpmnet_jax.simulation import range_scans
    meshes = fit_edge_doubt.meshes(fit_edge_doubt.DATA_ROOT, rows)  # one read of the train file
    for row in rows:
        scans = range_scans.simulate(*meshes[row], num_scans, image_size=240, noise=0.0005, seed=row)
        for i, j in itertools.combinations(range(len(scans)), 2):
            angle = np.degrees(np.arccos(np.clip(scans[i].pose[:3, 2] @ scans[j].pose[:3, 2], -1.0, 1.0)))
            if not VIEW_ANGLES[0] <= angle <= VIEW_ANGLES[1] or min(len(scans[i].points), len(scans[j].points)) < 500:
                continue
            gt = np.linalg.inv(scans[j].pose) @ scans[i].pose
            src, ref = scans[i].points, scans[j].points
            yield row, i, j, "scans", src, ref, gt
            rng = np.random.default_rng(100 * i + j)
            src, ref = (p[rng.choice(len(p), min(len(p), SAMPLE), replace=False)] for p in (src, ref))
            yield row, i, j, "scans_1024", src, ref, gt


def scan_records(num_meshes: int, num_scans: int):
    from experiments import fit_edge_doubt
    from rpmnet_jax.pairwise import alignment
    rows = list(fit_edge_doubt.TRAIN_ROWS)[:num_meshes]
    for row, i, j, kind, src, ref, gt in scan_pairs(rows, num_scans):
        yield _record(alignment.align(src, ref, init="classical"), gt, kind=kind, mesh=row, i=i, j=j)


def summary(records: list, bars=None) -> list:
    """Per kind, ``p_wrong`` bar (default ``GlobalOptions().network_doubt``) and rule: weak answers, trusted ones and
    the wrong among them."""
    from rpmnet_jax.pairwise import auto, options
    opts = options.GlobalOptions()
    out = []
    for kind, bar in itertools.product(sorted({r["kind"] for r in records}), bars or (opts.network_doubt,)):
        of_kind = [r for r in records if r["kind"] == kind]
        found = [r for r in of_kind if r["init"] != "identity"]  # none found: the network runs anyway
        weak = [r for r in found if r["fitness"] < opts.network_fitness or r["ambiguous"]]
        doubt_only = lambda r: (not r["ambiguous"] and r["fitness"] >= auto.DOUBT_FLOOR
                                and r["p_wrong"] < bar)
        unopposed = lambda r: doubt_only(r) and r["distinct"] == 1
        decided = lambda r: doubt_only(r) and (r["distinct"] == 1 or r.get("starts", opts.classical) < opts.classical)
        for rule, keep in (("doubt model", doubt_only), ("doubt model + unopposed", unopposed),
                           ("doubt model + unopposed or decided by RANSAC", decided)):
            trusted = [r for r in weak if keep(r)]
            out.append({"kind": kind, "rule": rule, "bar": bar, "pairs": len(of_kind),
                        "no_hypothesis": len(of_kind) - len(found), "weak": len(weak),
                        "weak_wrong": sum(r["error_deg"] > 5.0 for r in weak),
                        "trusted": len(trusted), "trusted_wrong": sum(r["error_deg"] > 5.0 for r in trusted)})
    return out


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--data-roots", default="../shared/data/modelnet40_real_subset,../shared/data/real_meshes_train")
    p.add_argument("--meshes", type=int, default=16, help="training meshes to scan (of fit_edge_doubt.TRAIN_ROWS)")
    p.add_argument("--scans", type=int, default=12, help="simulated scans per mesh")
    p.add_argument("--output", default=None, help="JSON lines: one record per pair")
    p.add_argument("--input", default=None, help="summarise these records (an earlier --output) instead of running")
    p.add_argument("--bars", default=None, help="p_wrong bars, comma-separated (default GlobalOptions().network_doubt)")
    a = p.parse_args(argv)
    if a.input and a.output:
        p.error("--input summarises saved records; --output writes new ones: give one of them")
    if a.input:
        from rpmnet_jax.evaluation import doubt_records
        if not os.path.isfile(a.input):
            p.error(f"--input {a.input}: no such file")
        records = doubt_records.read(a.input)
    else:
        sources = [crop_records(root) for root in a.data_roots.split(",") if root]
        sources.append(scan_records(a.meshes, a.scans) if a.meshes > 0 else iter(()))
        records = list(itertools.chain(*sources))
    if a.output:
        with open(a.output, "w") as f:
            f.writelines(json.dumps(r) + "\n" for r in records)
    for line in summary(records, [float(b) for b in a.bars.split(",")] if a.bars else None):
        print(json.dumps(line))


if __name__ == "__main__":
    main()
