"""The library's k-d tree: SciPy's neighbours and conventions (missing: ``inf``, index ``n``) for few and many
queries, repeated points, tiny and empty clouds; the compiled query; pickling."""

import os
import subprocess
import sys

import numpy as np
import pytest
from scipy.spatial import cKDTree

from rpmnet_jax.geometry import kdtree


def test_neighbours_and_misses_equal_scipys():
    rng = np.random.default_rng(0)
    points, queries = rng.uniform(-1, 1, (2000, 3)), rng.uniform(-1.5, 1.5, (500, 3))
    ours, theirs = kdtree.KdTree(points), cKDTree(points)
    for k, bound in ((1, np.inf), (1, 0.05), (3, 0.1), (16, np.inf)):
        d, i = ours.query(queries, k=k, distance_upper_bound=bound)
        d_ref, i_ref = theirs.query(queries, k=k, distance_upper_bound=bound)
        assert d.shape == d_ref.shape and i.dtype == np.int64
        np.testing.assert_array_equal(i, i_ref)
        np.testing.assert_allclose(d, d_ref, rtol=1e-12)
        if bound < np.inf:
            assert np.any(np.isinf(d)) and np.all(i[np.isinf(d)] == len(points))


def test_an_empty_query_and_float32_points():
    tree = kdtree.KdTree(np.random.default_rng(1).uniform(size=(50, 3)).astype(np.float32))
    assert tree.data.dtype == np.float64 and tree.n == 50
    d, i = tree.query(np.zeros((0, 3)), k=3)
    assert d.shape == i.shape == (0, 3)
    d, i = tree.query(tree.data[:4])
    np.testing.assert_array_equal(i, np.arange(4))
    np.testing.assert_array_equal(d, 0.0)


def test_a_pickled_tree_answers_the_same():
    """A tree sent to another process (a Dask worker) is built again there from its points."""
    import pickle

    rng = np.random.default_rng(1)
    points, queries = rng.uniform(-1, 1, (500, 3)), rng.uniform(-1, 1, (50, 3))
    tree = kdtree.KdTree(points)
    copy = pickle.loads(pickle.dumps(tree))
    assert np.array_equal(copy.data, tree.data) and copy.n == tree.n
    for a, b in zip(copy.query(queries, k=3), tree.query(queries, k=3)):
        np.testing.assert_array_equal(a, b)


