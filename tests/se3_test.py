import jax.numpy as jnp
import numpy as np
import pytest

from rpmnet_jax.ops import se3

from conftest import random_transform


def _homog(t):
    return np.concatenate([t, np.broadcast_to([0, 0, 0, 1], t.shape[:-2] + (1, 4))], axis=-2)


@pytest.mark.parametrize("batch_shape", [(), (4,), (2, 3)])
def test_compose_inverse_round_trip(batch_shape):
    rng = np.random.default_rng(0)
    n = int(np.prod(batch_shape)) if batch_shape else 1
    a = random_transform(rng, n).reshape(batch_shape + (3, 4)).astype(np.float32)
    b = random_transform(rng, n).reshape(batch_shape + (3, 4)).astype(np.float32)
    ident = se3.identity(batch_shape)
    np.testing.assert_allclose(se3.compose(a, se3.inverse(a)), ident, atol=1e-5)
    np.testing.assert_allclose(se3.compose(se3.inverse(a), a), ident, atol=1e-5)
    np.testing.assert_allclose(se3.compose(a, ident), a, atol=1e-6)
    np.testing.assert_allclose(_homog(np.asarray(se3.compose(a, b))), _homog(a) @ _homog(b), atol=1e-5)
    np.testing.assert_allclose(se3.to_homogeneous(a), _homog(a), atol=0)


def test_apply_matches_homogeneous_and_compose():
    rng = np.random.default_rng(1)
    a, b = random_transform(rng, 2).astype(np.float32)[:, None]
    pts = rng.normal(size=(1, 10, 3)).astype(np.float32)
    expected = (np.concatenate([pts, np.ones((1, 10, 1))], -1) @ _homog(a).transpose(0, 2, 1))[..., :3]
    np.testing.assert_allclose(se3.apply(a, pts), expected, atol=1e-5)
    np.testing.assert_allclose(se3.apply(se3.compose(a, b), pts), se3.apply(a, se3.apply(b, pts)), atol=1e-5)
    np.testing.assert_allclose(se3.apply(se3.inverse(a), se3.apply(a, pts)), pts, atol=1e-5)
    # rotate ignores translation
    np.testing.assert_allclose(se3.rotate(a, pts), se3.apply(a, pts) - a[..., :3, 3][:, None], atol=1e-5)
