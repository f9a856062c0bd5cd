"""The official RPM-Net training loss: per-iteration L1 registration loss plus the inlier loss."""

from __future__ import annotations

import jax.numpy as jnp

from rpmnet_jax import config as config_lib
from rpmnet_jax import registration
from rpmnet_jax.ops import se3

DISCOUNT = 0.5  # iteration i of N is weighted DISCOUNT ** (N - 1 - i)


def loss_terms(reg: registration.Registration, batch, cfg: config_lib.RPMNetConfig) -> dict:
    """Per-iteration losses ``mae (I,)``, ``inlier (I,)`` and the discounted ``total`` (scalar)."""
    xyz_src = batch["points_src"][..., :3]
    gt = se3.apply(batch["transform_gt"], xyz_src)  # (B, J, 3)
    pred = se3.apply(reg.transforms, xyz_src[None])  # (I, B, J, 3)
    mae = jnp.mean(jnp.abs(pred - gt[None]), axis=(1, 2, 3))
    perm = reg.perm_matrices
    ref_outliers = jnp.mean(1.0 - jnp.sum(perm, axis=2), axis=(1, 2))
    src_outliers = jnp.mean(1.0 - jnp.sum(perm, axis=3), axis=(1, 2))
    inlier = cfg.wt_inliers * (ref_outliers + src_outliers)
    num = mae.shape[0]
    discount = DISCOUNT ** jnp.arange(num - 1, -1, -1, dtype=mae.dtype)
    return {"mae": mae, "inlier": inlier, "total": jnp.sum(discount * (mae + inlier))}


def training_loss(params, batch, cfg: config_lib.RPMNetConfig = config_lib.RPMNetConfig()):
    """Scalar training loss with ``cfg.num_train_reg_iters`` iterations.

    ``batch``: ``points_src (B, J, 6)``, ``points_ref (B, K, 6)``, ``transform_gt (B, 3, 4)``.
    """
    reg = registration.register(params, batch["points_src"], batch["points_ref"], cfg,
                                num_iters=cfg.num_train_reg_iters, unroll=True)
    return loss_terms(reg, batch, cfg)["total"]
