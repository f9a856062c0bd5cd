"""Step 1 of align_scans, one scan: a refinement's scan (prepared without features) holds the same points and
normals as a registration's, rounded to ``REFINEMENT_DTYPE``, in its k-d tree's order, each normal still with its
point."""

import numpy as np

from conftest import ring_scans
from rpmnet_jax.multiway import preparation


def _rows(points, normals):
    """The ``(point, normal)`` rows, rounded to the refinement's dtype, sorted: the same set whatever the order."""
    rows = np.concatenate([points, normals], axis=1).astype(preparation.REFINEMENT_DTYPE)
    return rows[np.lexsort(rows[:, ::-1].T)]


def test_a_refinement_scan_keeps_each_normal_with_its_point_in_the_trees_order():
    clouds, _ = ring_scans(2)
    sensor = clouds[0].mean(axis=0) + [0.0, 0.0, 1.0]  # normals face a sensor: their signs depend on the point
    registered = preparation.prepare_scan(clouds[0], None, sensor, 0.01, 0)
    refined = preparation.prepare_scan(clouds[0], None, sensor, 0.01, 0, features=False)
    assert refined.features is None and registered.features is not None
    assert refined.points.dtype == refined.normals.dtype == preparation.REFINEMENT_DTYPE  # compact
    assert not np.array_equal(refined.points, registered.points)  # another order ...
    np.testing.assert_array_equal(_rows(refined.points, refined.normals),
                                  _rows(registered.points, registered.normals))  # ... the same rows
    assert np.shares_memory(refined.tree.data, refined.points)  # the points held once
    _, idx = refined.tree.query(refined.points[::7])
    assert np.array_equal(idx, np.arange(0, len(refined.points), 7))
