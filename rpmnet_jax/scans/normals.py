"""Normal estimation for clouds that come without them (host-side NumPy/SciPy).

PCA gives each point's normal line; its sign is made consistent over the surface by propagation along a
minimum spanning tree of the ``k``-nearest-neighbour graph weighted by ``1 - |n_i · n_j|`` (Hoppe et al.
1992; Open3D's ``orient_normals_consistent_tangent_plane``): neighbours on a smooth patch agree, and the
tree crosses creases where the normals turn least. One sign per connected part is then chosen: the majority
facing ``viewpoint`` (a sensor's position, as Open3D's ``orient_normals_towards_camera_location``) when it
is given, else the majority facing away from the cloud's centroid (outward for the closed and partial shapes
RPM-Net is trained on).
"""

from __future__ import annotations

import numpy as np
from scipy import sparse
from scipy.sparse import csgraph
from scipy.spatial import cKDTree


def estimate_normals(points: np.ndarray, k: int = 16, viewpoint: np.ndarray | None = None,
                     orient: bool = True) -> np.ndarray:
    """Unit normals ``(N, 3)`` of ``points (N, 3)`` from their ``k`` nearest neighbours, oriented
    consistently (see the module docstring); ``viewpoint (3,)`` in the points' frame, or ``None``.
    ``orient=False`` skips the orientation (signs arbitrary: enough for point-to-plane distances)."""
    points = np.asarray(points, np.float64)
    n = len(points)
    k = max(3, min(k, n))
    _, idx = cKDTree(points).query(points, k=k)
    normals = _pca_normals(points, idx)
    if not orient:
        return normals
    signs, labels = _consistent_signs(normals, idx)
    normals *= signs[:, None]
    facing = (np.asarray(viewpoint, np.float64) - points) if viewpoint is not None else points - points.mean(0)
    votes = np.sign(np.sum(normals * facing, axis=1))
    flip = np.bincount(labels, votes) < 0  # per part: most normals face the wrong way
    normals[flip[labels]] *= -1
    return normals


def normals_at(points: np.ndarray, rows: np.ndarray, k: int = 16, tree: cKDTree | None = None) -> np.ndarray:
    """Unoriented unit normals ``(R, 3)`` of ``points[rows]`` from their ``k`` nearest neighbours among all
    ``points (N, 3)`` (as :func:`estimate_normals` with ``orient=False``, for a few rows of a large cloud)."""
    points = np.asarray(points, np.float64)
    tree = tree if tree is not None else cKDTree(points)
    _, idx = tree.query(points[np.asarray(rows, np.int64)], k=max(3, min(k, len(points))))
    return _pca_normals(points, idx)


def _pca_normals(points: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """The direction of least spread of each neighbourhood ``points[idx] (R, k, 3)`` → ``(R, 3)``, unit."""
    nbrs = points[idx]  # (R, k, 3)
    centred = nbrs - nbrs.mean(axis=1, keepdims=True)
    cov = np.einsum("nki,nkj->nij", centred, centred)
    _, vecs = np.linalg.eigh(cov)  # ascending eigenvalues
    normals = vecs[:, :, 0]
    return normals / np.linalg.norm(normals, axis=1, keepdims=True)


def _graph(n: int, idx: np.ndarray, weights: np.ndarray) -> sparse.csr_matrix:
    rows = np.repeat(np.arange(n), idx.shape[1] - 1)
    g = sparse.csr_matrix((weights, (rows, idx[:, 1:].ravel())), shape=(n, n))
    return g.maximum(g.T)  # undirected (neighbourhoods are not symmetric)


def _consistent_signs(normals: np.ndarray, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(signs (N,) ±1, part (N,))``: the signs make ``normals`` agree along a minimum spanning tree of the
    ``k``-NN graph ``idx (N, k)`` (column 0 the point itself; each point takes its tree parent's
    orientation); ``part`` numbers the connected parts of the graph."""
    n = len(normals)
    cos = np.abs(np.sum(normals[:, None, :] * normals[idx[:, 1:]], axis=2)).ravel()
    tree = csgraph.minimum_spanning_tree(_graph(n, idx, 1.0 - cos + 1e-9))  # weights > 0 (0 = no edge)
    tree = tree + tree.T
    parent = np.arange(n)
    part = csgraph.connected_components(tree, directed=False)[1]
    for root in np.unique(part, return_index=True)[1]:
        order, pred = csgraph.breadth_first_order(tree, root, directed=False, return_predecessors=True)
        parent[order[1:]] = pred[order[1:]]
    # the sign relative to the root: the product of the edge signs along the path, by pointer jumping
    sign = np.where(np.sum(normals * normals[parent], axis=1) < 0, -1.0, 1.0)
    while np.any(parent != parent[parent]):
        sign, parent = sign * sign[parent], parent[parent]
    return sign, part
