"""Matmul throughput of the feature network against the machine's float32 matmul throughput.

    python benchmarks/feature_throughput.py [--points 1024] [--batch 1] [--repeats 10] [--threads N]

Prints one JSON line: the machine's measured float32 GEMM rate (a square matmul and one of the feature
network's own shapes), the feature network's dense-layer FLOPs per call, its median time per call (compile
time apart: ``compile_seconds``), and the achieved fraction of the GEMM rate (the rest goes to GroupNorm, ReLU
and max-pool memory passes).
"""

from __future__ import annotations

import argparse

import bench_utils


def gemm_gflops(m: int, k: int, n: int, repeats: int) -> float:
    import jax
    import jax.numpy as jnp
    import numpy as np
    a = jnp.asarray(np.random.default_rng(0).normal(size=(m, k)), jnp.float32)
    b = jnp.asarray(np.random.default_rng(1).normal(size=(k, n)), jnp.float32)
    return 2 * m * k * n / bench_utils.time_jax(jax.jit(jnp.matmul), a, b, repeats=repeats)["seconds"] / 1e9


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
    p.add_argument("--threads", type=int, default=bench_utils.available_cpus(), help="CPUs to run on (default: all)")
    a = p.parse_args()
    bench_utils.pin(a.threads)
    import jax
    import jax.numpy as jnp
    from rpmnet_jax import RPMNetConfig, init_params, registration
    cfg = RPMNetConfig()
    params = init_params(jax.random.PRNGKey(0), cfg)
    src, _, _ = bench_utils.inputs(a.points, a.batch)
    xyz, nrm = jnp.asarray(src[..., :3]), jnp.asarray(src[..., 3:])
    hood = jax.block_until_ready(registration.group(xyz, nrm, cfg))
    fn = jax.jit(lambda p_, x, h: registration.features(p_, x, h, cfg))
    timing = bench_utils.time_jax(fn, params, xyz, hood, repeats=a.repeats)
    rows = a.batch * a.points * cfg.num_neighbors
    flops = dense_flops(params, rows, a.batch * a.points)
    square = gemm_gflops(2048, 2048, 2048, a.repeats)
    own_shape = gemm_gflops(rows, 96, 192, a.repeats)  # the largest per-neighbour layer
    achieved = flops / timing["seconds"] / 1e9
    bench_utils.emit({"task": "feature_throughput", "points": a.points, "batch": a.batch,
                      "feature_seconds": timing["seconds"], "feature_min_seconds": timing["min_seconds"],
                      "feature_max_seconds": timing["max_seconds"], "compile_seconds": timing["compile_seconds"],
                      "feature_dense_gflop": flops / 1e9, "feature_gflops": achieved, "gemm_gflops_2048": square,
                      "gemm_gflops_feature_shape": own_shape, "fraction_of_gemm": achieved / max(square, own_shape),
                      "threads": a.threads, **bench_utils.environment()})


if __name__ == "__main__":
    main()
