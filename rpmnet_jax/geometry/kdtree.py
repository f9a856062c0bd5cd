"""The one k-d tree of the library, compiled with Numba, with SciPy's conventions.

Numba, so that compiled loops query it (:func:`query_into`, :func:`nearest`; the ICP's iteration is one compiled
loop around its queries, :mod:`rpmnet_jax.classical.icp`) and a query from Python is one compiled call. Median splits along the
widest axis down to leaves of ``LEAF`` points, stored in tree order; a query visits the nearer child first and
skips a node whose splitting plane lies beyond its current ``k``-th distance. A missing neighbour (none within
``distance_upper_bound``) has distance ``inf`` and index ``n``, as in SciPy.

Measured against pykdtree (C, OpenMP; the library's tree before), 2-core CPU: the ICP's 717 queries into 717
points 0.23 / 0.26 ms (k = 1 / 3) against 0.15 / 0.25 ms back to back, but no thread pool to wake inside a
pipeline (pykdtree's mean there was 0.37 ms); 200,000 queries into 200,000 points 0.25 s (k = 1) on both cores
against 0.31 s.
"""

from __future__ import annotations

import math
import warnings
from typing import NamedTuple

import numba
import numpy as np

from rpmnet_jax.geometry import threads

# Numba tries Intel TBB first for its parallel loops and says so when a system TBB is too old; it then runs them
# on OpenMP (or its own pool) just as well: the notice is not for our users
warnings.filterwarnings("ignore", message="The TBB threading layer requires TBB version",
                        category=numba.NumbaWarning)

LEAF = 12  # points per leaf at most
PARALLEL_QUERIES = 500  # a query of at least this many points runs on every core (the ICP's too): with BLAS on one
# thread (geometry.threads), the refinement of the 150 partial pairs of the ModelNet40 subset at any orientation (717
# points) took 16.5 ms a pair at 2,000, 10.7 at 700, 10.6 at 400, 11.3 at 200 (chosen on those test pairs' times;
# no answer depends on it)


