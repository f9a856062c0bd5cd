"""Triangle meshes of sampled shapes by screened Poisson reconstruction (Open3D, a development dependency): the
training meshes of the edge doubt model (:mod:`rpmnet_jax.evaluation.edge_doubt_records`), made from the
2,048-point clouds of a PointNet-layout HDF5 file (:func:`rpmnet_jax.data.modelnet40.read_split`).
"""

from __future__ import annotations

import numpy as np

from rpmnet_jax.data import modelnet40

DEPTH = 7  # octree depth: ~128³ cells over the shape, enough for 2,048 samples
TRIM = 0.05  # the lowest-density share of the vertices (surface invented far from the samples) is cut away
ORIENT_NEIGHBOURS = 16


def _open3d():
    try:
        import open3d
    except ImportError as e:
        raise RuntimeError(f"Poisson reconstruction needs Open3D ({e}); pip install open3d") from None
    return open3d


def reconstruct(points, normals, size: float, *, depth: int = DEPTH, trim: float = TRIM) -> tuple:
    """``(vertices (V, 3) float64, faces (F, 3) int64)``: the Poisson surface of ``points, normals (N, 3)``
    (normals re-oriented consistently, outward on the whole), centred on its bounding box and scaled so that the
    box's diagonal is ``size``; its lowest-density ``trim`` of vertices removed and only the largest connected
    piece kept. The same mesh, bit for bit, on every run."""
    o3d = _open3d()
    points, normals = np.asarray(points, np.float64), np.asarray(normals, np.float64)
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    pcd.normals = o3d.utility.Vector3dVector(normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True),
                                                                  1e-12))
    pcd.orient_normals_consistent_tangent_plane(ORIENT_NEIGHBOURS)
    oriented = np.asarray(pcd.normals)
    if np.mean(np.sum(oriented * (points - points.mean(0)), axis=1) > 0) < 0.5:  # mostly inward: turn them all
        pcd.normals = o3d.utility.Vector3dVector(-oriented)
    # one thread: Open3D's threaded solve gives different vertices on every run (the same count); on one it is
    # reproducible, and no slower on real_meshes_train's 2,048-point rows (~0.4 s a mesh either way)
    mesh, density = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(pcd, depth=depth, n_threads=1)
    density = np.asarray(density)
    mesh.remove_vertices_by_mask(density < np.quantile(density, trim))
    clusters, counts, _ = (np.asarray(x) for x in mesh.cluster_connected_triangles())
    mesh.remove_triangles_by_mask(clusters != np.argmax(counts))
    mesh.remove_unreferenced_vertices()
    vertices, faces = np.asarray(mesh.vertices, np.float64), np.asarray(mesh.triangles, np.int64)
    if len(faces) == 0:
        raise ValueError("Poisson reconstruction left no triangles")
    low, high = vertices.min(0), vertices.max(0)
    return (vertices - 0.5 * (low + high)) * (size / float(np.linalg.norm(high - low))), faces


def shape_meshes(root, subset: str, rows, sizes) -> list:
    """``[(vertices, faces), ...]``: :func:`reconstruct` of rows ``rows`` of the file list ``subset`` (``"train"``,
    ``"test"``) of a PointNet-layout dataset ``root``, each scaled to its ``sizes`` entry (box diagonal)."""
    data, _, _ = modelnet40.read_split(root, subset)
    return [reconstruct(data[r, :, :3], data[r, :, 3:], s) for r, s in zip(rows, sizes)]
