"""Official PyTorch RPM-Net weights ⇄ our parameter pytree.

Official names look like ``feat_extractor.prepool.0.weight``; ours are
``params["feat_extractor"]["prepool_0"]["kernel"]``. Convolutions with 1×1 kernels and linear layers
become Dense kernels ``(in, out)``; GroupNorm ``weight`` becomes ``scale``. torch is imported only to
read ``.pth`` files, with its tensors-only unpickler (a file is never allowed to run code).
"""

from __future__ import annotations

import os
from collections.abc import Mapping

import numpy as np

_MODULES = ("feat_extractor", "weights_net")
# Trailing singleton axes of the official kernels: Conv2d (out,in,1,1), Conv1d (out,in,1), Linear (out,in).
_KERNEL_TAIL = {
    ("feat_extractor", "prepool"): 2,
    ("feat_extractor", "postpool"): 1,
    ("weights_net", "prepool"): 1,
    ("weights_net", "postpool"): 0,
}


def _to_numpy(x) -> np.ndarray:
    if hasattr(x, "detach"):  # torch tensor
        x = x.detach().cpu().numpy()
    return np.asarray(x)


def _torch_load(path: str):
    """A ``.pth`` read with torch's tensors-only unpickler: a file that would run code or build other objects is
    refused (ValueError, one line) and nothing in it runs."""
    try:
        import torch
    except ImportError as e:  # pragma: no cover - depends on the environment
        raise ImportError("reading .pth checkpoints needs torch: pip install 'rpmnet_jax[torch]'") from e
    import pickle
    import warnings
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # torch's notes on pickle protocols
            return torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as e:
        lines = [l.strip() for l in str(e).splitlines()[1:] if l.strip()]
        reason = "; ".join(l for l in lines if not l.startswith(("Please file", "Check the documentation")))
        raise ValueError(f"{path}: refused: not a checkpoint of tensors only ({reason or 'unknown content'}); "
                         "pickled code or objects are never loaded") from None
    except (RuntimeError, EOFError, OSError) as e:
        raise ValueError(f"{path}: cannot read as a torch checkpoint ({type(e).__name__}: "
                         f"{str(e).splitlines()[0] if str(e) else ''})") from None


def load_state_dict(source) -> dict[str, np.ndarray]:
    """Official state dict as NumPy arrays from a mapping, an ``.npz`` or a ``.pth`` checkpoint."""
    if isinstance(source, (str, os.PathLike)):
        path = os.fspath(source)
        if not os.path.exists(path):
            raise FileNotFoundError(f"weights file not found: {path}")
        if path.endswith(".npz"):
            with np.load(path) as data:
                source = {k: data[k] for k in data.files}
        elif path.endswith((".pth", ".pt")):
            source = _torch_load(path)
        else:
            raise ValueError(f"unknown weights format {path!r}: expected .npz or .pth")
    if not isinstance(source, Mapping):
        raise TypeError(f"expected a mapping of official parameter names to arrays, got {type(source).__name__}")
    if "state_dict" in source and isinstance(source["state_dict"], Mapping):
        source = source["state_dict"]
    out = {}
    for key, value in source.items():
        name = key[len("param/"):] if key.startswith("param/") else key
        name = name[len("module."):] if name.startswith("module.") else name
        if name.split(".")[0] in _MODULES:
            out[name] = _to_numpy(value)
    if not out:
        raise ValueError("no RPM-Net parameters found: expected names starting with "
                         f"{' or '.join(_MODULES)} (optionally prefixed by 'param/' or 'module.')")
    return out


def params_from_torch(source) -> dict:
    """Our parameter pytree from official weights (mapping, ``.npz`` or ``.pth``; see module doc)."""
    params: dict = {}
    for name, value in load_state_dict(source).items():
        parts = name.split(".")
        module = parts[0]
        if parts[1:] == ["anneal_weights"]:  # constant annealing ablation
            params.setdefault(module, {})["anneal_weights"] = value.astype(np.float32)
            continue
        if len(parts) != 4 or parts[3] not in ("weight", "bias"):
            raise ValueError(f"unexpected official parameter name {name!r}")
        _, section, index, kind = parts
        layer = params.setdefault(module, {}).setdefault(f"{section}_{index}", {})
        if kind == "bias":
            layer["bias"] = value.astype(np.float32)
        elif value.ndim == 1:
            layer["scale"] = value.astype(np.float32)
        else:
            kernel = value.reshape(value.shape[:2])
            layer["kernel"] = np.ascontiguousarray(kernel.T).astype(np.float32)
    missing = [m for m in _MODULES if m not in params]
    if missing:
        raise ValueError(f"weights lack the module(s) {missing}")
    return params


def params_to_torch(params) -> dict[str, np.ndarray]:
    """Official state dict (names and shapes) from our parameter pytree."""
    out = {}
    for module in _MODULES:
        for layer, leaves in params[module].items():
            if layer == "anneal_weights":
                out[f"{module}.anneal_weights"] = np.asarray(leaves)
                continue
            section, index = layer.rsplit("_", 1)
            prefix = f"{module}.{section}.{index}"
            if "kernel" in leaves:
                kernel = np.asarray(leaves["kernel"]).T
                out[f"{prefix}.weight"] = kernel.reshape(kernel.shape + (1,) * _KERNEL_TAIL[(module, section)])
            else:
                out[f"{prefix}.weight"] = np.asarray(leaves["scale"])
            out[f"{prefix}.bias"] = np.asarray(leaves["bias"])
    return out
