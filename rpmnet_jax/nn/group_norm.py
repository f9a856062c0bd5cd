"""GroupNorm for channels-last tensors: the forward, and the one hand-written backward that both the layer
(:func:`group_norm`) and the fused per-neighbour MLP (:mod:`rpmnet_jax.nn.fused_mlp_max`) use."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import flax.linen as nn

EPS = 1e-5  # torch.nn.GroupNorm default


def group_stats(x, groups: int, eps: float, shift=None):
    """Per-sample, per-group mean and 1/std ``(B, G)`` of ``x (B, ..., C)``, or of ``x + shift`` for a
    per-channel ``shift (C,)`` without forming that sum (channel means move by ``shift``, variances do not).

    Two cheap reductions (channel means, then centred channel variances; neither materialises a copy of
    ``x``), pooled per group with the parallel-variance formula.
    """
    b, c = x.shape[0], x.shape[-1]
    rows = x.reshape(b, -1, c)
    mean_c = jnp.mean(rows, axis=1)
    var_c = jnp.mean(jnp.square(rows - mean_c[:, None, :]), axis=1)
    return pool_group_stats(mean_c if shift is None else mean_c + shift, var_c, groups, eps)


def pool_group_stats(mean_c, var_c, groups: int, eps: float):
    """Group mean and 1/std ``(B, G)`` from per-channel means and variances ``(B, C)``."""
    b = mean_c.shape[0]
    mean_c = mean_c.reshape(b, groups, -1)
    var_c = var_c.reshape(b, groups, -1)
    mean_g = jnp.mean(mean_c, axis=-1)
    var_g = jnp.mean(var_c + (mean_c - mean_g[..., None]) ** 2, axis=-1)
    return mean_g, jax.lax.rsqrt(var_g + eps)


def per_channel(v_BxG, c: int, ndim: int):
    """``(B, G)`` group values → ``(B, 1, ..., 1, C)`` broadcastable against a rank-``ndim`` input."""
    b, g = v_BxG.shape
    return jnp.repeat(v_BxG, c // g, axis=-1).reshape((b,) + (1,) * (ndim - 2) + (c,))


@functools.partial(jax.custom_vjp, nondiff_argnums=(3, 4))
def group_norm(x, scale, bias, groups: int, eps: float = EPS):
    """``torch.nn.GroupNorm`` for channels-last ``x (B, ..., C)``: statistics per sample and channel group
    over all non-batch axes; ``scale, bias (C,)``. Hand-written backward (the stable textbook form)."""
    return _group_norm_fwd(x, scale, bias, groups, eps)[0]


def _group_norm_fwd(x, scale, bias, groups, eps):
    c = x.shape[-1]
    mean_g, inv_g = group_stats(x, groups, eps)
    inv = per_channel(inv_g, c, x.ndim)
    mean = per_channel(mean_g, c, x.ndim)
    y = x * (inv * scale) + (bias - mean * inv * scale)
    return y, (x, scale, mean_g, inv_g)


def backward(dy, xhat, inv_g, scale, groups: int, sums=None):
    """GroupNorm backward from the normalised input ``xhat (B, ..., C)``, ``1/std (B, G)`` and ``scale (C,)``:
    ``(dx, dscale, dbias)`` for the output gradient ``dy``.

    ``sums``: the per-sample channel sums ``(sum dy, sum dy * xhat)``, each ``(B, C)``, when the caller has
    them more cheaply (a ``dy`` that is zero but for one element per max-pool window); otherwise two
    reductions over the large tensor compute them along its contiguous channel axis (summing straight to
    ``(B, G)`` over a strided ``(B, R, G, C/G)`` view is several times slower on CPU). Everything per group
    or per channel is derived from those sums.
    """
    b, c = xhat.shape[0], xhat.shape[-1]
    if sums is None:
        rows = lambda t: t.reshape(b, -1, c)
        sums = jnp.sum(rows(dy), axis=1), jnp.sum(rows(dy * xhat), axis=1)
    sum_dy, sum_dyx = sums  # (B, C)
    count = (xhat.size // (b * c)) * (c // groups)  # elements per sample and group
    group_mean = lambda t: jnp.sum((t * scale).reshape(b, groups, -1), axis=-1) / count  # (B, G)
    mean_g_dy, mean_g_dyx = group_mean(sum_dy), group_mean(sum_dyx)
    dx = per_channel(inv_g, c, xhat.ndim) * (
        dy * scale - per_channel(mean_g_dy, c, xhat.ndim) - xhat * per_channel(mean_g_dyx, c, xhat.ndim))
    return dx, jnp.sum(sum_dyx, axis=0), jnp.sum(sum_dy, axis=0)


def normalise(x, mean_g, inv_g):
    """``xhat`` of ``x (B, ..., C)`` given group mean and 1/std ``(B, G)``."""
    c = x.shape[-1]
    return (x - per_channel(mean_g, c, x.ndim)) * per_channel(inv_g, c, x.ndim)


def _group_norm_bwd(groups, eps, res, dy):
    x, scale, mean_g, inv_g = res
    return backward(dy, normalise(x, mean_g, inv_g), inv_g, scale, groups)


group_norm.defvjp(_group_norm_fwd, _group_norm_bwd)


class GroupNorm(nn.Module):
    """GroupNorm layer (parameters ``scale``, ``bias`` of shape ``(C,)``); see :func:`group_norm`."""

    groups: int

    @nn.compact
    def __call__(self, x):
        c = x.shape[-1]
        scale = self.param("scale", nn.initializers.ones, (c,))
        bias = self.param("bias", nn.initializers.zeros, (c,))
        return group_norm(x, scale, bias, self.groups)
