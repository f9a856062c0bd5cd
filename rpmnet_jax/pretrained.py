"""The model shipped inside the package, and loading parameters from any supported checkpoint."""

from __future__ import annotations

import json
import os

from rpmnet_jax import convert

WEIGHTS_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), "weights")
DEFAULT_WEIGHTS = os.path.join(WEIGHTS_DIR, "rpmnet_default.npz")
DEFAULT_INFO = os.path.join(WEIGHTS_DIR, "rpmnet_default.json")


def has_default() -> bool:
    return os.path.isfile(DEFAULT_WEIGHTS)


def default_info() -> dict:
    """How the shipped model was trained (command, data, steps, validation metrics)."""
    if not os.path.isfile(DEFAULT_INFO):
        return {}
    with open(DEFAULT_INFO) as f:
        return json.load(f)


def load_default_params() -> dict:
    """Parameters of the shipped model (official state-dict names in an ``.npz``)."""
    if not has_default():
        raise FileNotFoundError(f"no shipped model at {DEFAULT_WEIGHTS}; pass a checkpoint instead")
    return convert.params_from_torch(DEFAULT_WEIGHTS)


def load_params(path: str | None = None) -> dict:
    """Parameters from ``path``: an orbax training workdir/checkpoint, an ``.npz`` or an official ``.pth``;
    ``None`` gives the shipped model."""
    if path is None:
        return load_default_params()
    if not os.path.exists(path):
        raise FileNotFoundError(f"checkpoint not found: {path}")
    if os.path.isdir(path):
        from rpmnet_jax import training
        return training.restore_params(path)
    if path.endswith((".npz", ".pth", ".pt", ".tar")):
        return convert.params_from_torch(path)
    raise ValueError(f"unknown checkpoint format {path!r}: expected an orbax directory, .npz or .pth")
