import jax
import jax.numpy as jnp
import numpy as np
from jax.test_util import check_grads

from rpmnet_jax.ops import ppf
from rpmnet_jax.ops import se3

from conftest import float64, random_cloud, random_transform


def test_ppf_invariant_under_rigid_motion():
    rng = np.random.default_rng(0)
    cloud = random_cloud(rng, 2, 100, scale=0.5)
    xyz, normals = cloud[..., :3], cloud[..., 3:]
    _, _, feats = ppf.group_with_ppf(xyz, normals, 0.3, 16)
    for _ in range(3):
        t = random_transform(rng, 2).astype(np.float32)
        _, _, moved = ppf.group_with_ppf(se3.apply(t, xyz), se3.rotate(t, normals), 0.3, 16)
        np.testing.assert_allclose(moved, feats, atol=2e-4)


def test_angle_values():
    a = jnp.array([[1.0, 0, 0], [1.0, 0, 0], [1.0, 0, 0], [0.0, 0, 0]])
    b = jnp.array([[0.0, 1, 0], [-2.0, 0, 0], [3.0, 0, 0], [1.0, 0, 0]])
    np.testing.assert_allclose(ppf.angle(a, b), [np.pi / 2, np.pi, 0.0, 0.0], atol=1e-6)


def test_ppf_gradients_finite_differences():
    rng = np.random.default_rng(1)
    with float64():
        nc = jnp.asarray(rng.normal(size=(1, 3, 3)))
        d = jnp.asarray(rng.normal(size=(1, 3, 4, 3)))
        ni = jnp.asarray(rng.normal(size=(1, 3, 4, 3)))
        check_grads(ppf.point_pair_features, (nc, d, ni), order=1, modes=["rev", "fwd"], atol=1e-6, rtol=1e-6)


def test_no_nan_gradients_at_singular_points():
    nc = jnp.array([[[0.0, 0.0, 1.0]]])
    # zero-length offset (the padded centre itself), coincident points, parallel and anti-parallel normals
    d = jnp.array([[[[0.0, 0.0, 0.0], [0.0, 0.0, 0.5], [0.0, 0.0, -0.5], [0.1, 0.0, 0.0]]]])
    ni = jnp.array([[[[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [0.0, 0.0, 1.0]]]])
    grads = jax.grad(lambda *a: jnp.sum(ppf.point_pair_features(*a)), argnums=(0, 1, 2))(nc, d, ni)
    for g in grads:
        assert np.all(np.isfinite(g))
    values = ppf.point_pair_features(nc, d, ni)
    assert np.all(np.isfinite(values))
    np.testing.assert_allclose(values[0, 0, 0], [0, 0, 0, 0], atol=0)
