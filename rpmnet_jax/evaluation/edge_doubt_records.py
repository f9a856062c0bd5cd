"""Labelled pair edges for the edge doubt model (:mod:`rpmnet_jax.multiway.edge_doubt`): a set of scans with true
poses, prepared as :func:`rpmnet_jax.align_scans` prepares them, every distinct answer of
``edges.classical_edges`` on its pairs (with align_scans' settings and per-pair generators) kept as a JSON-safe
record with its true rotation error, so the features can be recomputed without registering again."""

from __future__ import annotations

import itertools
import json
import os

import numpy as np

from rpmnet_jax.multiway import edge_doubt, options as options_lib, preparation, scan_alignment, sizes
from rpmnet_jax.pair_edges import edges as edges_lib, pair_engine
from rpmnet_jax.ops import se3


def rotation_error_deg(transform, truth) -> float:
    """Degrees between the rotations of ``transform`` and ``truth`` (both ``(4, 4)``)."""
    return float(se3.rotation_angle_deg(np.asarray(transform)[:3, :3].T @ np.asarray(truth)[:3, :3]))


def _answer(e: edges_lib.Edge, truth) -> dict:
    return {"transform": e.transform.tolist(), "fitness": float(e.fitness), "inlier_rmse": float(e.inlier_rmse),
            "plane_residual": float(e.plane_residual) if np.isfinite(e.plane_residual) else None,
            "information": np.asarray(e.information).tolist(), "stage": e.stage,
            "error_deg": rotation_error_deg(e.transform, truth)}


def scan_set(clouds, poses, *, seed: int = 0, tick=None, **meta) -> list:
    """One record per pair ``i < j`` of the scans ``clouds[k] (N_k, 3)`` whose true poses ``poses (S, 4, 4)`` map
    each scan into a common frame: ``{**meta, i, j, num_scans, max_distance, truth (the true (4, 4) motion of scan
    i onto scan j), candidate (among align_scans' candidate pairs), true_overlap (edges.predicted_overlap at the truth), answers: [{transform, fitness,
    inlier_rmse, plane_residual, information, stage, error_deg}, ...]}``, answers best first as
    ``classical_edges`` returns them (``seed``: align_scans' ``ScanOptions.seed``); ``tick(done, total)``."""
    o = options_lib.ScanOptions(seed=seed)
    scans, voxel = preparation.prepare_scans(clouds, None, None)[:2]
    max_dist = sizes.DISTANCE_VOXELS * voxel
    candidates = set(preparation.pairs_to_register(scans, o.all_pairs_up_to, o.neighbours, seed)[0])
    pairs = list(itertools.combinations(range(len(scans)), 2))
    out = []
    for k, (i, j) in enumerate(pairs):
        truth = np.linalg.inv(poses[j]) @ poses[i]
        answers = edges_lib.classical_edges(
            scans, i, j, max_dist, sizes.RANSAC_VOXELS * voxel,
            pair_engine.pair_rng(seed, pair_engine.CLASSICAL_TAG, i, j),
            num_points=scan_alignment.NETWORK_ICP_POINTS, max_plane_residual=sizes.OBJECT_PLANE_RESIDUAL)
        out.append({**meta, "i": i, "j": j, "num_scans": len(scans), "max_distance": max_dist,
                    "truth": truth.tolist(), "candidate": (i, j) in candidates,
                    "true_overlap": edges_lib.predicted_overlap(scans, i, j, truth, max_dist),
                    "answers": [_answer(e, truth) for e in answers]})
        if tick is not None:
            tick(k + 1, len(pairs))
    return out


def simulated_set(vertices, faces, num_scans: int, *, image_size: int, noise: float, sim_seed: int, seed: int = 0,
                  tick=None, **meta) -> list:
    """:func:`scan_set` of ``num_scans`` range scans of the mesh ``vertices (V, 3)``, ``faces (F, 3)`` simulated
    with ``image_size``, ``noise`` and ``sim_seed`` (:func:`rpmnet_jax.simulation.range_scans.simulate`), each scan in
    its sensor frame; the settings go into ``meta``."""
    from rpmnet_jax.simulation import range_scans

    sim = range_scans.simulate(vertices, faces, num_scans, image_size=image_size, noise=noise, seed=sim_seed)
    return scan_set([s.points for s in sim], np.stack([s.pose for s in sim]), seed=seed, tick=tick,
                    image_size=image_size, noise=noise, sim_seed=sim_seed, **meta)


def edges_of(record: dict) -> list:
    """The pair's answers ``[Edge, ...]`` (stage as recorded), rebuilt from a :func:`scan_set` record."""
    return [edges_lib.Edge(record["i"], record["j"], np.asarray(a["transform"]), a["fitness"], a["inlier_rmse"],
                           np.asarray(a["information"]),
                           np.inf if a["plane_residual"] is None else a["plane_residual"], a["stage"])
            for a in record["answers"]]


def answers(records) -> list:
    """``[(record, rank, Edge), ...]``: every answer of every record, flattened in order."""
    return [(r, k, e) for r in records for k, e in enumerate(edges_of(r))]


def features(records) -> np.ndarray:
    """``(A, F)`` :data:`edge_doubt.FEATURES` of every answer of ``records`` (in :func:`answers` order)."""
    rows = [edge_doubt.features(e, r["max_distance"], edges_of(r)) for r, _, e in answers(records)]
    return np.stack(rows) if rows else np.zeros((0, len(edge_doubt.FEATURES)))


def labels(records) -> np.ndarray:
    """``(A,)`` bool: the answer is more than ``edge_doubt.WRONG_DEG`` off (in :func:`answers` order)."""
    return np.array([a["error_deg"] > edge_doubt.WRONG_DEG for r in records for a in r["answers"]], bool)


def good(records) -> np.ndarray:
    """``(A,)`` bool: the answer passes align_scans' default rule for a pair edge (fitness ≥ ``min_fitness``,
    median point-to-plane distance ≤ ``max_plane_residual`` × the correspondence distance)."""
    o = options_lib.ScanOptions()
    return np.array([e.fitness >= o.min_fitness and e.plane_residual <= sizes.OBJECT_PLANE_RESIDUAL * r["max_distance"]
                     for r, _, e in answers(records)], bool)


def read(path: str) -> list:
    """The records of a JSON-lines file (none when it does not exist)."""
    if not os.path.exists(path):
        return []
    with open(path) as f:
        return [json.loads(line) for line in f if line.strip()]


def append(path: str, records) -> None:
    """Appends ``records`` to the JSON-lines ``path``."""
    with open(path, "a") as f:
        for r in records:
            f.write(json.dumps(r) + "\n")
