"""Step 1 of align_scans, one scan: a refinement's scan (prepared without features) holds the voxel grid's points
rounded to ``SCAN_DTYPE`` and its normals packed (geometry.packed_normals), in its k-d tree's order, each normal
still with its point; a registration's scan holds them in float64 in the grid's order, its features those of its
keypoints' rows."""

import numpy as np

from conftest import ring_scans
from rpmnet_jax.classical import fpfh
from rpmnet_jax.geometry import normals as normals_lib, packed_normals, sampling
from rpmnet_jax.multiway import preparation, sizes
from rpmnet_jax.pair_edges import edges


def _rows(points, normals):
    """The ``(point, normal)`` rows, rounded to the scans' dtype, sorted: the same set whatever the order."""
    rows = np.concatenate([points, normals], axis=1).astype(preparation.SCAN_DTYPE)
    return rows[np.lexsort(rows[:, ::-1].T)]


def test_a_refinement_scan_keeps_each_normal_with_its_point_in_the_trees_order():
    clouds, _ = ring_scans(2)
    sensor = clouds[0].mean(axis=0) + [0.0, 0.0, 1.0]  # normals face a sensor: their signs depend on the point
    grid, _ = sampling.voxel_downsample(clouds[0], None, 0.01)
    registered = preparation.prepare_scan(clouds[0], None, sensor, 0.01, 0)
    refined = preparation.prepare_scan(clouds[0], None, sensor, 0.01, 0, features=False)
    assert refined.features is None and registered.features is not None
    assert registered.points.dtype == np.float64 and np.array_equal(registered.points, grid)  # the grid's order
    np.testing.assert_array_equal(registered.normals,  # made in float64, held rounded
                                  normals_lib.facing(grid, sensor).astype(preparation.SCAN_DTYPE))
    assert refined.points.dtype == preparation.SCAN_DTYPE and packed_normals.is_packed(refined.normals)  # compact
    assert not np.array_equal(refined.points, registered.points.astype(preparation.SCAN_DTYPE))  # another order ...
    packed = packed_normals.unpack(packed_normals.pack(normals_lib.facing(grid, sensor)))  # from float64, as made
    np.testing.assert_array_equal(_rows(refined.points, packed_normals.unpack(refined.normals)),
                                  _rows(registered.points, packed))  # ... the same rows
    assert np.shares_memory(refined.tree.data, refined.points)  # the points held once
    _, idx = refined.tree.query(refined.points[::7])
    assert np.array_equal(idx, np.arange(0, len(refined.points), 7))


def test_a_registration_scans_features_are_its_keypoints_rows():
    """Its points float64 in their own order; its normals and the FPFH of its keypoints made from those in float64,
    then held in float32 (``SCAN_DTYPE``), as its tree's copy of the points (the caller's rows kept)."""
    clouds, _ = ring_scans(2)
    sensor = clouds[0].mean(axis=0) + [0.0, 0.0, 1.0]
    scan = preparation.prepare_scan(clouds[0], None, sensor, 0.01, 0)
    assert scan.points.dtype == np.float64 and scan.tree.data is scan.points
    normals = normals_lib.facing(scan.points, sensor)
    whole = fpfh.fpfh(scan.points, normals, sizes.FEATURE_VOXELS * 0.01, edges.FEATURE_NEIGHBOURS)
    np.testing.assert_array_equal(scan.normals, normals.astype(preparation.SCAN_DTYPE))
    np.testing.assert_array_equal(scan.features, whole[scan.keypoints].astype(preparation.SCAN_DTYPE))
    assert scan.tree.nodes.points.dtype == preparation.SCAN_DTYPE and len(scan.tree.nodes.rows) == len(scan.points)
