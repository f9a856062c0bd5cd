"""rpmnet_jax: RPM-Net (Yew & Lee, CVPR 2020) as pure JAX functions and two Flax PointNets, and a registration
library around it.

Entry points: :func:`register` (the paper's network, jittable), :func:`align` (one pair of your clouds, any
orientation), :func:`align_scans` (many scans into one frame), :func:`load_params` (official ``.pth``, ``.npz``,
orbax). Layers, each importing only those below it: ``ops`` (pure jax.numpy) → ``nn`` (the two PointNets) →
``registration`` / ``losses`` / ``weights`` → ``geometry`` (host-side cloud geometry) → ``pairwise`` (``align``)
→ ``multiway`` (``align_scans``) → ``data``, ``evaluation``, ``train`` → ``cli``; ``io`` (files) serves them all.
"""

from rpmnet_jax.config import RPMNetConfig
from rpmnet_jax.geometry.scoring import evaluate_registration
from rpmnet_jax.multiway.options import ScanOptions
from rpmnet_jax.multiway.scan_alignment import ScanAlignment, align_scans
from rpmnet_jax.nn.pointnets import init_params
from rpmnet_jax.pairwise.alignment import Alignment, Answer, align
from rpmnet_jax.pairwise.options import GlobalOptions, RefineOptions
from rpmnet_jax.registration import Registration, register
from rpmnet_jax.weights import convert
from rpmnet_jax.weights.loading import load_default_params, load_params

__all__ = ["Alignment", "Answer", "GlobalOptions", "RPMNetConfig", "RefineOptions", "Registration", "ScanAlignment",
           "ScanOptions", "align", "align_scans", "convert", "evaluate_registration", "init_params",
           "load_default_params", "load_params", "register"]
__version__ = "0.1.0"
