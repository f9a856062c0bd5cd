"""Normal estimation for clouds that come without them (host-side NumPy/SciPy)."""

from __future__ import annotations

import numpy as np


def estimate_normals(points: np.ndarray, k: int = 16) -> np.ndarray:
    """Unit normals ``(N, 3)`` of ``points (N, 3)``: the least-variance direction of the ``k`` nearest
    neighbours (PCA), oriented away from the centroid (outward for the closed and partial shapes RPM-Net
    is trained on)."""
    from scipy.spatial import cKDTree

    points = np.asarray(points, np.float64)
    n = len(points)
    k = max(3, min(k, n))
    _, idx = cKDTree(points).query(points, k=k)
    nbrs = points[idx]  # (N, k, 3)
    centred = nbrs - nbrs.mean(axis=1, keepdims=True)
    cov = np.einsum("nki,nkj->nij", centred, centred)
    _, vecs = np.linalg.eigh(cov)  # ascending eigenvalues
    normals = vecs[:, :, 0]
    outward = points - points.mean(axis=0)
    flip = np.sum(normals * outward, axis=1) < 0
    normals[flip] *= -1
    return normals / np.linalg.norm(normals, axis=1, keepdims=True)
