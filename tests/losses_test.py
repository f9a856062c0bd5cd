import jax
import jax.numpy as jnp
import numpy as np
import pytest

import rpmnet_jax
from rpmnet_jax import losses, registration
from rpmnet_jax.ops import se3

from conftest import random_cloud, random_transform


def test_loss_terms_hand_computed():
    b, j, k = 2, 5, 4
    rng = np.random.default_rng(0)
    src = random_cloud(rng, b, j)
    gt = random_transform(rng, b).astype(np.float32)
    ident = np.broadcast_to(np.eye(3, 4, dtype=np.float32), (b, 3, 4))
    transforms = np.stack([ident, gt])  # iteration 0 wrong, iteration 1 exact
    perm = np.full((2, b, j, k), 0.1, np.float32)
    reg = registration.Registration(transforms, perm, np.zeros((2, b, j, 3)), np.zeros((2, b)), np.zeros((2, b)))
    cfg = rpmnet_jax.RPMNetConfig()
    terms = losses.loss_terms(reg, {"points_src": src, "transform_gt": gt}, cfg)
    mae0 = np.mean(np.abs(src[..., :3] - np.asarray(se3.apply(gt, src[..., :3]))))
    np.testing.assert_allclose(terms["mae"], [mae0, 0.0], atol=1e-6)
    inlier = 0.01 * ((1 - 0.1 * j) + (1 - 0.1 * k))
    np.testing.assert_allclose(terms["inlier"], [inlier, inlier], rtol=1e-5)
    np.testing.assert_allclose(terms["total"], 0.5 * (mae0 + inlier) + inlier, rtol=1e-5)


@pytest.mark.slow  # a training-loss gradient compile (~30 s); the parity tests check the full-size gradients
def test_training_loss_gradient_is_finite_and_nonzero():
    cfg = rpmnet_jax.RPMNetConfig(num_neighbors=8, feature_dim=16)
    params = rpmnet_jax.init_params(jax.random.PRNGKey(0), cfg)
    rng = np.random.default_rng(1)
    src = random_cloud(rng, 2, 32, 0.5)
    gt = random_transform(rng, 2, 0.2).astype(np.float32)
    ref = np.concatenate([se3.apply(gt, src[..., :3]), se3.rotate(gt, src[..., 3:])], -1)
    batch = {"points_src": src, "points_ref": np.asarray(ref), "transform_gt": gt}
    loss, grads = jax.jit(jax.value_and_grad(losses.training_loss), static_argnums=2)(params, batch, cfg)
    assert np.isfinite(loss)
    leaves = jax.tree_util.tree_leaves(grads)
    assert all(np.all(np.isfinite(g)) for g in leaves)
    assert sum(float(jnp.sum(jnp.abs(g))) for g in leaves) > 0
