"""Thin input checks: shapes and dtypes before tracing (so they also work under jit), and the values of options
objects (one line each, naming the option)."""

import numpy as np


def check_cloud(name: str, x, *, channels: int = 6):
    """Raises ``ValueError`` unless ``x`` is a floating ``(B, N, channels)`` array with ``B, N ≥ 1``."""
    import jax.numpy as jnp  # here, not at import: the option checks below serve callers that need no JAX

    shape = tuple(getattr(x, "shape", np.shape(x)))
    dtype = getattr(x, "dtype", None)
    if dtype is None:
        dtype = np.asarray(x).dtype
    if len(shape) != 3:
        raise ValueError(f"{name} must have shape (B, N, {channels}) (xyz + normals), got rank {len(shape)} "
                         f"shape {shape}")
    if shape[-1] != channels:
        raise ValueError(f"{name} must have {channels} channels in the last axis (xyz + normals), got shape {shape}")
    if shape[0] == 0 or shape[1] == 0:
        raise ValueError(f"{name} is empty: shape {shape}; every cloud needs at least one point")
    if not jnp.issubdtype(dtype, jnp.floating):
        raise ValueError(f"{name} must be a floating-point array, got dtype {dtype}")


def check_pair(src, ref):
    """Checks a source/reference pair of clouds ``(B, J, 6)`` and ``(B, K, 6)``."""
    check_cloud("src", src)
    check_cloud("ref", ref)
    if src.shape[0] != ref.shape[0]:
        raise ValueError(f"src and ref must have the same batch size, got src {tuple(src.shape)} "
                         f"and ref {tuple(ref.shape)}")


def require_choice(name: str, value, choices) -> None:
    """Raises ``ValueError`` unless ``value`` is one of ``choices``."""
    if value not in choices:
        raise ValueError(f"{name} must be one of {tuple(choices)}, got {value!r}")


def require_at_least(name: str, value, least) -> None:
    """Raises ``ValueError`` unless ``value >= least``."""
    if not value >= least:
        raise ValueError(f"{name} must be >= {least}, got {value}")


def require_positive(name: str, value, optional: bool = False) -> None:
    """Raises ``ValueError`` unless ``value > 0`` (or, ``optional``, ``None``: a setting left to its default)."""
    if value is None and optional:
        return
    if value is None or not value > 0:
        raise ValueError(f"{name} must be > 0, got {value}")


def require_fraction(name: str, value) -> None:
    """Raises ``ValueError`` unless ``0 <= value <= 1``."""
    if not 0.0 <= value <= 1.0:
        raise ValueError(f"{name} must be in [0, 1], got {value}")
