"""Matmul throughput of the feature network against the machine's float32 matmul throughput.

    python benchmarks/feature_throughput.py [--points 1024] [--batch 1]

Prints one JSON line: the machine's measured float32 GEMM rate (a square matmul and one of the feature
network's own shapes), the feature network's dense-layer FLOPs per call, its time per call, and the
achieved fraction of the GEMM rate (the rest goes to GroupNorm, ReLU and max-pool memory passes).
"""

from __future__ import annotations

import argparse
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import jax
import jax.numpy as jnp
import numpy as np

from common import emit, environment, time_jitted
from rpmnet_jax import RPMNetConfig, init_params, registration


def gemm_gflops(m: int, k: int, n: int, repeats: int) -> float:
    a = jnp.asarray(np.random.default_rng(0).normal(size=(m, k)), jnp.float32)
    b = jnp.asarray(np.random.default_rng(1).normal(size=(k, n)), jnp.float32)
    _, seconds = time_jitted(jax.jit(jnp.matmul), a, b, repeats=repeats)
    return 2 * m * k * n / seconds / 1e9


def dense_flops(params: dict, rows_prepool: int, rows_postpool: int) -> int:
    """FLOPs of the feature network's dense layers (prepool runs per neighbour, postpool per point)."""
    total = 0
    for name, layer in params["feat_extractor"].items():
        if "kernel" in layer:
            rows = rows_prepool if name.startswith("prepool") else rows_postpool
            total += 2 * rows * layer["kernel"].shape[0] * layer["kernel"].shape[1]
    return total


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--points", type=int, default=1024)
    p.add_argument("--batch", type=int, default=1)
    p.add_argument("--repeats", type=int, default=10)
    a = p.parse_args()
    cfg = RPMNetConfig()
    params = init_params(jax.random.PRNGKey(0), cfg)
    import compare_torch
    src, _, _ = compare_torch._inputs(a.points, a.batch)
    xyz, nrm = jnp.asarray(src[..., :3]), jnp.asarray(src[..., 3:])
    hood = jax.block_until_ready(registration.group(xyz, nrm, cfg))
    fn = jax.jit(lambda p_, x, h: registration.features(p_, x, h, cfg))
    _, seconds = time_jitted(fn, params, xyz, hood, repeats=a.repeats)
    rows = a.batch * a.points * cfg.num_neighbors
    flops = dense_flops(params, rows, a.batch * a.points)
    square = gemm_gflops(2048, 2048, 2048, a.repeats)
    own_shape = gemm_gflops(rows, 96, 192, a.repeats)  # the largest per-neighbour layer
    achieved = flops / seconds / 1e9
    emit({"task": "feature_throughput", "points": a.points, "batch": a.batch, "feature_seconds": seconds,
          "feature_dense_gflop": flops / 1e9, "feature_gflops": achieved, "gemm_gflops_2048": square,
          "gemm_gflops_feature_shape": own_shape, "fraction_of_gemm": achieved / max(square, own_shape),
          **environment()})


if __name__ == "__main__":
    main()
