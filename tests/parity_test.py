"""Parity with the official PyTorch RPM-Net on the shared fixtures (weights loaded via convert)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import rpmnet_jax
from rpmnet_jax import losses, registration
from rpmnet_jax.weights import convert

from conftest import float64, require_fixtures

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


def _float64_gradients(params, batch):
    with float64():
        p64 = jax.tree.map(lambda a: jnp.asarray(np.asarray(a, np.float64)), params)
        b64 = {k: np.asarray(v, np.float64) for k, v in batch.items()}
        return convert.params_to_torch(jax.jit(jax.grad(losses.training_loss))(p64, b64))


@pytest.mark.parametrize("fused", [False, True], ids=["autodiff", "fused"])
def test_training_loss_and_gradients(case, fused):
    """Gradients of both training paths (autodiff and the fused MLP + max-pool backward) agree with the official float32 ones to 1e-3 (relative L2), beyond the official values' own
    float32 rounding error.

    A few GroupNorm-adjacent bias gradients are sums of ~4e5 nearly cancelling terms: the official float32
    values sit up to 4e-3 from the same function evaluated in float64 (``clean`` case: 6e-5), and whether
    float32 XLA repeats torch's rounding depends on the CPU's reduction order (on one machine to 6e-5, on
    another ours sit within 1e-6 of float64 and so 4e-3 from torch). The float64 evaluation separates the
    two: every gradient must be within ``1e-3 + rel(official, float64)`` of the official one and within
    1e-4 of the float64 one.
    """
    fixture, params = case
    batch = {k: fixture[k] for k in ["points_src", "points_ref", "transform_gt"]}
    cfg = rpmnet_jax.RPMNetConfig(fused_prepool=fused)  # both paths a training run can take
    loss, grads = jax.jit(jax.value_and_grad(lambda p, b: losses.training_loss(p, b, cfg)))(params, batch)
    np.testing.assert_allclose(loss, fixture["train_loss"], rtol=1e-4)
    official = convert.params_to_torch(grads)
    assert set(official) == {k[len("grad/"):] for k in fixture if k.startswith("grad/")}
    exact = _float64_gradients(params, batch)
    rel = lambda a, b: float(np.linalg.norm(a - b) / np.linalg.norm(b))
    for name, grad in official.items():
        expected = fixture[f"grad/{name}"]
        official_error = rel(expected, exact[name])
        assert rel(grad, expected) <= 1e-3 + official_error, (
            f"gradient of {name}: relative L2 error {rel(grad, expected):.2e} to the official one, whose own "
            f"error to float64 is {official_error:.2e}")
        assert rel(grad, exact[name]) <= 1e-4, f"gradient of {name}: {rel(grad, exact[name]):.2e} from float64"
