import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from rpmnet_jax.ops import sinkhorn

from conftest import float64


def _log_alpha(seed, j=7, k=9, scale=3.0):
    return np.random.default_rng(seed).normal(scale=scale, size=(2, j, k)).astype(np.float32)


def _reference(log_alpha, iters):
    """Plain NumPy transcription of the slack Sinkhorn (explicit row/column loops)."""
    la = np.pad(log_alpha.astype(np.float64), ((0, 0), (0, 1), (0, 1)))
    for _ in range(iters):
        for r in range(la.shape[1] - 1):
            la[:, r] -= np.log(np.exp(la[:, r]).sum(-1))[:, None]
        for c in range(la.shape[2] - 1):
            la[:, :, c] -= np.log(np.exp(la[:, :, c]).sum(-1))[:, None]
    return la[:, :-1, :-1]


def test_matches_reference_transcription():
    la = _log_alpha(0)
    np.testing.assert_allclose(sinkhorn.log_sinkhorn(la, 5, True), _reference(la, 5), atol=1e-5)


@pytest.mark.parametrize("j,k", [(7, 9), (9, 7), (5, 5)])
def test_slack_marginals_at_most_one_and_converge(j, k):
    la = _log_alpha(1, j, k)
    p = np.exp(np.asarray(sinkhorn.log_sinkhorn(la, 5, True)))
    assert np.all(p.sum(1) <= 1 + 1e-5) and np.all(p.sum(2) <= 1 + 1e-5)
    for iters in (1, 5, 50):
        p = np.exp(np.asarray(sinkhorn.log_sinkhorn(la, iters, True), np.float64))
        assert np.all(p.sum(1) <= 1 + 1e-5) and np.all(p.sum(2) <= 1 + 1e-5)
    # successive differences shrink: iteration converges
    p5 = np.exp(np.asarray(sinkhorn.log_sinkhorn(la, 5, True), np.float64))
    p6 = np.exp(np.asarray(sinkhorn.log_sinkhorn(la, 6, True), np.float64))
    p50 = np.exp(np.asarray(sinkhorn.log_sinkhorn(la, 50, True), np.float64))
    p51 = np.exp(np.asarray(sinkhorn.log_sinkhorn(la, 51, True), np.float64))
    assert np.abs(p51 - p50).max() < np.abs(p6 - p5).max()


def test_no_slack_is_doubly_stochastic():
    la = _log_alpha(2, 6, 6, scale=1.0)
    p = np.exp(np.asarray(sinkhorn.log_sinkhorn(la, 100, False)))
    np.testing.assert_allclose(p.sum(1), 1, atol=1e-4)
    np.testing.assert_allclose(p.sum(2), 1, atol=1e-4)


def test_gradients_finite_differences():
    with float64():
        la = jnp.asarray(_log_alpha(3, 4, 5, scale=1.0), jnp.float64)
        check_grads(lambda x: sinkhorn.log_sinkhorn(x, 3, True), (la,), order=1, modes=["rev", "fwd"],
                    atol=1e-6, rtol=1e-6)
