"""Robust point-to-plane ICP: makes a good initial transform precise on the caller's dense clouds.

Each iteration pairs every moved source point with its nearest reference point (k-d tree), keeps the pairs
closer than a gate, weights them with Tukey's biweight of their distance (pairs near the gate count little,
pairs beyond it not at all: source points without a partner — partial overlap, outliers — cannot pull the
answer), and solves the linearised weighted point-to-plane problem (6×6). The gate shrinks in stages
(``scales × max_distance``, coarse to fine) so that an answer a few degrees off is first pulled in and then
refined on close pairs only. A stage ends when the update is below ``tolerance`` (rotation in radians,
translation relative to the cloud radius) or after ``max_iterations`` for that stage.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree

from rpmnet_jax.ops import se3


class Refinement(NamedTuple):
    transform: np.ndarray  # (4, 4): maps source onto reference
    converged: bool  # every stage ended on the tolerance, not on max_iterations
    num_iterations: int  # over all stages


def point_to_plane_icp(src, ref, ref_normals, init, max_distance: float, *, scales=(4.0, 2.0, 1.0),
                       max_iterations: int = 30, tolerance: float = 1e-5, ref_tree: cKDTree | None = None
                       ) -> Refinement:
    """Refines ``init (4, 4)`` moving ``src (N, 3)`` onto ``ref (M, 3)`` with unit ``ref_normals (M, 3)``.

    ``max_distance``: the finest gate (same units as the clouds); ``scales``: the gates of the stages as
    multiples of it; ``max_iterations``: per stage.
    """
    src = np.asarray(src, np.float64)
    ref = np.asarray(ref, np.float64)
    normals = np.asarray(ref_normals, np.float64)
    if not max_distance > 0:
        raise ValueError(f"max_distance must be > 0, got {max_distance}")
    if max_iterations < 1:
        raise ValueError(f"max_iterations must be >= 1, got {max_iterations}")
    tree = ref_tree if ref_tree is not None else cKDTree(ref)
    radius = max(float(np.max(np.linalg.norm(src - src.mean(0), axis=1))), 1e-12)
    transform = np.array(init, np.float64)
    total, converged = 0, True
    for scale in scales:
        gate = scale * max_distance
        stage_done = False
        for _ in range(max_iterations):
            total += 1
            moved = src @ transform[:3, :3].T + transform[:3, 3]
            dist, idx = tree.query(moved, k=1, distance_upper_bound=gate)
            ok = np.isfinite(dist)
            if ok.sum() < 6:
                break  # too few pairs at this gate: keep the transform, try the next stage
            p, q, n = moved[ok], ref[idx[ok]], normals[idx[ok]]
            w = (1.0 - (dist[ok] / gate) ** 2) ** 2
            r = np.sum((p - q) * n, axis=1)
            jac = np.concatenate([np.cross(p, n), n], axis=1)  # d r / d (omega, v)
            a = jac.T @ (jac * w[:, None])
            b = -jac.T @ (w * r)
            a[np.diag_indices(6)] += 1e-9 * max(np.trace(a), 1e-12)
            x = np.linalg.solve(a, b)
            step = np.eye(4)
            step[:3, :3] = se3.exp(np.concatenate([x[:3], np.zeros(3)]))[:, :3]  # the rotation of omega
            step[:3, 3] = x[3:]
            transform = step @ transform
            if np.linalg.norm(x[:3]) < tolerance and np.linalg.norm(x[3:]) < tolerance * radius:
                stage_done = True
                break
        converged &= stage_done
    return Refinement(transform, bool(converged), total)
