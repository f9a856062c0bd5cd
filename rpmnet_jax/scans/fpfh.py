"""Fast Point Feature Histograms (Rusu et al., ICRA 2009) as Open3D computes them, in NumPy/SciPy.

Rotation-invariant 33-bin descriptors of a point's neighbourhood: for each neighbour the Darboux-frame angles
``(α, φ, θ)`` of the pair (:func:`pair_features`), binned 11 ways each (the SPFH); the FPFH adds the
neighbours' SPFHs weighted by ``1 / distance²``, each 11-bin block renormalised to 100 (Open3D's
``ComputeFPFHFeature`` with a hybrid radius / max_nn search).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

BINS = 11


def pair_features(p1, n1, p2, n2):
    """Open3D's ``ComputePairFeatures`` of point pairs ``(*, 3)`` each: ``(f1, f2, f3, f4) (*, 4)`` with
    ``f1 = α`` in ``[-π, π]``, ``f2 = φ`` and ``f3 = θ`` cosines in ``[-1, 1]``, ``f4`` the distance; zeros for a
    pair at one place or with the offset parallel to the chosen normal."""
    d = p2 - p1
    f4 = np.linalg.norm(d, axis=-1)
    safe = np.where(f4 > 0, f4, 1.0)
    a1 = np.sum(n1 * d, axis=-1) / safe
    a2 = np.sum(n2 * d, axis=-1) / safe
    swap = np.arccos(np.clip(np.abs(a1), 0, 1)) > np.arccos(np.clip(np.abs(a2), 0, 1))
    na = np.where(swap[..., None], n2, n1)
    nb = np.where(swap[..., None], n1, n2)
    d = np.where(swap[..., None], -d, d)
    f3 = np.where(swap, -a2, a1)
    v = np.cross(d, na)
    v_norm = np.linalg.norm(v, axis=-1)
    v = v / np.where(v_norm > 0, v_norm, 1.0)[..., None]
    w = np.cross(na, v)
    f2 = np.sum(v * nb, axis=-1)
    f1 = np.arctan2(np.sum(w * nb, axis=-1), np.sum(na * nb, axis=-1))
    out = np.stack([f1, f2, f3, f4], axis=-1)
    return np.where(((f4 > 0) & (v_norm > 0))[..., None], out, 0.0)


def neighbours(points: np.ndarray, radius: float, max_nn: int, tree: cKDTree | None = None):
    """Hybrid search (Open3D's ``KDTreeSearchParamHybrid``): the ``max_nn`` nearest points within ``radius``
    of each point, itself included first. Returns ``(idx (N, max_nn), dist² (N, max_nn), valid (N, max_nn))``;
    invalid slots point at the point itself."""
    tree = tree or cKDTree(points)
    dist, idx = tree.query(points, k=min(max_nn, len(points)), distance_upper_bound=radius)
    valid = np.isfinite(dist)
    own = np.arange(len(points))[:, None]
    return np.where(valid, idx, own), np.where(valid, dist, 0.0) ** 2, valid


def spfh(points, normals, idx, valid) -> np.ndarray:
    """Simplified PFH ``(N, 33)`` of every point from its neighbours ``idx, valid (N, K)`` (slot 0 = itself)."""
    n = len(points)
    pf = pair_features(points[:, None, :], normals[:, None, :], points[idx], normals[idx])  # (N, K, 4)
    used = valid.copy()
    used[:, 0] = False  # the point itself
    count = used.sum(axis=1)
    incr = np.where(count > 0, 100.0 / np.maximum(count, 1), 0.0)  # Open3D: 100 / (neighbours - 1)
    bins = [np.floor(BINS * (pf[..., 0] + np.pi) / (2 * np.pi)), np.floor(BINS * (pf[..., 1] + 1.0) * 0.5),
            np.floor(BINS * (pf[..., 2] + 1.0) * 0.5)]
    rows = np.broadcast_to(np.arange(n)[:, None] * (3 * BINS), used.shape)[used]
    weights = np.broadcast_to(incr[:, None], used.shape)[used]
    flat = np.concatenate([rows + np.clip(b, 0, BINS - 1).astype(np.int64)[used] + block * BINS
                           for block, b in enumerate(bins)])
    return np.bincount(flat, np.tile(weights, 3), minlength=n * 3 * BINS).reshape(n, 3 * BINS)


def fpfh(points, normals, radius: float, max_nn: int = 100, tree: cKDTree | None = None) -> np.ndarray:
    """FPFH ``(N, 33)`` of ``points, normals (N, 3)`` with Open3D's hybrid search (``radius``, ``max_nn``)."""
    points = np.asarray(points, np.float64)
    normals = np.asarray(normals, np.float64)
    idx, d2, valid = neighbours(points, radius, max_nn, tree)
    s = spfh(points, normals, idx, valid)
    use = valid & (d2 > 0)
    use[:, 0] = False
    w = np.where(use, 1.0 / np.where(d2 > 0, d2, 1.0), 0.0)  # (N, K)
    acc = np.einsum("nk,nkj->nj", w, s[idx])  # (N, 33)
    block_sums = acc.reshape(-1, 3, BINS).sum(axis=-1)  # (N, 3)
    scale = np.where(block_sums != 0, 100.0 / np.where(block_sums != 0, block_sums, 1.0), 0.0)
    return (acc.reshape(-1, 3, BINS) * scale[..., None]).reshape(-1, 3 * BINS) + s
