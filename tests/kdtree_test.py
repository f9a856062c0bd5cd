"""The pipeline's k-d tree: SciPy's neighbours and conventions (missing: ``inf``, index ``n``); pickling."""

import numpy as np
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
