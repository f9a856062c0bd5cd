"""What the robust pose graph of :func:`rpmnet_jax.align_scans` (step 3) makes of one scan set's recorded pair edges
(:mod:`rpmnet_jax.evaluation.edge_doubt_records`), with and without the edge doubt rule: the wrong edges that
enter it, those it keeps, the scans it places and how many of them end more than 5° off."""

from __future__ import annotations

import numpy as np

from rpmnet_jax.evaluation import edge_doubt_records as records_lib
from rpmnet_jax.multiway import edge_doubt, edge_graph, options as options_lib, scan_alignment


def _truth_to(records, anchor: int) -> dict:
    """``{scan: (4, 4) true motion of the scan onto scan anchor}`` from the pairs' recorded truths."""
    out = {anchor: np.eye(4)}
    for r in records:
        if r["j"] == anchor:
            out[r["i"]] = np.asarray(r["truth"])
        elif r["i"] == anchor:
            out[r["j"]] = np.linalg.inv(np.asarray(r["truth"]))
    return out


def outcome(records, p, *, threshold: float, reject_at: float | None = None, weigh: bool = False) -> dict:
    """Counts for one scan set (``records``: its :func:`~edge_doubt_records.scan_set` records, all pairs; ``p (A,)``:
    the ``p_wrong`` of their answers in :func:`~edge_doubt_records.answers` order). Into the graph go the answers of
    align_scans' candidate pairs that pass its good rule, less those with ``p ≥ reject_at``; ``weigh``: the
    consensus tree ranks edges by fitness × (1 − p) instead of fitness. ``{edges, wrong_in, wrong_kept,
    right_kept, placed (scans), wrong_poses (placed scans more than 5° off the truth, relative to the anchor),
    resting (placed scans whose every path to the anchor crosses a kept edge with p ≥ threshold), resting_wrong
    (of those, the wrong poses)}``."""
    if not records:
        raise ValueError("no records")
    num_scans, max_dist = records[0]["num_scans"], records[0]["max_distance"]
    o = options_lib.ScanOptions()
    p = np.asarray(p, np.float64)
    wrong, good = records_lib.labels(records), records_lib.good(records)
    chosen = [(e, w, q) for (r, _, e), w, g, q in zip(records_lib.answers(records), wrong, good, p)
              if r["candidate"] and g and (reject_at is None or q < reject_at)]
    counts = {"edges": len(chosen), "wrong_in": int(sum(w for _, w, _ in chosen))}
    if not chosen:
        return {**counts, "wrong_kept": 0, "right_kept": 0, "placed": 0, "wrong_poses": 0, "resting": 0,
                "resting_wrong": 0}
    edges = [e._replace(p_wrong=float(q)) for e, _, q in chosen]
    noise = tuple(scan_alignment.NETWORK_NOISE_SCALE * x for x in (np.radians(o.edge_sigma_deg),
                                                                   o.edge_sigma_fraction * max_dist))
    anchor = edge_graph.largest_component(num_scans, edges)
    poses, kept, _ = edge_graph.solve(num_scans, edges, anchor, noise, o.seed,
                                       edge_graph.doubt_weights(edges) if weigh else None)
    kept_ids = {id(e) for e in kept}
    kept_mask = np.array([id(e) in kept_ids for e in edges])
    truth = _truth_to(records, anchor)
    placed = [s for s in range(num_scans) if np.isfinite(poses[s, 0, 0])]
    off = {s: records_lib.rotation_error_deg(poses[s], truth[s]) > edge_doubt.WRONG_DEG for s in placed}
    resting = edge_graph.resting_on_doubt(num_scans, kept, anchor, threshold)  # as align_scans reports
    w = np.array([w for _, w, _ in chosen], bool)
    return {**counts, "wrong_kept": int((w & kept_mask).sum()), "right_kept": int((~w & kept_mask).sum()),
            "placed": len(placed), "wrong_poses": int(sum(off.values())), "resting": len(resting),
            "resting_wrong": int(sum(off[s] for s in resting))}
