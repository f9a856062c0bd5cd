"""Point-pair features (PPF) of local neighbourhoods, NaN-free in value and gradient."""

import jax.numpy as jnp

from rpmnet_jax.ops import grouping


def _dot3(a, b):
    """``a · b (*)`` of ``(*, 3)`` vectors, written out as two adds: an element-wise fusion (XLA's CPU reduce
    over a size-3 axis is a slow strided reduction; PPF of 1024 points 16.5 → 6.9 ms)."""
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


def safe_norm(x):
    """Euclidean norm ``(*)`` of ``x (*, 3)`` with a zero (not NaN) gradient at the origin."""
    sq = _dot3(x, x)
    is_zero = sq == 0
    return jnp.where(is_zero, 0.0, jnp.sqrt(jnp.where(is_zero, 1.0, sq)))


def angle(v1, v2):
    """Angle between ``v1, v2 (*, 3)`` as ``atan2(|v1×v2|, v1·v2)``; 0 when either is zero."""
    cross = jnp.cross(v1, v2)
    y = safe_norm(cross)
    x = _dot3(v1, v2)
    degenerate = (y == 0) & (x == 0)
    return jnp.where(degenerate, 0.0, jnp.arctan2(y, jnp.where(degenerate, 1.0, x)))


def point_pair_features(centre_normals, dxyz, neighbour_normals):
    """PPF ``(B, N, k, 4)``: ``[∠(n_c, d), ∠(n_i, d), ∠(n_c, n_i), |d|]`` with ``d = p_i - p_c``.

    Args:
      centre_normals: ``(B, N, 3)``.
      dxyz: ``(B, N, k, 3)`` offsets of the neighbours from their centre.
      neighbour_normals: ``(B, N, k, 3)``.
    """
    nr = centre_normals[:, :, None, :]
    return jnp.stack([
        angle(jnp.broadcast_to(nr, dxyz.shape), dxyz),
        angle(neighbour_normals, dxyz),
        angle(jnp.broadcast_to(nr, neighbour_normals.shape), neighbour_normals),
        safe_norm(dxyz),
    ], axis=-1)


def group_with_ppf(xyz, normals, radius: float, k: int, chunk: int = 2048):
    """Groups every point with its ball-query neighbours.

    Args:
      xyz, normals: ``(B, N, 3)``.

    Returns:
      ``(idx (B, N, k), dxyz (B, N, k, 3), ppf (B, N, k, 4))``.
    """
    idx = grouping.ball_query(xyz, radius, k, chunk)
    dxyz = grouping.gather(xyz, idx) - xyz[:, :, None, :]
    ppf = point_pair_features(normals, dxyz, grouping.gather(normals, idx))
    return idx, dxyz, ppf
