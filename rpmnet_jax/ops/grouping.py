"""Ball-query neighbourhoods with the official RPM-Net semantics, as dense fixed-size index arrays.

Neighbourhood of centre ``c``: points within ``radius`` of ``c`` *other than c*, in increasing index
order (not by distance), the first ``k`` of them; empty slots hold ``c`` itself. The official code finds
them by sorting an ``N×N`` index matrix; here a prefix count plus a binary search per slot gives the same
indices without the sort, and query rows are processed in chunks to bound memory.
"""

import jax
import jax.numpy as jnp
from jax import lax


def square_distance(a, b):
    """Pairwise squared distances ``(B, N, M)`` between ``a (B, N, C)`` and ``b (B, M, C)``.

    Uses the same expansion as the official code (``-2ab + |a|^2 + |b|^2``) so that radius tests agree
    bit-for-bit at the boundary.
    """
    dist = -2.0 * jnp.einsum("bnc,bmc->bnm", a, b)
    dist = dist + jnp.sum(a**2, axis=-1)[:, :, None]
    dist = dist + jnp.sum(b**2, axis=-1)[:, None, :]
    return dist


def _first_k_valid(valid, centre_idx, k):
    """Indices ``(R, k)`` of the first ``k`` True entries of each row of ``valid (R, N)``; pads with centre."""
    n = valid.shape[-1]
    counts = jnp.cumsum(valid.astype(jnp.int32), axis=-1)  # (R, N), non-decreasing
    targets = jnp.arange(1, k + 1, dtype=jnp.int32)
    # Position of the (s+1)-th valid entry = first index whose prefix count reaches s+1.
    pos = jax.vmap(lambda row: jnp.searchsorted(row, targets, side="left"))(counts)
    pos = pos.astype(jnp.int32)
    return jnp.where(pos < n, pos, centre_idx[:, None])


def ball_query(xyz, radius: float, k: int, chunk: int = 2048):
    """Neighbour indices ``(B, N, k)`` int32 of every point of ``xyz (B, N, 3)`` (official order).

    Memory is ``O(B * chunk * N)`` instead of ``O(B * N^2)``.
    """
    b, n, _ = xyz.shape
    r2 = jnp.asarray(float(radius) ** 2, xyz.dtype)  # as torch: python r^2 cast to the tensor dtype
    sq_norm = jnp.sum(xyz**2, axis=-1)  # (B, N)
    cols = jnp.arange(n, dtype=jnp.int32)

    def rows(start_xyz, start_idx):
        # start_xyz (B, R, 3), start_idx (R,) -> (B, R, k)
        dist = -2.0 * jnp.einsum("brc,bnc->brn", start_xyz, xyz)
        dist = dist + jnp.sum(start_xyz**2, axis=-1)[:, :, None]
        dist = dist + sq_norm[:, None, :]
        valid = (dist <= r2) & (cols[None, None, :] != start_idx[None, :, None])
        flat = valid.reshape(-1, n)
        centre = jnp.broadcast_to(start_idx[None, :], (b, start_idx.shape[0])).reshape(-1)
        return _first_k_valid(flat, centre, k).reshape(b, -1, k)

    if n <= chunk:
        return rows(xyz, cols)
    num_chunks = -(-n // chunk)
    pad = num_chunks * chunk - n
    q_xyz = jnp.pad(xyz, ((0, 0), (0, pad), (0, 0)))
    q_idx = jnp.arange(num_chunks * chunk, dtype=jnp.int32)
    q_xyz = q_xyz.reshape(b, num_chunks, chunk, 3).transpose(1, 0, 2, 3)
    q_idx = q_idx.reshape(num_chunks, chunk)
    out = lax.map(lambda args: rows(*args), (q_xyz, q_idx))  # (C, B, chunk, k)
    return out.transpose(1, 0, 2, 3).reshape(b, -1, k)[:, :n]


def gather(values, idx):
    """``values (B, N, C)`` gathered at ``idx (B, S, k)`` → ``(B, S, k, C)``."""
    return jax.vmap(lambda v, i: v[i])(values, idx)
