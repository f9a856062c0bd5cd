"""A user's cloud made usable: checked and cleaned (:func:`clean_cloud`), its robust centre and radius
(:func:`robust_centre`, :func:`radius`): a few stray points (a far outlier, a speck of another object) move
neither."""

from __future__ import annotations

import warnings

import numpy as np

STRAY_QUANTILE = 0.9  # a point is stray beyond STRAY_FACTOR × this quantile of the distances from the median
STRAY_FACTOR = 3.0  # with STRAY_QUANTILE: chosen on the 1,220 real test clouds (their farthest point <= 2.4x, so
# none is stray; tuning data: numbers on that data are not held-out)
MIN_POINTS = 3  # fewer cannot fix a rigid transform


def clean_cloud(name: str, points, normals, max_points: int | None = None, seed: int = 0):
    """``(points (n, 3), normals (n, 3) or None, rows (n,))``: float64 points without NaN/inf rows (warned),
    unit normals, and the indices of the kept rows in the caller's ``points (N, 3)``; raises ``ValueError``
    naming ``name`` for a wrong shape, fewer than ``MIN_POINTS`` points, a degenerate cloud or zero normals.

    ``max_points``: a cloud with more finite rows keeps a random (``seed``) subset of this many, in row order:
    only those are copied, so a dense cloud costs what the subset costs."""
    points = np.asarray(points)
    if not np.issubdtype(points.dtype, np.floating):
        points = points.astype(np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"{name}: expected points of shape (N, 3), got {points.shape}")
    if normals is not None:
        normals = np.asarray(normals)
        if normals.shape != points.shape:
            raise ValueError(f"{name}: normals {normals.shape} do not match points {points.shape}")
    if np.isfinite(np.sum(points)) and (normals is None or np.isfinite(np.sum(normals))):
        rows = np.arange(len(points))  # a finite total has no NaN/inf term (one pass, not a per-row test)
    else:
        finite = np.all(np.isfinite(points), axis=1)
        if normals is not None:
            finite &= np.all(np.isfinite(normals), axis=1)
        rows = np.flatnonzero(finite)
    if len(rows) < len(points):
        warnings.warn(f"{name}: dropped {len(points) - len(rows)} points with NaN/inf values", stacklevel=3)
    if max_points is not None and len(rows) > max_points:
        rows = np.sort(np.random.default_rng(seed).choice(rows, max_points, replace=False))
    if len(rows) < len(points):
        points = points[rows]
        normals = None if normals is None else normals[rows]
    points = np.asarray(points, np.float64)
    normals = None if normals is None else np.asarray(normals, np.float64)
    if len(points) < MIN_POINTS:
        raise ValueError(f"{name}: {len(points)} usable points; at least {MIN_POINTS} are needed")
    sv = np.linalg.svd(points - points.mean(axis=0), compute_uv=False)
    if sv[0] <= 1e-12 * max(1.0, np.abs(points).max()) or sv[1] <= 1e-6 * sv[0]:
        raise ValueError(f"{name}: degenerate cloud (all points coincident or collinear)")
    if normals is not None:
        length = np.linalg.norm(normals, axis=1)
        if np.any(length < 1e-8):
            raise ValueError(f"{name}: {int(np.sum(length < 1e-8))} normals have zero length; "
                             "fix them or re-estimate normals")
        normals = normals / length[:, None]
    return points, normals, rows


def robust_centre(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(centre (3,), core (N,) bool)`` of ``points (N, 3)``: the centroid of the points that are not stray,
    and which those are. A point is stray when its distance from the coordinate-wise median exceeds
    ``STRAY_FACTOR`` × the ``STRAY_QUANTILE`` quantile of those distances (a few far points move neither;
    on 1,220 real ModelNet40 partial and noisy clouds the farthest point lies at most 2.4× that quantile
    from the median, so a clean cloud keeps every point and its plain centroid)."""
    d = np.linalg.norm(points - np.median(points, axis=0), axis=1)
    core = d <= STRAY_FACTOR * np.quantile(d, STRAY_QUANTILE)
    return points[core].mean(axis=0), core


def radius(points: np.ndarray, centre: np.ndarray | None = None) -> float:
    """Largest distance of ``points (N, 3)`` from ``centre (3,)`` (default: their centroid)."""
    points = np.asarray(points, np.float64)
    centre = points.mean(axis=0) if centre is None else centre
    return float(np.max(np.linalg.norm(points - centre, axis=1)))


def robust_radius(points: np.ndarray) -> float:
    """:func:`radius` of the non-stray points of ``points (N, 3)`` about their :func:`robust_centre`: the size
    of a cloud that one stray point does not inflate."""
    centre, core = robust_centre(points)
    return radius(points[core], centre)