def test_many_queries_on_every_core_and_repeated_points_equal_scipys():
    """A batch of ``PARALLEL_QUERIES`` or more runs in parallel; clouds with repeated points and of fewer points
    than a leaf give SciPy's distances (of equally near points either may come first)."""
    rng = np.random.default_rng(2)
    for n in (1, 5, 40, 3000):
        points = rng.uniform(-1, 1, (n, 3))
        points[: n // 3] = points[n - n // 3:]  # a third repeated
        queries = rng.uniform(-1, 1, (kdtree.PARALLEL_QUERIES + 7 if n == 3000 else 300, 3))
        for k, bound in ((1, np.inf), (3, 0.2), (8, np.inf)):
            d, i = kdtree.KdTree(points).query(queries, k=k, distance_upper_bound=bound)
            d_ref, _ = cKDTree(points).query(queries, k=k, distance_upper_bound=bound)
            np.testing.assert_allclose(d, d_ref, rtol=1e-12)
            found = np.isfinite(d)
            near = np.linalg.norm(points[np.where(found, i, 0)] - (queries[:, None] if k > 1 else queries), axis=-1)
            np.testing.assert_allclose(np.where(found, near, np.inf), d, rtol=1e-12)
            assert np.all(i[~found] == n)


def test_a_reordered_tree_holds_the_points_once_in_its_order_and_answers_the_same():
    """``reordered``: its data is the points in the tree's order (the very array the tree searches), ``order``
    maps them back, and its neighbours (as rows of that data) are SciPy's, also after pickling."""
    import pickle

    rng = np.random.default_rng(3)
    points, queries = rng.normal(size=(3000, 3)), rng.normal(size=(700, 3))
    tree, order = kdtree.KdTree(points).reordered()
    assert np.array_equal(tree.data, points[order]) and np.shares_memory(tree.data, tree.nodes.points)
    assert np.array_equal(np.sort(order), np.arange(len(points)))
    want_d, want_i = cKDTree(tree.data).query(queries, k=3, distance_upper_bound=0.3)
    for t in (tree, pickle.loads(pickle.dumps(tree))):
        dist, idx = t.query(queries, k=3, distance_upper_bound=0.3)
        np.testing.assert_allclose(dist, want_d, rtol=1e-12)
        assert np.array_equal(idx, want_i)


def test_a_float32_reordered_tree_is_the_exact_tree_of_the_rounded_points():
    """``reordered(np.float32)``: half the bytes, no row map, and its neighbours are SciPy's among the points rounded
    to float32 (the splits are rounded alike, so no neighbour across a split is missed), also after pickling (as
    its nodes: still float32, no row map, its points held once)."""
    import pickle

    rng = np.random.default_rng(5)
    points = rng.uniform(-50, 50, (4000, 3))
    queries = rng.uniform(-50, 50, (900, 3))
    whole = kdtree.KdTree(points)
    tree, order = whole.reordered(np.float32)
    assert tree.data.dtype == np.float32 and len(tree.nodes.rows) == 0
    # compact nodes: the splits in the points' dtype, axes in a byte, positions in 4 bytes
    assert (whole.nodes.split.dtype, tree.nodes.split.dtype) == (np.float64, np.float32)
    for t in (whole, tree):
        assert (t.nodes.axis.dtype, t.nodes.first.dtype, t.nodes.last.dtype) == (np.int8, np.int32, np.int32)
    rounded = points[order].astype(np.float32).astype(np.float64)
    assert np.array_equal(tree.data.astype(np.float64), rounded)
    want_d, want_i = cKDTree(rounded).query(queries, k=4, distance_upper_bound=3.0)
    for t in (tree, pickle.loads(pickle.dumps(tree))):
        assert t.data.dtype == np.float32 and len(t.nodes.rows) == 0 and t.data is t.nodes.points  # not rebuilt
        dist, idx = t.query(queries, k=4, distance_upper_bound=3.0)
        np.testing.assert_allclose(dist, want_d, rtol=1e-12)
        assert np.array_equal(idx, want_i)


def test_a_rounded_tree_keeps_the_callers_points_and_rows_and_finds_the_rounded_points_neighbours():
    """``rounded(np.float32)``: the tree's own copy of the points (and its splits) in float32, the caller's float64
    points and the row map kept: its neighbours are SciPy's among the rounded points, as rows of the caller's
    array, also after pickling (built again with its copy rounded)."""
    import pickle

    rng = np.random.default_rng(6)
    points = rng.uniform(-50, 50, (4000, 3))
    queries = rng.uniform(-50, 50, (900, 3))
    whole = kdtree.KdTree(points)
    tree = whole.rounded(np.float32)
    assert tree.data is whole.data and tree.data.dtype == np.float64 and tree.nodes.rows is whole.nodes.rows
    assert (tree.nodes.points.dtype, tree.nodes.split.dtype) == (np.float32, np.float32)
    rounded = points.astype(np.float32).astype(np.float64)
    want_d, want_i = cKDTree(rounded).query(queries, k=4, distance_upper_bound=3.0)
    for t in (tree, pickle.loads(pickle.dumps(tree))):
        assert t.data.dtype == np.float64 and t.nodes.points.dtype == np.float32 and len(t.nodes.rows) == len(points)
        np.testing.assert_array_equal(t.data, points)
        dist, idx = t.query(queries, k=4, distance_upper_bound=3.0)
        np.testing.assert_allclose(dist, want_d, rtol=1e-12)
        assert np.array_equal(idx, want_i)


def test_the_compiled_query_gives_tree_positions_of_the_nearest():
    """``nearest`` (for compiled loops): squared distances, ascending, and positions in tree order."""
    rng = np.random.default_rng(3)
    points = rng.uniform(-1, 1, (500, 3))
    tree = kdtree.KdTree(points)
    d2, at = np.empty(4), np.empty(4, np.int64)
    kdtree.nearest(tree.nodes, 0.1, -0.2, 0.3, 4, np.inf, d2, at, kdtree.scratch())
    d, i = cKDTree(points).query([0.1, -0.2, 0.3], k=4)
    np.testing.assert_allclose(np.sqrt(d2), d, rtol=1e-12)
    np.testing.assert_array_equal(tree.nodes.rows[at], i)
    np.testing.assert_array_equal(tree.nodes.points[at], points[i])
    kdtree.nearest(tree.nodes, 5.0, 5.0, 5.0, 4, 1.0, d2, at, kdtree.scratch())  # nothing within 1
    assert np.all(np.isinf(d2)) and np.all(at == 500)


_QUERY = """
import numpy as np
from rpmnet_jax.geometry import kdtree
x = np.random.default_rng(0).normal(size=(5000, 3))
print("ok", kdtree.KdTree(x).query(x, k=3)[0].shape == (5000, 3))
"""
_SMALL_ICP = """
import numpy as np
from rpmnet_jax.classical import icp
from rpmnet_jax.geometry import kdtree
x = np.random.default_rng(0).normal(size=(1000, 3))
x /= np.linalg.norm(x, axis=1, keepdims=True)
print("ok", icp.point_to_plane_icp(x, x, x.copy(), np.eye(4), 0.05, ref_tree=kdtree.KdTree(x)).converged)
"""


@pytest.mark.slow  # three processes that compile or load the tree and the ICP
def test_compiled_code_loaded_from_numbas_cache_runs_in_a_new_process(tmp_path):
    """New processes sharing one Numba cache, as a Dask run's client and workers do: the first queries 5,000
    points (on the thread pool; the query's compiled code goes to the cache), the second runs an ICP of 1,000 (no
    query reaches the pool; its stage is compiled against the cached query and cached too), the third runs it
    again, everything loaded from the cache. The third used to jump to address 0 (SIGSEGV; a Dask worker died
    that way on a second run) until every query from Python started the pool first (``kdtree.chunks_for``)."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "numba"))
    for step, code in (("query", _QUERY), ("ICP, compiled", _SMALL_ICP), ("ICP, from the cache", _SMALL_ICP)):
        out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=900)
        assert out.returncode == 0 and out.stdout.strip() == "ok True", (step, out.returncode, out.stderr[-1500:])
