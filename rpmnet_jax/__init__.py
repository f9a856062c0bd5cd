"""rpmnet_jax: RPM-Net (Yew & Lee, CVPR 2020) as pure JAX functions and two Flax PointNets."""

from rpmnet_jax.alignment import Alignment, align
from rpmnet_jax.config import RPMNetConfig
from rpmnet_jax.model import init_params
from rpmnet_jax.pretrained import load_default_params, load_params
from rpmnet_jax.registration import Registration, register

__all__ = ["Alignment", "RPMNetConfig", "Registration", "align", "init_params", "load_default_params",
           "load_params", "register"]
__version__ = "0.1.0"
