"""Fast Point Feature Histograms (Rusu et al., ICRA 2009) as Open3D computes them, in NumPy/SciPy.

Rotation-invariant 33-bin descriptors of a point's neighbourhood: for each neighbour the Darboux-frame angles
``(α, φ, θ)`` of the pair (:func:`pair_features`), binned 11 ways each (the SPFH); the FPFH adds the
neighbours' SPFHs weighted by ``1 / distance²``, each 11-bin block renormalised to 100 (Open3D's
``ComputeFPFHFeature`` with a hybrid radius / max_nn search).
"""

from __future__ import annotations

import numpy as np
from scipy import sparse
from scipy.spatial import cKDTree

BINS = 11


def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def _acos_greater(x, y):
    """``arccos(x) > arccos(y)`` for ``x, y`` in ``[0, 1]`` as Open3D decides it, with ``arccos`` evaluated only
    where ``x`` and ``y`` are within 1e-6 (elsewhere ``x < y`` decides: arccos is decreasing; near-equal values
    can round to one arccos, and then neither is greater)."""
    out = np.array(x < y)  # an array also for scalar inputs (written below)
    close = np.flatnonzero(np.abs(x - y) < 1e-6)
    out.flat[close] = np.arccos(x.flat[close]) > np.arccos(y.flat[close])
    return out


def pair_features(p1, n1, p2, n2):
    """Open3D's ``ComputePairFeatures`` of point pairs ``(*, 3)`` each: ``(f1, f2, f3, f4) (*, 4)`` with
    ``f1 = α`` in ``[-π, π]``, ``f2 = φ`` and ``f3 = θ`` cosines in ``[-1, 1]``, ``f4`` the distance; zeros for a
    pair at one place or with the offset parallel to the chosen normal."""
    shape = np.broadcast_shapes(np.shape(p1), np.shape(n1), np.shape(p2), np.shape(n2))[:-1]
    comps = (np.moveaxis(np.broadcast_to(x, shape + (3,)), -1, 0) for x in (p1, n1, p2, n2))
    return np.stack(_pair_features(*comps), axis=-1)


def _pair_features(p1, n1, p2, n2):
    """:func:`pair_features` on component-first arrays ``(3, *)`` (``x[0], x[1], x[2]`` broadcast together):
    ``(f1, f2, f3, f4)``, each ``(*)``. Component-wise: ``np.cross`` and interleaved ``(*, 3)`` temporaries cost
    3-4x more on the ``(N, K)`` pairs of :func:`spfh`."""
    d = tuple(p2[i] - p1[i] for i in range(3))
    f4 = np.sqrt(_dot(d, d))
    safe = np.where(f4 > 0, f4, 1.0)
    a1 = _dot(n1, d) / safe
    a2 = _dot(n2, d) / safe
    swap = _acos_greater(np.clip(np.abs(a1), 0, 1), np.clip(np.abs(a2), 0, 1))
    na = tuple(np.where(swap, n2[i], n1[i]) for i in range(3))
    nb = tuple(np.where(swap, n1[i], n2[i]) for i in range(3))
    d = tuple(np.where(swap, -d[i], d[i]) for i in range(3))
    f3 = np.where(swap, -a2, a1)
    v = _cross(d, na)
    v_norm = np.sqrt(_dot(v, v))
    v = tuple(c / np.where(v_norm > 0, v_norm, 1.0) for c in v)
    w = _cross(na, v)
    f2 = _dot(v, nb)
    f1 = np.arctan2(_dot(w, nb), _dot(na, nb))
    ok = (f4 > 0) & (v_norm > 0)
    return tuple(np.where(ok, f, 0.0) for f in (f1, f2, f3, f4))


def neighbours(points: np.ndarray, radius: float, max_nn: int, tree: cKDTree | None = None):
    """Hybrid search (Open3D's ``KDTreeSearchParamHybrid``): the ``max_nn`` nearest points within ``radius``
    of each point, itself included first. Returns ``(idx (N, max_nn), dist² (N, max_nn), valid (N, max_nn))``;
    invalid slots point at the point itself."""
    if max_nn < 1:
        raise ValueError(f"max_nn must be >= 1, got {max_nn}")
    tree = tree or cKDTree(points)
    k = min(max_nn, len(points))
    dist, idx = tree.query(points, k=k, distance_upper_bound=radius, workers=-1)
    dist, idx = dist.reshape(len(points), k), idx.reshape(len(points), k)  # k=1 returns (N,): keep (N, 1)
    valid = np.isfinite(dist)
    own = np.arange(len(points))[:, None]
    return np.where(valid, idx, own), np.where(valid, dist, 0.0) ** 2, valid


def spfh(points, normals, idx, valid) -> np.ndarray:
    """Simplified PFH ``(N, 33)`` of every point from its neighbours ``idx, valid (N, K)`` (slot 0 = itself)."""
    n = len(points)
    pts, nrm = points.T, normals.T  # (3, N): contiguous per component, gathered to (3, N, K)
    f1, f2, f3, _ = _pair_features(pts[:, :, None], nrm[:, :, None], pts[:, idx], nrm[:, idx])  # (N, K) each
    used = valid.copy()
    used[:, 0] = False  # the point itself
    count = used.sum(axis=1)
    incr = np.where(count > 0, 100.0 / np.maximum(count, 1), 0.0)  # Open3D: 100 / (neighbours - 1)
    bins = [np.floor(BINS * (f1 + np.pi) / (2 * np.pi)), np.floor(BINS * (f2 + 1.0) * 0.5),
            np.floor(BINS * (f3 + 1.0) * 0.5)]
    weights = np.where(used, incr[:, None], 0.0).ravel()  # unused slots add 0 (no boolean compaction)
    rows = np.arange(n)[:, None] * (3 * BINS)
    flat = np.concatenate([(rows + np.clip(b, 0, BINS - 1).astype(np.int64) + block * BINS).ravel()
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
    n, k = idx.shape
    acc = sparse.csr_matrix((w.ravel(), idx.ravel(), np.arange(0, n * k + 1, k)), shape=(n, n)) @ s  # (N, 33)
    block_sums = acc.reshape(-1, 3, BINS).sum(axis=-1)  # (N, 3)
    scale = np.where(block_sums != 0, 100.0 / np.where(block_sums != 0, block_sums, 1.0), 0.0)
    return (acc.reshape(-1, 3, BINS) * scale[..., None]).reshape(-1, 3 * BINS) + s