@numba.njit(cache=True)
def select(keys, rows, m, k):
    """Moves the ``k`` smallest of ``keys[:m]`` (and the same entries of ``rows``) to the front, the ``k``-th
    smallest at ``k - 1``, in no particular order otherwise (Hoare's selection, in place)."""
    lo, hi = 0, m - 1
    target = k - 1
    while lo < hi and 0 <= target:
        pivot = keys[(lo + hi) // 2]
        a, b = lo, hi
        while a <= b:
            while keys[a] < pivot:
                a += 1
            while keys[b] > pivot:
                b -= 1
            if a <= b:
                keys[a], keys[b] = keys[b], keys[a]
                rows[a], rows[b] = rows[b], rows[a]
                a += 1
                b -= 1
        if target <= b:
            hi = b
        elif target >= a:
            lo = a
        else:
            return


class Nodes(NamedTuple):
    """The tree's arrays (Numba reads them as one tuple)."""

    points: np.ndarray  # (n, 3) float64 (or float32: :meth:`KdTree.reordered`): the points in tree order
    rows: np.ndarray  # (n,) int32 (int64 from 2^31 points): each tree-order point's row in the caller's array;
    # empty: the caller's array is the tree's order (:func:`row_of`)
    axis: np.ndarray  # (nodes,) int8: the splitting axis, -1 for a leaf
    split: np.ndarray  # (nodes,) the points' dtype: the splitting coordinate
    first: np.ndarray  # (nodes,) as rows: the node's points are points[first:last]; its children are 2i+1, 2i+2
    last: np.ndarray  # (nodes,)


@numba.njit(cache=True)
def _copy_box(box, source, target):
    """``box[target] = box[source]`` element by element: a whole-row assignment makes Numba compile its shape-error
    message (string formatting): 3.4 of the 6.1 s that compiling :func:`_build` took."""
    for side in range(2):
        for a in range(3):
            box[target, side, a] = box[source, side, a]


@numba.njit(cache=True)
def _build(points):
    n = len(points)
    rows = np.arange(n)
    size = 1
    while size * LEAF < n:  # a complete binary tree: leaves of at most LEAF points
        size *= 2
    count = 2 * size - 1
    axis = np.full(count, -1, np.int64)
    split = np.zeros(count)
    first = np.zeros(count, np.int64)
    last = np.zeros(count, np.int64)
    last[0] = n
    keys = np.empty(n)
    box = np.empty((count, 2, 3))  # each node's box: the root's bounds, cut by the splits above it
    for a in range(3):
        box[0, 0, a], box[0, 1, a] = (np.inf, -np.inf) if n else (0.0, 0.0)
        for t in range(n):
            box[0, 0, a] = min(box[0, 0, a], points[t, a])
            box[0, 1, a] = max(box[0, 1, a], points[t, a])
    for node in range(count):
        lo, hi = first[node], last[node]
        if 2 * node + 2 >= count or hi - lo <= LEAF:
            if 2 * node + 2 < count:  # a small node above the last level: an empty right child, a leaf left
                first[2 * node + 1], last[2 * node + 1] = lo, hi
                first[2 * node + 2], last[2 * node + 2] = hi, hi
                axis[node], split[node] = 0, np.inf
                _copy_box(box, node, 2 * node + 1)
                _copy_box(box, node, 2 * node + 2)
            continue
        widest = 0
        for a in range(1, 3):
            if box[node, 1, a] - box[node, 0, a] > box[node, 1, widest] - box[node, 0, widest]:
                widest = a
        mid = (lo + hi) // 2
        for t in range(lo, hi):
            keys[t] = points[rows[t], widest]
        select(keys[lo:hi], rows[lo:hi], hi - lo, mid - lo + 1)
        axis[node], split[node] = widest, keys[mid]
        first[2 * node + 1], last[2 * node + 1] = lo, mid
        first[2 * node + 2], last[2 * node + 2] = mid, hi
        _copy_box(box, node, 2 * node + 1)
        _copy_box(box, node, 2 * node + 2)
        box[2 * node + 1, 1, widest] = box[2 * node + 2, 0, widest] = split[node]
    ordered = np.empty((n, 3), points.dtype)
    for t in range(n):
        for a in range(3):
            ordered[t, a] = points[rows[t], a]
    return ordered, rows, axis, split, first, last


@numba.njit(cache=True)
def row_of(nodes, t):
    """The caller's row of tree-order position ``t`` (``t < n``)."""
    return nodes.rows[t] if len(nodes.rows) else t


STACK = 64  # nodes waiting in a query: more than twice the depth of a tree of 2^31 points


@numba.njit(cache=True)
def scratch():
    """The work space of :func:`nearest` (made once per loop, not per query: an allocation per query costs as
    much as a query of a small tree, and serialises threads)."""
    return np.empty(STACK, np.int64), np.empty(STACK), np.zeros((STACK, 3))


@numba.njit(cache=True)
def nearest(nodes, x, y, z, k, bound2, out_d2, out_at, work):
    """The ``k`` nearest tree points of ``(x, y, z)`` closer than ``sqrt(bound2)``: squared distances into
    ``out_d2 (k,)`` (ascending, ``inf`` where none) and tree-order positions into ``out_at (k,)`` (``n`` where
    none); ``work``: :func:`scratch`. For compiled loops: :func:`row_of` gives the caller's rows. A node waits on
    the stack with the squared distance from the query to its cell (the sum over the axes of the offsets to the
    splits that bound it, Arya and Mount's incremental distance) and is skipped when that exceeds the current
    ``k``-th distance."""
    points, _, axis, split, first, last = nodes
    n = len(points)
    for t in range(k):
        out_d2[t], out_at[t] = np.inf, n
    worst = bound2
    stack_node, stack_low, stack_off = work
    stack_node[0], stack_low[0], top = 0, 0.0, 1
    stack_off[0, 0] = stack_off[0, 1] = stack_off[0, 2] = 0.0
    while top:
        top -= 1
        node, low = stack_node[top], stack_low[top]
        if low > worst or (low == worst and out_d2[k - 1] == worst):  # nothing nearer there (ties: repeated points)
            continue
        a = axis[node]
        if a < 0:
            for t in range(first[node], last[node]):
                ex, ey, ez = points[t, 0] - x, points[t, 1] - y, points[t, 2] - z
                d2 = ex * ex + ey * ey + ez * ez
                if d2 <= worst and d2 < out_d2[k - 1]:
                    j = k - 1
                    while j > 0 and out_d2[j - 1] > d2:
                        out_d2[j], out_at[j] = out_d2[j - 1], out_at[j - 1]
                        j -= 1
                    out_d2[j], out_at[j] = d2, t
                    if out_d2[k - 1] < worst:
                        worst = out_d2[k - 1]
            continue
        offset = (x if a == 0 else y if a == 1 else z) - split[node]
        near, far = (2 * node + 1, 2 * node + 2) if offset < 0 else (2 * node + 2, 2 * node + 1)
        far_low = low - stack_off[top, a] ** 2 + offset * offset
        if far_low < worst or (far_low == worst and out_d2[k - 1] > worst):  # the far cell: the offset along
            # this axis grows to the split's
            stack_node[top], stack_low[top] = far, far_low
            for b in range(3):  # not a row assignment: see _copy_box
                stack_off[top + 1, b] = stack_off[top, b]
            stack_off[top, a] = abs(offset)
            stack_node[top + 1], stack_low[top + 1] = near, low
            top += 2
        else:
            stack_node[top], stack_low[top] = near, low
            top += 1


@numba.njit(cache=True)
def _query_rows(nodes, queries, k, bound2, dist, idx, start, stop):
    """Rows ``start..stop`` of :func:`query_into`."""
    n = len(nodes.points)
    d2 = np.empty(k)
    at = np.empty(k, np.int64)
    work = scratch()
    for i in range(start, stop):
        nearest(nodes, queries[i, 0], queries[i, 1], queries[i, 2], k, bound2, d2, at, work)
        for t in range(k):
            found = at[t] < n
            dist[i, t] = math.sqrt(d2[t]) if found else np.inf
            idx[i, t] = row_of(nodes, at[t]) if found else n


@numba.njit(cache=True, parallel=True)
def _query_parallel(nodes, queries, k, bound2, dist, idx, chunks):
    per = (len(queries) + chunks - 1) // chunks
    for c in numba.prange(chunks):
        _query_rows(nodes, queries, k, bound2, dist, idx, c * per, min((c + 1) * per, len(queries)))


@numba.njit(cache=True)
def query_into(nodes, queries, k, bound2, dist, idx, chunks):
    """The ``k`` nearest tree points of each of ``queries (Q, 3)`` closer than ``sqrt(bound2)``, written into
    ``dist, idx (Q, k)`` (the caller's rows; ``inf`` and ``n`` where none): in ``chunks`` pieces on every core,
    or in one when ``chunks`` is 1 (:func:`chunks_for`). For compiled loops and :meth:`KdTree.query` alike."""
    if chunks > 1:
        _query_parallel(nodes, queries, k, bound2, dist, idx, chunks)
    else:
        _query_rows(nodes, queries, k, bound2, dist, idx, 0, len(queries))


def chunks_for(count: int) -> int:
    """How many pieces :func:`query_into` splits ``count`` queries into: 1 below ``PARALLEL_QUERIES``, else
    :func:`rpmnet_jax.geometry.threads.chunks`. Every call from Python into code that holds :func:`query_into` goes
    through here, so this is also where Numba's thread pool is started (even for one piece)."""
    pieces = threads.chunks()
    return pieces if count >= PARALLEL_QUERIES else 1


class KdTree:
    """A k-d tree of ``points (N, 3)`` (float64, kept as given in ``data``; :meth:`reordered`: in its own order,
    float64 or float32)."""

    def __init__(self, points: np.ndarray):
        self.data = np.ascontiguousarray(points, np.float64)
        self.n = len(self.data)
        ordered, rows, axis, split, first, last = _build(self.data.reshape(-1, 3))
        index = _index_dtype(self.n)  # compact nodes: 13 bytes a node, not 32 (a site's trees: ~0.26 of its points)
        self.nodes = Nodes(ordered, rows.astype(index), axis.astype(np.int8), split, first.astype(index),
                           last.astype(index))

    def reordered(self, dtype=np.float64) -> tuple:
        """``(tree, order (n,))``: this tree over ``data[order]``, the points in the tree's own order (the array it
        searches, so the points are held once, not twice, and no row map), its queries answering rows of that.
        ``dtype`` float32 holds them in half the bytes: the splits are rounded as the points are (rounding keeps
        order), so it is a valid tree of the rounded points and its answers are exact for them (not necessarily the
        tree ``KdTree`` would build from them)."""
        points = self.nodes.points.astype(dtype, copy=False)
        split = self.nodes.split.astype(dtype)  # inf stays inf
        return _of_nodes(self.nodes._replace(points=points, rows=np.empty(0, self.nodes.rows.dtype), split=split)), \
            self.nodes.rows

    def rounded(self, dtype) -> KdTree:
        """This tree with its own copy of the points (and its splits) in ``dtype`` (float32: half the bytes), the
        caller's ``data`` and row map kept: its queries answer the same rows but for near ties, their distances
        those of the rounded points (a valid tree of them, as :meth:`reordered`'s)."""
        tree = object.__new__(KdTree)
        tree.data, tree.n = self.data, self.n
        tree.nodes = self.nodes._replace(points=self.nodes.points.astype(dtype, copy=False),
                                         split=self.nodes.split.astype(dtype, copy=False))
        return tree

    def __reduce__(self):  # pickled as its points; the tree is built again where it is unpickled (a Dask worker);
        # a reordered tree as its nodes (its points are its data: nothing twice, the same tree)
        if self.data is self.nodes.points:
            return _of_nodes, (self.nodes,)
        return _rebuilt, (self.data, self.nodes.points.dtype.str)

    def query(self, queries: np.ndarray, k: int = 1, distance_upper_bound: float = np.inf):
        """``(distances, indices)`` of the ``k`` nearest points of each of ``queries (Q, 3)``: ``(Q,)`` each for
        ``k = 1``, else ``(Q, k)``, nearest first; beyond ``distance_upper_bound`` distance ``inf``, index ``n``."""
        queries = np.ascontiguousarray(queries, np.float64).reshape(-1, 3)
        dist, idx = np.empty((len(queries), k)), np.empty((len(queries), k), np.int64)
        query_into(self.nodes, queries, int(k), float(distance_upper_bound) ** 2, dist, idx, chunks_for(len(queries)))
        return (dist[:, 0], idx[:, 0]) if k == 1 else (dist, idx)


def _index_dtype(n: int):
    """The nodes' and row map's integer dtype for a tree of ``n`` points."""
    return np.int32 if n < 2 ** 31 else np.int64


def _rebuilt(data: np.ndarray, dtype: str) -> KdTree:
    """The tree of ``data`` built again, its own copy of the points in ``dtype`` (:meth:`KdTree.rounded`)."""
    tree = KdTree(data)
    return tree if np.dtype(dtype) == tree.nodes.points.dtype else tree.rounded(np.dtype(dtype))


def _of_nodes(nodes: Nodes) -> KdTree:
    """A tree over ``nodes.points`` in their order (:meth:`KdTree.reordered`)."""
    tree = object.__new__(KdTree)
    tree.data, tree.n, tree.nodes = nodes.points, len(nodes.points), nodes
    return tree
