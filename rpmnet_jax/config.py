"""Model configuration: one frozen dataclass with the paper's defaults."""

from __future__ import annotations

import dataclasses

FEATURE_SIZES = {"xyz": 3, "dxyz": 3, "ppf": 4}
FEATURE_ORDER = ("xyz", "dxyz", "ppf")  # official concatenation order
ANNEAL_MODES = ("network", "constant")


@dataclasses.dataclass(frozen=True)
class RPMNetConfig:
    """Hyper-parameters of RPM-Net (defaults follow the paper and the official code).

    Attributes:
      radius: ball-query radius for the local neighbourhoods.
      num_neighbors: neighbours per point (static capacity).
      features: subset of ``("xyz", "dxyz", "ppf")``; always used in that order.
      feature_dim: dimension of the hybrid features.
      num_sk_iters: Sinkhorn normalisation iterations.
      add_slack: pad the match matrix with a slack row and column.
      num_reg_iters: registration iterations at inference.
      num_train_reg_iters: registration iterations in the training loss.
      wt_inliers: weight of the inlier (outlier-penalty) loss.
      anneal: ``"network"`` predicts alpha, beta per pair; ``"constant"`` learns one
        global pair (the ablation of the paper's Table 4).
      query_chunk: ball-query rows processed at once (bounds the O(N^2) memory).
      fused_prepool: differentiate the per-neighbour MLP + max-pool with the hand-written backward of
        :func:`rpmnet_jax.nn.fused_mlp_max.mlp_max` (about 2x faster training steps on CPU; same forward). Off, JAX
        autodiff reproduces the official float32 gradients to 1e-4.
    """

    radius: float = 0.3
    num_neighbors: int = 64
    features: tuple[str, ...] = ("xyz", "dxyz", "ppf")
    feature_dim: int = 96
    num_sk_iters: int = 5
    add_slack: bool = True
    num_reg_iters: int = 5
    num_train_reg_iters: int = 2
    wt_inliers: float = 0.01
    anneal: str = "network"
    query_chunk: int = 2048
    fused_prepool: bool = False

    def __post_init__(self):
        feats = tuple(self.features)
        unknown = [f for f in feats if f not in FEATURE_SIZES]
        if unknown or not feats or len(set(feats)) != len(feats):
            raise ValueError(
                f"features must be a non-empty subset of {FEATURE_ORDER} without repeats, got {feats!r}")
        object.__setattr__(self, "features", tuple(f for f in FEATURE_ORDER if f in feats))
        if self.anneal not in ANNEAL_MODES:
            raise ValueError(f"anneal must be one of {ANNEAL_MODES}, got {self.anneal!r}")
        if self.feature_dim % 8 or self.feature_dim <= 0:
            raise ValueError(f"feature_dim must be a positive multiple of 8 (GroupNorm groups), got {self.feature_dim}")
        for name in ("num_neighbors", "num_sk_iters", "num_reg_iters", "num_train_reg_iters", "query_chunk"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        if self.radius <= 0:
            raise ValueError(f"radius must be > 0, got {self.radius}")

    @property
    def raw_feature_dim(self) -> int:
        """Channels of the per-neighbour input to the feature network."""
        return sum(FEATURE_SIZES[f] for f in self.features)

    def replace(self, **changes) -> "RPMNetConfig":
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["features"] = list(self.features)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "RPMNetConfig":
        fields = {f.name for f in dataclasses.fields(cls)}
        kw = {k: v for k, v in d.items() if k in fields}
        if "features" in kw:
            kw["features"] = tuple(kw["features"])
        return cls(**kw)
