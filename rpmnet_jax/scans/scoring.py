"""Scoring a rigid transform the way Open3D's ``evaluate_registration`` does (host-side NumPy/SciPy)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree


class Score(NamedTuple):
    fitness: float  # fraction of source points with a reference point within max_distance
    inlier_rmse: float  # RMS distance of those pairs (0 when there are none)
    correspondences: np.ndarray  # (n, 2) int64: (source index, reference index) of each inlier pair
    distances: np.ndarray  # (n,) distance of each inlier pair


def _as_points(name: str, x) -> np.ndarray:
    x = np.asarray(x, np.float64)
    if x.ndim != 2 or x.shape[1] < 3 or len(x) == 0:
        raise ValueError(f"{name}: expected a non-empty (N, 3) array, got shape {x.shape}")
    return x[:, :3]


def evaluate_registration(src, ref, transform, max_distance: float, ref_tree: cKDTree | None = None) -> Score:
    """Fitness, inlier RMSE and correspondences of ``transform`` moving ``src (N, 3)`` onto ``ref (M, 3)``.

    ``transform``: ``(4, 4)`` or ``(3, 4)``; a source point is an inlier when its nearest reference point is
    within ``max_distance`` (same units as the clouds). ``ref_tree`` reuses a k-d tree of ``ref``.
    """
    src, ref = _as_points("source", src), _as_points("reference", ref)
    t = np.asarray(transform, np.float64)
    if t.shape not in ((4, 4), (3, 4)):
        raise ValueError(f"transform must be (4, 4) or (3, 4), got {t.shape}")
    if not max_distance > 0:
        raise ValueError(f"max_distance must be > 0, got {max_distance}")
    moved = src @ t[:3, :3].T + t[:3, 3]
    tree = ref_tree if ref_tree is not None else cKDTree(ref)
    dist, idx = tree.query(moved, k=1, distance_upper_bound=max_distance)
    inlier = np.isfinite(dist) & (dist <= max_distance)
    n = int(inlier.sum())
    rmse = float(np.sqrt(np.mean(dist[inlier] ** 2))) if n else 0.0
    corr = np.stack([np.nonzero(inlier)[0], idx[inlier]], axis=1).astype(np.int64)
    return Score(n / len(src), rmse, corr, dist[inlier])
