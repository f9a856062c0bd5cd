"""The two PointNets (Flax) and their GroupNorm / fused per-neighbour MLP kernels."""
