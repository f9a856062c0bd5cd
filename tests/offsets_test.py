"""Moving scans near the origin and back: the shift, transforms and information expressed in the caller's frame."""

import numpy as np

from conftest import random_transform
from rpmnet_jax.geometry import offsets
from rpmnet_jax.ops import se3


def _transform(rng) -> np.ndarray:
    return se3.to_homogeneous(random_transform(rng, 1, 5.0)[0].astype(np.float64))


def _exp(xi) -> np.ndarray:
    """``(4, 4)`` of a small twist ``ξ = (ω, v)`` to first order (enough for the 1e-6 steps below)."""
    out = np.eye(4)
    w = xi[:3]
    out[:3, :3] += np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
    out[:3, 3] = xi[3:]
    return out


def test_the_shift_is_the_middle_of_the_scans_in_whole_units_and_zero_near_the_origin():
    rng = np.random.default_rng(0)
    scans = [rng.normal(size=(500, 3)) + [512_000.3, 4_100_000.6, 120.2] for _ in range(3)]
    scans[1][:10] = np.nan  # NaN rows are left out of the medians
    np.testing.assert_array_equal(offsets.common_shift(scans), [512_000.0, 4_100_001.0, 120.0])
    np.testing.assert_array_equal(offsets.common_shift([0.1 * s_ for s_ in (rng.normal(size=(100, 3)),) * 2]), 0.0)


def test_a_motion_between_shifted_frames_is_the_same_motion_between_the_callers():
    shift = np.array([512_000.0, 4_100_000.0, 120.0])
    t = _transform(np.random.default_rng(1))
    points = np.random.default_rng(2).normal(size=(20, 3)) * 10 + shift
    expected = (points - shift) @ t[:3, :3].T + t[:3, 3] + shift  # moved near the origin, then back
    caller = offsets.unshift_transforms(t, shift)
    np.testing.assert_allclose(points @ caller[:3, :3].T + caller[:3, 3], expected, atol=1e-6)
    assert np.all(np.isnan(offsets.unshift_transforms(np.full((4, 4), np.nan), shift)))


def test_information_follows_the_perturbation_into_the_callers_frame():
    """``ξ'ᵀ Λ' ξ'`` of the shifted frames' perturbation equals ``ξᵀ Λ ξ`` of the caller's, where both perturb
    the one motion: ``S T' Exp(ξ') S⁻¹ = T Exp(ξ)``."""
    rng = np.random.default_rng(3)
    shift = np.array([30.0, -12.0, 5.0])
    t = _transform(rng)
    a = rng.normal(size=(6, 6))
    info_shifted = a @ a.T
    info = offsets.unshift_information(info_shifted, shift)
    caller = offsets.unshift_transforms(t, shift)
    s = np.eye(4)
    s[:3, 3] = shift
    for _ in range(5):
        xi = 1e-6 * rng.normal(size=6)
        # the ξ' that gives the same perturbed motion: Exp(ξ') = T'⁻¹ S⁻¹ T Exp(ξ) S
        moved = np.linalg.inv(t) @ np.linalg.inv(s) @ caller @ _exp(xi) @ s
        xi_shifted = np.array([moved[2, 1], moved[0, 2], moved[1, 0], *moved[:3, 3]])
        np.testing.assert_allclose(xi @ info @ xi, xi_shifted @ info_shifted @ xi_shifted, rtol=1e-5)
