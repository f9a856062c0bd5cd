"""Fast Point Feature Histograms (Rusu et al., ICRA 2009) as Open3D computes them, compiled with Numba.

Rotation-invariant 33-bin descriptors of a point's neighbourhood: for each neighbour the Darboux-frame angles
``(α, φ, θ)`` of the pair (:func:`pair_features`), binned 11 ways each (the SPFH); the FPFH adds the
neighbours' SPFHs weighted by ``1 / distance²``, each 11-bin block renormalised to 100 (Open3D's
``ComputeFPFHFeature`` with a hybrid radius / max_nn search).

Numba, not NumPy: a point's pair features, bins and weighted sum are one loop with no ``(N, K)`` temporaries,
20x faster than the vectorised NumPy form on 1,024 points with 128 neighbours (2.4 ms against 48 ms), the same
values; ``cache=True`` keeps the compiled loops on disk, so only a first run ever compiles them.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from rpmnet_jax.geometry import kdtree, threads

BINS = 11


@numba.njit(cache=True)
def _swaps(x, y):
    """Open3D's normal swap for ``x = |cos|`` of the source normal, ``y`` of the target's (both in [0, 1]):
    ``arccos(x) > arccos(y)``, with ``arccos`` evaluated only where the two are within 1e-6 (elsewhere ``x < y``
    decides: arccos is decreasing; near-equal values can round to one arccos, and then neither is greater)."""
    if abs(x - y) < 1e-6:
        return math.acos(x) > math.acos(y)
    return x < y


@numba.njit(cache=True)
def _features(points, normals, i, q):
    """Open3D's ``ComputePairFeatures`` of the pair of rows ``i, q`` of ``points, normals (N, 3)``:
    ``(f1, f2, f3, f4)``, zeros for a pair at one place or with the offset parallel to the chosen normal.
    Scalar arithmetic throughout (no small arrays: each would be a heap allocation per pair)."""
    dx, dy, dz = points[q, 0] - points[i, 0], points[q, 1] - points[i, 1], points[q, 2] - points[i, 2]
    f4 = math.sqrt(dx * dx + dy * dy + dz * dz)
    if f4 == 0.0:
        return 0.0, 0.0, 0.0, 0.0
    ax, ay, az = normals[i, 0], normals[i, 1], normals[i, 2]
    bx, by, bz = normals[q, 0], normals[q, 1], normals[q, 2]
    a1 = (ax * dx + ay * dy + az * dz) / f4
    a2 = (bx * dx + by * dy + bz * dz) / f4
    f3 = a1
    if _swaps(min(abs(a1), 1.0), min(abs(a2), 1.0)):
        ax, ay, az, bx, by, bz = bx, by, bz, ax, ay, az
        dx, dy, dz, f3 = -dx, -dy, -dz, -a2
    vx, vy, vz = dy * az - dz * ay, dz * ax - dx * az, dx * ay - dy * ax
    v_norm = math.sqrt(vx * vx + vy * vy + vz * vz)
    if v_norm == 0.0:
        return 0.0, 0.0, 0.0, 0.0
    vx, vy, vz = vx / v_norm, vy / v_norm, vz / v_norm
    wx, wy, wz = ay * vz - az * vy, az * vx - ax * vz, ax * vy - ay * vx
    f2 = vx * bx + vy * by + vz * bz
    f1 = math.atan2(wx * bx + wy * by + wz * bz, ax * bx + ay * by + az * bz)
    return f1, f2, f3, f4


@numba.njit(cache=True)
def _rows_features(p1, n1, p2, n2):
    points, normals = np.concatenate((p1, p2)), np.concatenate((n1, n2))
    out = np.empty((len(p1), 4))
    for i in range(len(p1)):
        out[i] = _features(points, normals, i, len(p1) + i)
    return out


def pair_features(p1, n1, p2, n2):
    """``(f1, f2, f3, f4) (*, 4)`` of point pairs ``(*, 3)`` each (broadcast): ``f1 = α`` in ``[-π, π]``,
    ``f2 = φ`` and ``f3 = θ`` cosines in ``[-1, 1]``, ``f4`` the distance."""
    arrays = np.broadcast_arrays(*(np.asarray(x, np.float64) for x in (p1, n1, p2, n2)))
    shape = arrays[0].shape[:-1]
    flat = [np.ascontiguousarray(x.reshape(-1, 3)) for x in arrays]
    return _rows_features(*flat).reshape(shape + (4,))


GRID_CELLS_PER_AXIS = 1 << 20  # beyond this many radius cells along an axis the k-d tree searches instead


def neighbours(points: np.ndarray, radius: float, max_nn: int, tree: kdtree.KdTree | None = None):
    """Hybrid search (Open3D's ``KDTreeSearchParamHybrid``): the ``max_nn`` nearest points within ``radius``
    of each point, itself first. Returns ``(idx (N, max_nn), dist² (N, max_nn), valid (N, max_nn))``;
    invalid slots point at the point itself. By a grid of ``radius`` cells (:func:`_grid_search`: the same
    neighbours as the k-d tree's search, after the first slot in no particular order: FPFH sums over them, and
    leaving them unsorted makes the search 4x faster, 2.0 against 9.5 ms on 717 points at 128 neighbours)
    unless the grid would be too fine for the cloud's extent or a ``tree`` is given (then nearest first)."""
    if max_nn < 1:
        raise ValueError(f"max_nn must be >= 1, got {max_nn}")
    points = np.ascontiguousarray(points, np.float64)
    k = min(max_nn, len(points))
    gridded = tree is None and len(points) > 0 and 0 < radius < np.inf and bool(np.isfinite(points).all())
    if gridded and np.all(np.ptp(points, axis=0) / radius < GRID_CELLS_PER_AXIS):
        d2, idx = _grid_search(points, float(radius), k, threads.chunks())
        valid = np.isfinite(d2)
    else:
        tree = tree or kdtree.KdTree(points)
        dist, idx = tree.query(points, k=k, distance_upper_bound=radius)
        dist, idx = dist.reshape(len(points), k), idx.reshape(len(points), k)  # k=1 returns (N,): keep (N, 1)
        valid = np.isfinite(dist)
        d2 = dist ** 2
    own = np.arange(len(points))[:, None]
    return np.where(valid, idx, own), np.where(valid, d2, 0.0), valid


@numba.njit(cache=True, parallel=True)
def _grid_search(points, radius, k, chunks):
    """``(squared distances (N, k), indices (N, k))``: each point itself in the first slot, then its ``k - 1``
    nearest other points within ``radius`` in no particular order (of equally far ones at the ``k``-th
    place, the first found), ``inf`` and ``N`` in the slots left over (the k-d tree's convention), found in
    the 27 cells of side ``radius`` around its own; the rows in ``chunks`` pieces on every core."""
    n = len(points)
    lo = np.empty(3)
    for a in range(3):
        lo[a] = points[:, a].min()
    cells = np.empty((n, 3), np.int64)
    for i in range(n):
        for a in range(3):
            cells[i, a] = int(math.floor((points[i, a] - lo[a]) / radius))
    ny, nz = cells[:, 1].max() + 3, cells[:, 2].max() + 3  # a margin: neighbour cells never wrap
    keys = ((cells[:, 0] + 1) * ny + cells[:, 1] + 1) * nz + cells[:, 2] + 1
    order = np.argsort(keys, kind="mergesort")
    sorted_keys = keys[order]
    out_d = np.full((n, k), np.inf)
    out_i = np.full((n, k), n, np.int64)
    r2 = radius * radius
    per = (n + chunks - 1) // chunks
    for c in numba.prange(chunks):
        cand_d = np.empty(n)
        cand_i = np.empty(n, np.int64)
        for i in range(c * per, min((c + 1) * per, n)):
            _grid_row(points, cells, ny, nz, order, sorted_keys, r2, k, i, cand_d, cand_i, out_d, out_i)
    return out_d, out_i


@numba.njit(cache=True)
def _grid_row(points, cells, ny, nz, order, sorted_keys, r2, k, i, cand_d, cand_i, out_d, out_i):
    """Row ``i`` of :func:`_grid_search` (``cand_d, cand_i (N,)``: its work space)."""
    n = len(points)
    m = 0
    for dx in range(-1, 2):
        for dy in range(-1, 2):
            for dz in range(-1, 2):
                key = ((cells[i, 0] + 1 + dx) * ny + cells[i, 1] + 1 + dy) * nz + cells[i, 2] + 1 + dz
                j = np.searchsorted(sorted_keys, key)
                while j < n and sorted_keys[j] == key:
                    q = order[j]
                    ex, ey, ez = points[q, 0] - points[i, 0], points[q, 1] - points[i, 1], points[q, 2] - points[i, 2]
                    d = ex * ex + ey * ey + ez * ez
                    if d <= r2 and q != i:
                        cand_d[m], cand_i[m] = d, q
                        m += 1
                    j += 1
    out_d[i, 0], out_i[i, 0] = 0.0, i
    if m > k - 1:  # only the k - 1 nearest: moved to the front
        kdtree.select(cand_d, cand_i, m, k - 1)
    for t in range(min(m, k - 1)):
        out_d[i, 1 + t], out_i[i, 1 + t] = cand_d[t], cand_i[t]


@numba.njit(cache=True)
def _bin(scaled):
    """Bin of ``scaled = BINS * (value - low) / (high - low)`` (the arithmetic as Open3D's), clipped to 0..10."""
    return min(max(int(math.floor(scaled)), 0), BINS - 1)


@numba.njit(cache=True, parallel=True)
def spfh(points, normals, idx, valid):
    """Simplified PFH ``(N, 33)`` of every point from its neighbours ``idx, valid (N, K)`` (slot 0 = itself):
    each neighbour adds ``100 / (neighbours - 1)`` to one bin of α, of φ and of θ (Open3D's increment)."""
    n, k = idx.shape
    hist = np.zeros((n, 3 * BINS))
    for i in numba.prange(n):
        count = 0
        for j in range(1, k):
            count += valid[i, j]
        if count == 0:
            continue
        step = 100.0 / count
        for j in range(1, k):
            if valid[i, j]:
                f1, f2, f3, _ = _features(points, normals, i, idx[i, j])
                hist[i, _bin(BINS * (f1 + math.pi) / (2 * math.pi))] += step
                hist[i, BINS + _bin(BINS * (f2 + 1.0) * 0.5)] += step
                hist[i, 2 * BINS + _bin(BINS * (f3 + 1.0) * 0.5)] += step
    return hist


@numba.njit(cache=True, parallel=True)
def _fpfh_from_spfh(hist, idx, d2, valid):
    """Each point's SPFH plus its neighbours' weighted by ``1 / d²``, every 11-bin block of the sum scaled to 100."""
    n, k = idx.shape
    out = np.zeros_like(hist)
    for i in numba.prange(n):
        for j in range(1, k):
            if valid[i, j] and d2[i, j] > 0:
                weight, q = 1.0 / d2[i, j], idx[i, j]
                for b in range(3 * BINS):
                    out[i, b] += weight * hist[q, b]
        for block in range(3):
            total = 0.0
            for b in range(block * BINS, (block + 1) * BINS):
                total += out[i, b]
            scale = 100.0 / total if total != 0 else 0.0
            for b in range(block * BINS, (block + 1) * BINS):
                out[i, b] = out[i, b] * scale + hist[i, b]
    return out


def fpfh(points, normals, radius: float, max_nn: int = 100, tree: kdtree.KdTree | None = None) -> np.ndarray:
    """FPFH ``(N, 33)`` of ``points, normals (N, 3)`` with Open3D's hybrid search (``radius``, ``max_nn``)."""
    points = np.ascontiguousarray(points, np.float64)
    normals = np.ascontiguousarray(normals, np.float64)
    idx, d2, valid = neighbours(points, radius, max_nn, tree)
    return _fpfh_from_spfh(spfh(points, normals, idx, valid), idx, d2, valid)
