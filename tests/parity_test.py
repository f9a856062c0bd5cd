"""Parity with the official PyTorch RPM-Net on the shared fixtures (weights loaded via convert)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import rpmnet_jax
from rpmnet_jax import convert, losses, registration

from conftest import require_fixtures

ABS_TOL = 1e-4


@pytest.fixture(scope="module", params=["partial", "clean"])
def case(request):
    path = require_fixtures() / f"parity_{request.param}.npz"
    with np.load(path) as data:
        fixture = {k: data[k] for k in data.files}
    params = convert.params_from_torch(path)
    return fixture, params


def test_grouping_and_ppf(case):
    fixture, _ = case
    src = jnp.asarray(fixture["points_src"])
    hood = registration.group(src[..., :3], src[..., 3:], rpmnet_jax.RPMNetConfig())
    np.testing.assert_allclose(hood.dxyz, fixture["group_src_dxyz"], atol=ABS_TOL, rtol=0)
    np.testing.assert_allclose(hood.ppf, fixture["group_src_ppf"], atol=ABS_TOL, rtol=0)


def test_features(case):
    fixture, params = case
    cfg = rpmnet_jax.RPMNetConfig()
    for cloud, key in [("points_src", "feat_src_iter0"), ("points_ref", "feat_ref")]:
        pts = jnp.asarray(fixture[cloud])
        hood = registration.group(pts[..., :3], pts[..., 3:], cfg)
        feat = registration.features(params, pts[..., :3], hood, cfg)
        np.testing.assert_allclose(feat, fixture[key], atol=ABS_TOL, rtol=0)


def test_registration_outputs(case):
    fixture, params = case
    reg = jax.jit(rpmnet_jax.register)(params, fixture["points_src"], fixture["points_ref"])
    for key in ["transforms", "perm_matrices", "weighted_ref", "alpha", "beta"]:
        np.testing.assert_allclose(getattr(reg, key), fixture[key], atol=ABS_TOL, rtol=0, err_msg=key)
    np.testing.assert_array_equal(reg.transform, reg.transforms[-1])


def test_training_loss_and_gradients(case):
    fixture, params = case
    batch = {k: fixture[k] for k in ["points_src", "points_ref", "transform_gt"]}
    loss, grads = jax.jit(jax.value_and_grad(losses.training_loss))(params, batch)
    np.testing.assert_allclose(loss, fixture["train_loss"], rtol=1e-4)
    official = convert.params_to_torch(grads)
    assert set(official) == {k[len("grad/"):] for k in fixture if k.startswith("grad/")}
    for name, grad in official.items():
        expected = fixture[f"grad/{name}"]
        rel = np.linalg.norm(grad - expected) / np.linalg.norm(expected)
        assert rel <= 1e-3, f"gradient of {name}: relative L2 error {rel:.2e}"
