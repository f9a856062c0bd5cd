"""Weighted Procrustes (Kabsch) with the reflection fix, and an SVD whose gradient is NaN-free."""

import jax
import jax.numpy as jnp

_EPS = 1e-5  # as the official code


def _t(x):
    return jnp.swapaxes(x, -1, -2)


@jax.custom_jvp
def svd(a):
    """``u, s, vh`` of square matrices ``a (*, n, n)``; the JVP masks the terms of equal singular values."""
    u, s, vh = jnp.linalg.svd(a, full_matrices=False)
    return u, s, vh


@svd.defjvp
def _svd_jvp(primals, tangents):
    (a,), (da,) = primals, tangents
    u, s, vh = svd(a)
    v = _t(vh)
    dp = _t(u) @ da @ v
    s2 = s**2
    diff = s2[..., None, :] - s2[..., :, None]  # F_ij = 1 / (s_j^2 - s_i^2)
    tol = jnp.finfo(a.dtype).eps * jnp.max(s2, axis=-1, keepdims=True)[..., None]
    ok = jnp.abs(diff) > tol
    f = jnp.where(ok, 1.0 / jnp.where(ok, diff, 1.0), 0.0)
    s_mat = s[..., None, :] * jnp.eye(s.shape[-1], dtype=s.dtype)
    du = u @ (f * (dp @ s_mat + s_mat @ _t(dp)))
    dv = v @ (f * (s_mat @ dp + _t(dp) @ s_mat))
    ds = jnp.diagonal(dp, axis1=-2, axis2=-1)
    return (u, s, vh), (du, ds, _t(dv))


def weighted_procrustes(a, b, weights):
    """Rigid transform ``(B, 3, 4)`` minimising ``sum_j w_j |T a_j - b_j|^2``.

    Args:
      a, b: ``(B, M, 3)`` corresponding points; the result maps ``a`` onto ``b``.
      weights: ``(B, M)`` non-negative; normalised with ``+1e-5`` in the denominator as officially.
    """
    w = weights[..., None] / (jnp.sum(weights[..., None], axis=1, keepdims=True) + _EPS)
    centroid_a = jnp.sum(a * w, axis=1)
    centroid_b = jnp.sum(b * w, axis=1)
    a_c = a - centroid_a[:, None, :]
    b_c = b - centroid_b[:, None, :]
    cov = _t(a_c) @ (b_c * w)  # (B, 3, 3)
    u, _, vh = svd(cov)
    v = _t(vh)
    rot_pos = v @ _t(u)
    v_neg = v.at[..., :, 2].multiply(-1.0)
    rot_neg = v_neg @ _t(u)
    rot = jnp.where((jnp.linalg.det(rot_pos) > 0)[:, None, None], rot_pos, rot_neg)
    trans = -(rot @ centroid_a[..., None]) + centroid_b[..., None]
    return jnp.concatenate([rot, trans], axis=-1)
