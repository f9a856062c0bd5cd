"""rpmnet_jax: RPM-Net (Yew & Lee, CVPR 2020) as pure JAX functions and two Flax PointNets.

Layers (each imports only the ones above it): ``ops`` (pure jax.numpy) → ``nn`` (the two PointNets) →
``registration`` / ``losses`` → ``weights`` (checkpoints in, shipped model out) → ``scans`` (own clouds),
``data``, ``evaluation``, ``train`` → ``cli`` (argument parsing, messages for people).
"""

from rpmnet_jax.config import RPMNetConfig
from rpmnet_jax.nn.pointnets import init_params
from rpmnet_jax.registration import Registration, register
from rpmnet_jax.scans.alignment import Alignment, Answer, align
from rpmnet_jax.scans.multiway import ScanAlignment, align_scans
from rpmnet_jax.scans.options import GlobalOptions, RefineOptions
from rpmnet_jax.scans.scoring import evaluate_registration
from rpmnet_jax.weights import convert
from rpmnet_jax.weights.loading import load_default_params, load_params

__all__ = ["Alignment", "Answer", "GlobalOptions", "RPMNetConfig", "RefineOptions", "Registration", "ScanAlignment", "align",
           "align_scans", "convert", "evaluate_registration", "init_params", "load_default_params", "load_params",
           "register"]
__version__ = "0.1.0"
