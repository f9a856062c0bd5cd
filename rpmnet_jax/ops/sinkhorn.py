"""Unrolled log-domain Sinkhorn normalisation with an optional slack row and column."""

import jax.numpy as jnp
from jax import lax
from jax.scipy.special import logsumexp


def _normalize_rows(log_p, skip_last: bool):
    """Subtracts each row's log-sum; the last (slack) row is left alone when ``skip_last``."""
    lse = logsumexp(log_p, axis=-1, keepdims=True)
    if skip_last:
        is_slack = jnp.arange(log_p.shape[-2])[:, None] == log_p.shape[-2] - 1
        lse = jnp.where(is_slack, 0.0, lse)
    return log_p - lse


def _normalize_cols(log_p, skip_last: bool):
    lse = logsumexp(log_p, axis=-2, keepdims=True)
    if skip_last:
        is_slack = jnp.arange(log_p.shape[-1])[None, :] == log_p.shape[-1] - 1
        lse = jnp.where(is_slack, 0.0, lse)
    return log_p - lse


def log_sinkhorn(log_alpha, num_iters: int = 5, slack: bool = True):
    """Log of a near doubly-stochastic matrix ``(B, J, K)`` from log-affinities ``log_alpha (B, J, K)``.

    With ``slack``, the matrix is padded with one zero (log 1) row and column; each iteration normalises
    every row but the slack row, then every column but the slack column, and the padding is dropped at
    the end, so row and column sums of the result are ≤ 1 (the rest is mass sent to the slack).
    """
    if slack:
        log_alpha = jnp.pad(log_alpha, ((0, 0), (0, 1), (0, 1)))

    def one_iteration(log_p, _):
        log_p = _normalize_rows(log_p, skip_last=slack)
        log_p = _normalize_cols(log_p, skip_last=slack)
        return log_p, None

    log_p, _ = lax.scan(one_iteration, log_alpha, None, length=num_iters)
    return log_p[:, :-1, :-1] if slack else log_p
