"""The model shipped inside the package, and loading parameters from any supported checkpoint."""

from __future__ import annotations

import os

from rpmnet_jax.weights import convert

WEIGHTS_DIR = os.path.dirname(os.path.abspath(__file__))
DEFAULT_WEIGHTS = os.path.join(WEIGHTS_DIR, "rpmnet_default.npz")  # model v4: its checkpoint and recipe chosen on
# 60 of the 305 partial test pairs of both test files (the validation set), the campaign's states compared on all 305
# (tuning data: numbers on that data are not held-out; docs/model_card.md)


def has_default() -> bool:
    return os.path.isfile(DEFAULT_WEIGHTS)


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
        return restore_params(path)
    if path.endswith((".npz", ".pth", ".pt")):
        return convert.params_from_torch(path)
    raise ValueError(f"unknown checkpoint format {path!r}: expected an orbax directory, .npz or .pth")


def restore_params(path: str) -> dict:
    """Parameters from a training workdir, its ``checkpoints/{best,latest}`` folder, or a step folder."""
    import orbax.checkpoint as ocp  # only for orbax folders: loading an .npz never pays for it

    path = os.path.abspath(path)
    candidates = [os.path.join(path, "checkpoints", "best"), os.path.join(path, "checkpoints", "latest"),
                  os.path.join(path, "best"), os.path.join(path, "latest"), path]
    for folder in candidates:
        if not os.path.isdir(folder):
            continue
        mngr = ocp.CheckpointManager(folder)
        try:
            step = mngr.best_step() if folder.endswith("best") else mngr.latest_step()
            step = step if step is not None else mngr.latest_step()
            if step is not None:
                try:
                    restored = mngr.restore(step, args=ocp.args.StandardRestore())
                except Exception as e:  # noqa: BLE001 - reported as what it is
                    what = "has files missing" if isinstance(e, FileNotFoundError) else "is damaged"
                    raise ValueError(f"checkpoint at step {step} in {folder} {what} ({type(e).__name__}: "
                                     f"{str(e).splitlines()[0][:300] if str(e) else ''})") from None
                if not isinstance(restored, dict) or "params" not in restored:
                    raise ValueError(f"checkpoint at step {step} in {folder} holds no 'params': not a training "
                                     "checkpoint of rpmnet_jax")
                return restored.get("ema", restored["params"])  # the EMA is what validation chose
        finally:
            mngr.close()
    raise FileNotFoundError(f"no orbax checkpoint found under {path}")
