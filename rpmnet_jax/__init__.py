"""rpmnet_jax: RPM-Net (Yew & Lee, CVPR 2020) as pure JAX functions and two Flax PointNets, and a registration
library around it.

Entry points: :func:`register` (the paper's network, jittable), :func:`align` (one pair of your clouds, any
orientation), :func:`align_scans` (many scans into one frame), :func:`load_params` (official ``.pth``, ``.npz``,
orbax). Layers, each importing only those below it: ``ops`` (pure jax.numpy) → ``nn`` (the two PointNets) →
``registration`` / ``losses`` / ``weights`` → ``geometry`` (host-side cloud geometry) → ``pairwise`` (``align``)
→ ``multiway`` (``align_scans``) → ``data``, ``evaluation``, ``train`` → ``cli``; ``io`` (files) serves them all.
"""

import importlib

# The public names, imported on first use (PEP 562): ``import rpmnet_jax.io.clouds`` (reading a file, a CLI's input
# checks) then loads neither JAX nor Flax, and ``rpmnet_jax.align`` loads what it needs when first touched.
_PUBLIC = {
    "RPMNetConfig": "rpmnet_jax.config", "evaluate_registration": "rpmnet_jax.classical.scoring",
    "ScanOptions": "rpmnet_jax.multiway.options", "ScanAlignment": "rpmnet_jax.multiway.scan_alignment",
    "align_scans": "rpmnet_jax.multiway.scan_alignment", "init_params": "rpmnet_jax.nn.pointnets",
    "Alignment": "rpmnet_jax.pairwise.alignment", "Answer": "rpmnet_jax.pairwise.alignment",
    "align": "rpmnet_jax.pairwise.alignment", "GlobalOptions": "rpmnet_jax.pairwise.options",
    "NetworkOptions": "rpmnet_jax.pairwise.options",
    "RefineOptions": "rpmnet_jax.pairwise.options", "Registration": "rpmnet_jax.registration",
    "register": "rpmnet_jax.registration", "convert": "rpmnet_jax.weights.convert",
    "load_default_params": "rpmnet_jax.weights.loading", "load_params": "rpmnet_jax.weights.loading",
}


def __getattr__(name: str):
    if name not in _PUBLIC:
        raise AttributeError(f"module 'rpmnet_jax' has no attribute {name!r}")
    module = importlib.import_module(_PUBLIC[name])
    value = module if name == "convert" else getattr(module, name)
    globals()[name] = value  # later lookups skip this function
    return value


def __dir__():
    return sorted(set(globals()) | set(_PUBLIC))


__all__ = ["Alignment", "Answer", "GlobalOptions", "NetworkOptions", "RPMNetConfig", "RefineOptions", "Registration",
           "ScanAlignment", "ScanOptions", "align", "align_scans", "convert", "evaluate_registration", "init_params",
           "load_default_params", "load_params", "register"]
__version__ = "0.1.0"
