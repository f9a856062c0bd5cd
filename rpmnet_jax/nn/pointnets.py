"""The two PointNets of RPM-Net as Flax (Linen) modules, layer for layer as in the official model.

Layer names carry the index of the matching layer in the official ``nn.Sequential`` (``prepool_0`` is
``prepool.0``), which keeps weight conversion a renaming. Initialisation follows PyTorch's defaults.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import flax.linen as nn

from rpmnet_jax import config as config_lib
from rpmnet_jax.nn import fused_mlp_max
from rpmnet_jax.nn.group_norm import GroupNorm


def _uniform(bound: float):
    def init(key, shape, dtype=jnp.float32):
        return jax.random.uniform(key, shape, dtype, -bound, bound)
    return init


def _dense(fan_in: int, features: int, name: str) -> nn.Dense:
    """Dense layer initialised like torch Conv/Linear: U(±1/sqrt(fan_in)) for kernel and bias."""
    bound = 1.0 / fan_in**0.5
    return nn.Dense(features, kernel_init=_uniform(bound), bias_init=_uniform(bound), name=name)


def _on_rows(dense: nn.Dense, h_BxNxC):
    """``dense`` applied to ``h (B, N, C)`` as one ``(B*N, C)`` matrix: the kernel gradient is then one plain
    GEMM, where the 3-D form makes XLA transpose the whole activation first (ParameterNet backward 2-3x
    faster)."""
    b, n, c = h_BxNxC.shape
    return dense(h_BxNxC.reshape(b * n, c)).reshape(b, n, -1)


def _group_norm(groups: int, name: str) -> GroupNorm:
    return GroupNorm(groups=groups, name=name)


class _DenseParams(nn.Module):
    """The ``kernel (fan_in, features)`` and ``bias`` of a Dense layer, initialised like :func:`_dense`."""

    fan_in: int
    features: int

    @nn.compact
    def __call__(self):
        bound = 1.0 / self.fan_in**0.5
        return (self.param("kernel", _uniform(bound), (self.fan_in, self.features)),
                self.param("bias", _uniform(bound), (self.features,)))


class _NormParams(nn.Module):
    """The ``scale`` and ``bias`` ``(C,)`` of a :class:`GroupNorm` layer."""

    channels: int

    @nn.compact
    def __call__(self):
        return (self.param("scale", nn.initializers.ones, (self.channels,)),
                self.param("bias", nn.initializers.zeros, (self.channels,)))


class FeatureNet(nn.Module):
    """Hybrid-feature PointNet: per-neighbour MLP, max over neighbours, MLP, L2 normalisation.

    ``(B, N, k, C_raw)`` → ``(B, N, feature_dim)`` unit vectors. With ``fused`` the per-neighbour part runs
    as one operation with a lean hand-written backward (:func:`rpmnet_jax.nn.fused_mlp_max.mlp_max`).
    """

    raw_dim: int = 10
    feature_dim: int = 96
    fused: bool = False

    @nn.compact
    def __call__(self, x_BxNxKxC):
        d = self.feature_dim
        layers = []
        for i, (fan_in, out) in enumerate([(self.raw_dim, d), (d, d), (d, 2 * d)]):
            kernel, bias = _DenseParams(fan_in, out, name=f"prepool_{3 * i}")()
            scale, shift = _NormParams(out, name=f"prepool_{3 * i + 1}")()
            layers.append(fused_mlp_max.Layer(kernel, bias, scale, shift))
        pool = fused_mlp_max.mlp_max if self.fused else fused_mlp_max.mlp_max_reference
        h_BxNxC = pool(x_BxNxKxC, tuple(layers), 8)
        h_BxNxC = nn.relu(_group_norm(8, "postpool_1")(_on_rows(_dense(2 * d, 2 * d, "postpool_0"), h_BxNxC)))
        h_BxNxC = nn.relu(_group_norm(8, "postpool_4")(_on_rows(_dense(2 * d, d, "postpool_3"), h_BxNxC)))
        h_BxNxC = _on_rows(_dense(d, d, "postpool_6"), h_BxNxC)
        return h_BxNxC / jnp.linalg.norm(h_BxNxC, axis=-1, keepdims=True)


class ParameterNet(nn.Module):
    """PointNet predicting the annealing parameters from both clouds.

    ``xyz_src (B, J, 3)``, ``xyz_ref (B, K, 3)`` → ``(beta (B,), alpha (B,))``, both softplus-positive.
    """

    @nn.compact
    def __call__(self, xyz_src, xyz_ref):
        b = xyz_src.shape[0]
        src = jnp.concatenate([xyz_src, jnp.zeros((b, xyz_src.shape[1], 1), xyz_src.dtype)], axis=-1)
        ref = jnp.concatenate([xyz_ref, jnp.ones((b, xyz_ref.shape[1], 1), xyz_ref.dtype)], axis=-1)
        h = jnp.concatenate([src, ref], axis=1)  # (B, J+K, 4)
        layers = [(4, 64, 8), (64, 64, 8), (64, 64, 8), (64, 128, 8), (128, 1024, 16)]
        for i, (fan_in, out, groups) in enumerate(layers):
            h = _on_rows(_dense(fan_in, out, f"prepool_{3 * i}"), h)
            h = nn.relu(_group_norm(groups, f"prepool_{3 * i + 1}")(h))
        h = jnp.max(h, axis=1)  # (B, 1024)
        h = nn.relu(_group_norm(16, "postpool_1")(_dense(1024, 512, "postpool_0")(h)))
        h = nn.relu(_group_norm(16, "postpool_4")(_dense(512, 256, "postpool_3")(h)))
        raw = _dense(256, 2, "postpool_6")(h)
        return jax.nn.softplus(raw[:, 0]), jax.nn.softplus(raw[:, 1])


class ConstantParameters(nn.Module):
    """Ablation: one learned (beta, alpha) pair shared by every input (``anneal="constant"``)."""

    @nn.compact
    def __call__(self, xyz_src, xyz_ref):
        raw = self.param("anneal_weights", nn.initializers.zeros, (2,))
        b = xyz_src.shape[0]
        return (jnp.broadcast_to(jax.nn.softplus(raw[0]), (b,)),
                jnp.broadcast_to(jax.nn.softplus(raw[1]), (b,)))


def feature_net(cfg: config_lib.RPMNetConfig) -> FeatureNet:
    return FeatureNet(raw_dim=cfg.raw_feature_dim, feature_dim=cfg.feature_dim, fused=cfg.fused_prepool)


def parameter_net(cfg: config_lib.RPMNetConfig) -> nn.Module:
    return ParameterNet() if cfg.anneal == "network" else ConstantParameters()


def init_params(key, cfg: config_lib.RPMNetConfig | None = None) -> dict:
    """Fresh parameters ``{"feat_extractor": ..., "weights_net": ...}`` (a plain pytree of arrays)."""
    cfg = cfg or config_lib.RPMNetConfig()
    k_feat, k_weights = jax.random.split(key)
    k = min(cfg.num_neighbors, 4)
    dummy_feat = jnp.zeros((1, 4, k, cfg.raw_feature_dim), jnp.float32)
    dummy_xyz = jnp.zeros((1, 4, 3), jnp.float32)
    feat = feature_net(cfg).init(k_feat, dummy_feat)["params"]
    weights = parameter_net(cfg).init(k_weights, dummy_xyz, dummy_xyz)["params"]
    return {"feat_extractor": _plain(feat), "weights_net": _plain(weights)}


def _plain(tree):
    """Nested plain dicts (Flax may hand back FrozenDicts)."""
    if hasattr(tree, "items"):
        return {k: _plain(v) for k, v in tree.items()}
    return tree
