import jax
import jax.numpy as jnp
import numpy as np
from jax.test_util import check_grads

from rpmnet_jax.ops import procrustes
from rpmnet_jax.ops import se3

from conftest import float64, random_transform


def _points(seed, b=3, m=40):
    return np.random.default_rng(seed).normal(size=(b, m, 3)).astype(np.float32)


def test_recovers_known_transform_unweighted_and_weighted():
    rng = np.random.default_rng(0)
    a = _points(0)
    t = random_transform(rng, 3).astype(np.float32)
    b = np.asarray(se3.apply(t, a))
    np.testing.assert_allclose(procrustes.weighted_procrustes(a, b, np.ones(a.shape[:2], np.float32)), t, atol=2e-5)
    # outliers with zero weight do not matter
    w = rng.uniform(0.5, 2.0, size=a.shape[:2]).astype(np.float32)
    w[:, :10] = 0
    b_out = b.copy()
    b_out[:, :10] += rng.normal(scale=5, size=(3, 10, 3)).astype(np.float32)
    np.testing.assert_allclose(procrustes.weighted_procrustes(a, b_out, w), t, atol=5e-5)


def test_reflection_fixed():
    a = _points(1, 1)
    mirror = np.diag([1.0, 1.0, -1.0]).astype(np.float32)
    t = np.asarray(procrustes.weighted_procrustes(a, a @ mirror, np.ones((1, 40), np.float32)))
    assert np.linalg.det(t[0, :, :3]) > 0.99
    np.testing.assert_allclose(t[0, :, :3] @ t[0, :, :3].T, np.eye(3), atol=1e-5)


def test_gradients_finite_differences():
    rng = np.random.default_rng(2)
    with float64():
        a = jnp.asarray(rng.normal(size=(2, 8, 3)))
        b = jnp.asarray(rng.normal(size=(2, 8, 3)))
        w = jnp.asarray(rng.uniform(0.2, 1.0, size=(2, 8)))
        check_grads(procrustes.weighted_procrustes, (a, b, w), order=1, modes=["rev", "fwd"], atol=1e-5, rtol=1e-5)


def test_no_nan_gradients_for_rank_deficient_covariance():
    # collinear points: covariance of rank 1 (two equal zero singular values)
    line = np.linspace(-1, 1, 10, dtype=np.float32)[:, None] * np.array([[1.0, 2.0, 0.5]], np.float32)
    a = jnp.asarray(line[None])
    b = a + 0.1
    w = jnp.ones((1, 10))
    for argnums in (0, 1, 2):
        g = jax.grad(lambda *x: jnp.sum(procrustes.weighted_procrustes(*x) ** 2), argnums=argnums)(a, b, w)
        assert np.all(np.isfinite(g))
    # all points coincident: covariance zero
    same = jnp.zeros((1, 5, 3))
    g = jax.grad(lambda x: jnp.sum(procrustes.weighted_procrustes(x, same, jnp.ones((1, 5)))))(same)
    assert np.all(np.isfinite(g))
