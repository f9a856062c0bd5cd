"""Scoring a rigid transform the way Open3D's ``evaluate_registration`` does, and its point-to-plane information
matrix (host-side NumPy/SciPy)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from rpmnet_jax.geometry import kdtree, packed_normals
from rpmnet_jax.ops import se3

class Score(NamedTuple):
    fitness: float  # fraction of source points with a reference point within max_distance
    inlier_rmse: float  # RMS distance of those pairs (0 when there are none)
    correspondences: np.ndarray  # (n, 2) int64: (source index, reference index) of each inlier pair
    distances: np.ndarray  # (n,) distance of each inlier pair


def _as_points(name: str, x) -> np.ndarray:
    """``x[:, :3]``, float32 kept as it is (a scan set's compact scans: rows are converted to float64 once picked,
    not the whole cloud for each pair), anything else as float64."""
    x = np.asarray(x)
    x = x if x.dtype in (np.float32, np.float64) else x.astype(np.float64)
    if x.ndim != 2 or x.shape[1] < 3 or len(x) == 0:
        raise ValueError(f"{name}: expected a non-empty (N, 3) array, got shape {x.shape}")
    return x[:, :3]


def evaluate_registration(src, ref, transform, max_distance: float, ref_tree: kdtree.KdTree | None = None) -> Score:
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
    moved = se3.apply(t, src.astype(np.float64, copy=False))
    tree = ref_tree if ref_tree is not None else kdtree.KdTree(ref)
    dist, idx = tree.query(moved, k=1, distance_upper_bound=max_distance)
    inlier = np.isfinite(dist) & (dist <= max_distance)
    n = int(inlier.sum())
    rmse = float(np.sqrt(np.mean(dist[inlier] ** 2))) if n else 0.0
    corr = np.stack([np.nonzero(inlier)[0], idx[inlier]], axis=1).astype(np.int64)
    return Score(n / len(src), rmse, corr, dist[inlier])


NORMAL_DIRECTIONS = 40  # buckets of balanced_fitness: the nearest of this many directions spread on the sphere
MIN_BUCKET = 10  # a bucket with fewer points does not count


def _directions(count: int) -> np.ndarray:
    """``(count, 3)`` unit vectors spread evenly on the sphere (a Fibonacci lattice)."""
    k = np.arange(count) + 0.5
    z = 1.0 - 2.0 * k / count
    phi = np.pi * (3.0 - np.sqrt(5.0)) * k
    r = np.sqrt(1.0 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


_BUCKETS = _directions(NORMAL_DIRECTIONS)


def _bucket(normals) -> np.ndarray:
    """``(N,)`` each unit normal's bucket (``normals`` unit vectors or packed:
    :func:`~rpmnet_jax.geometry.packed_normals.unit`): the nearest of the :data:`NORMAL_DIRECTIONS` directions."""
    return np.argmax(np.asarray(packed_normals.unit(normals), np.float64) @ _BUCKETS.T, axis=1)


def dominant_share(normals) -> float:
    """The share of ``normals (N, 3)`` in their fullest bucket (:func:`balanced_fitness`'): near 1 / the number of
    directions a closed object faces, large where one plane holds most points (a scene's ground)."""
    return float(np.bincount(_bucket(normals)).max() / len(normals)) if len(normals) else 0.0


def balanced_fitness(normals, inlier_rows) -> float:
    """Fitness with every normal direction weighing the same: the points, by their unit ``normals (N, 3)``, in
    buckets of the nearest of :data:`NORMAL_DIRECTIONS` directions; the inlier share (the rows ``inlier_rows``,
    e.g. a :class:`Score`'s ``correspondences[:, 0]``) of each bucket of at least :data:`MIN_BUCKET` points,
    averaged (0 without one). Normal-space sampling (Rusinkiewicz and Levoy, "Efficient variants of the ICP
    algorithm", 3DIM 2001) as a score: a plane that holds most of the points (a scene's ground) fits under any turn
    about its normal and any slide along it, and carries plain fitness; here it is one bucket among the surfaces
    that fix the pose."""
    if len(normals) == 0:
        return 0.0
    inlier = np.zeros(len(normals), bool)
    inlier[np.asarray(inlier_rows, np.int64)] = True
    bucket = _bucket(normals)
    counts = np.bincount(bucket, minlength=NORMAL_DIRECTIONS)
    hits = np.bincount(bucket, weights=inlier, minlength=NORMAL_DIRECTIONS)
    used = counts >= MIN_BUCKET
    return float(np.mean(hits[used] / counts[used])) if used.any() else 0.0


class PlaneFit(NamedTuple):
    information: np.ndarray  # (6, 6) on ξ = (ω, v) of transform · Exp(ξ)
    residuals: np.ndarray  # (n,) signed point-to-plane distance of each pair


def plane_fit(src, ref, ref_normals, transform, correspondences) -> PlaneFit:
    """Point-to-plane residuals and information matrix of ``transform (4, 4)`` moving ``src (N, 3)`` onto
    ``ref (M, 3)`` (unit ``ref_normals (M, 3)``, or packed: :mod:`~rpmnet_jax.geometry.packed_normals`) over
    ``correspondences (n, 2)`` (e.g. a :class:`Score`'s).

    The information is ``Σ_k J_kᵀ J_k / σ²`` with rows ``J_k = [p_k × m_k, m_k]``: ``p_k`` a source point,
    ``m_k = Rᵀ n_k`` its partner's normal in the source frame, so it is the information of the right
    perturbation ``transform · Exp(ξ)``, ``ξ = (ω, v)`` (rotation first, as GTSAM's ``Pose3``; Open3D's
    ``get_information_matrix_from_point_clouds`` is the point-to-point analogue); ``σ²`` the mean squared
    residual (floored at 1e-12 of the clouds' squared extent). All zeros without pairs.
    """
    src, ref = _as_points("source", src), _as_points("reference", ref)
    t = np.asarray(transform, np.float64)
    corr = np.asarray(correspondences, np.int64).reshape(-1, 2)
    if len(corr) == 0:
        return PlaneFit(np.zeros((6, 6)), np.zeros(0))
    p = src[corr[:, 0]].astype(np.float64)
    n = packed_normals.unit(np.asarray(ref_normals), corr[:, 1]).astype(np.float64)
    residuals = np.sum((se3.apply(t, p) - ref[corr[:, 1]].astype(np.float64)) * n, axis=1)
    m = n @ t[:3, :3]  # R^T n, row by row
    jac = np.concatenate([np.cross(p, m), m], axis=1)
    extent = float(np.max(ref.max(axis=0).astype(np.float64) - ref.min(axis=0).astype(np.float64))) or 1.0
    sigma_sq = max(float(np.mean(residuals ** 2)), 1e-12 * extent ** 2)
    return PlaneFit(jac.T @ jac / sigma_sq, residuals)
