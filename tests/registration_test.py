import jax
import jax.numpy as jnp
import numpy as np
import pytest

import rpmnet_jax
from rpmnet_jax.ops import se3

from conftest import random_cloud, random_transform

SMALL = rpmnet_jax.RPMNetConfig(num_neighbors=8, feature_dim=16, num_reg_iters=3)


@pytest.fixture(scope="module")
def params():
    return rpmnet_jax.init_params(jax.random.PRNGKey(0), SMALL)


def test_shapes_with_different_sizes_and_jit_as_written(params):
    rng = np.random.default_rng(0)
    src, ref = random_cloud(rng, 2, 30), random_cloud(rng, 2, 45)
    reg = jax.jit(rpmnet_jax.register, static_argnames=("cfg", "num_iters"))(params, src, ref, cfg=SMALL)
    assert reg.transforms.shape == (3, 2, 3, 4)
    assert reg.perm_matrices.shape == (3, 2, 30, 45)
    assert reg.weighted_ref.shape == (3, 2, 30, 3)
    assert reg.alpha.shape == reg.beta.shape == (3, 2)
    assert reg.transform.shape == (2, 3, 4)
    rot = np.asarray(reg.transform[..., :3])
    np.testing.assert_allclose(rot @ rot.transpose(0, 2, 1), np.broadcast_to(np.eye(3), (2, 3, 3)), atol=1e-5)


def test_default_config_jit_exactly_as_documented():
    params = rpmnet_jax.init_params(jax.random.PRNGKey(1))
    rng = np.random.default_rng(1)
    reg = jax.jit(rpmnet_jax.register)(params, random_cloud(rng, 1, 70), random_cloud(rng, 1, 80))
    assert reg.transforms.shape == (5, 1, 3, 4)
    assert np.all(np.isfinite(reg.transforms))


def test_num_iters_override(params):
    rng = np.random.default_rng(2)
    reg = rpmnet_jax.register(params, random_cloud(rng, 1, 20), random_cloud(rng, 1, 20), SMALL, num_iters=1)
    assert reg.transforms.shape == (1, 1, 3, 4)


@pytest.mark.slow  # eager registration of odd shapes (~25 s)
def test_tiny_clouds_fewer_points_than_neighbours(params):
    rng = np.random.default_rng(3)
    reg = rpmnet_jax.register(params, random_cloud(rng, 1, 3), random_cloud(rng, 1, 4), SMALL)
    assert np.all(np.isfinite(reg.transforms))
    reg = rpmnet_jax.register(params, random_cloud(rng, 1, 1), random_cloud(rng, 1, 1), SMALL)
    assert reg.transforms.shape == (3, 1, 3, 4)


@pytest.mark.slow  # two eager registrations (~25 s)
def test_nan_in_one_pair_leaves_others_untouched(params):
    rng = np.random.default_rng(4)
    src, ref = random_cloud(rng, 2, 25), random_cloud(rng, 2, 25)
    clean = rpmnet_jax.register(params, src, ref, SMALL)
    src_nan = src.copy()
    src_nan[0, 3, 0] = np.nan
    dirty = rpmnet_jax.register(params, src_nan, ref, SMALL)
    assert np.isnan(np.asarray(dirty.transforms[:, 0])).any()
    np.testing.assert_allclose(dirty.transforms[:, 1], clean.transforms[:, 1], atol=1e-6)


def test_feature_subset(params):
    """Ablation feature subsets build and run."""
    cfg = SMALL.replace(features=("dxyz", "ppf"))
    p = rpmnet_jax.init_params(jax.random.PRNGKey(2), cfg)
    rng = np.random.default_rng(5)
    src, ref = random_cloud(rng, 1, 40, 0.5), random_cloud(rng, 1, 40, 0.5)
    reg = rpmnet_jax.register(p, src, ref, cfg, num_iters=1)
    assert np.all(np.isfinite(reg.transforms))


@pytest.mark.parametrize("src_shape,ref_shape,match", [
    ((10, 6), (1, 10, 6), "src must have shape"),
    ((1, 10, 3), (1, 10, 6), "src must have 6 channels"),
    ((1, 10, 6), (2, 10, 6), "same batch size"),
    ((1, 0, 6), (1, 10, 6), "src is empty"),
    ((1, 10, 6), (1, 0, 6), "ref is empty"),
    ((1, 10, 6), (1, 10, 7), "ref must have 6 channels"),
])
def test_invalid_inputs(params, src_shape, ref_shape, match):
    with pytest.raises(ValueError, match=match):
        rpmnet_jax.register(params, np.zeros(src_shape, np.float32), np.zeros(ref_shape, np.float32), SMALL)


def test_integer_input_rejected(params):
    with pytest.raises(ValueError, match="floating-point"):
        rpmnet_jax.register(params, np.zeros((1, 5, 6), np.int32), np.zeros((1, 5, 6), np.float32), SMALL)


def test_invalid_config():
    with pytest.raises(ValueError, match="features"):
        rpmnet_jax.RPMNetConfig(features=("xyz", "normals"))
    with pytest.raises(ValueError, match="anneal"):
        rpmnet_jax.RPMNetConfig(anneal="learned")
    assert rpmnet_jax.RPMNetConfig(features=("ppf", "xyz")).features == ("xyz", "ppf")


def test_constant_anneal_ablation():
    cfg = SMALL.replace(anneal="constant")
    p = rpmnet_jax.init_params(jax.random.PRNGKey(3), cfg)
    assert p["weights_net"]["anneal_weights"].shape == (2,)
    rng = np.random.default_rng(6)
    reg = rpmnet_jax.register(p, random_cloud(rng, 2, 20), random_cloud(rng, 2, 20), cfg)
    np.testing.assert_allclose(reg.beta, np.log(2.0), rtol=1e-6)
