"""Shared test helpers: fixture location, float64 context, random clouds."""

import contextlib
import os
import pathlib

import jax
import numpy as np
import pytest

from rpmnet_jax.ops import se3

FIXTURES = pathlib.Path(os.environ.get("RPMNET_FIXTURES",
                                       pathlib.Path(__file__).resolve().parents[2] / "shared" / "fixtures"))
DATA = FIXTURES.parent / "data"


def require_fixtures():
    if not FIXTURES.is_dir():
        pytest.skip(f"parity fixtures not found at {FIXTURES} (set RPMNET_FIXTURES to the shared/fixtures folder)")
    return FIXTURES


@contextlib.contextmanager
def float64():
    """Enables float64 inside the block (for finite-difference gradient checks)."""
    if hasattr(jax, "enable_x64"):
        with jax.enable_x64(True):
            yield
    else:  # older JAX
        from jax.experimental import enable_x64
        with enable_x64():
            yield


def random_cloud(rng: np.random.Generator, batch: int, n: int, scale: float = 1.0) -> np.ndarray:
    """``(batch, n, 6)`` float32 points in a cube with random unit normals."""
    xyz = rng.uniform(-scale, scale, size=(batch, n, 3))
    normals = rng.normal(size=(batch, n, 3))
    normals /= np.linalg.norm(normals, axis=-1, keepdims=True)
    return np.concatenate([xyz, normals], axis=-1).astype(np.float32)


def random_transform(rng: np.random.Generator, batch: int, trans_mag: float = 0.5) -> np.ndarray:
    """``(batch, 3, 4)`` uniformly random rotations with translations in ±trans_mag."""
    rot = se3.quaternion_to_matrix(rng.normal(size=(batch, 4)))
    trans = rng.uniform(-trans_mag, trans_mag, size=(batch, 3, 1))
    return np.concatenate([rot, trans], axis=-1)
