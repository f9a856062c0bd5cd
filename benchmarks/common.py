"""Helpers shared by the benchmark scripts: timing with compile time apart, environment facts."""

from __future__ import annotations

import json
import platform
import resource
import statistics
import sys
import time

import jax
import numpy as np


def environment() -> dict:
    dev = jax.devices()[0]
    return {"device": f"{dev.platform}:{getattr(dev, 'device_kind', '')}".rstrip(":"),
            "jax": jax.__version__, "python": platform.python_version(), "machine": platform.machine()}


def peak_rss_mb() -> float:
    """Peak resident set size of this process in MiB."""
    scale = 1 if sys.platform == "darwin" else 1024  # ru_maxrss is bytes on macOS, KiB on Linux
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * scale / 2**20


def time_jitted(fn, *args, repeats: int = 10) -> tuple[float, float]:
    """``(compile_seconds, median_run_seconds)`` of a jitted ``fn``; results blocked on."""
    t0 = time.perf_counter()
    jax.block_until_ready(fn(*args))
    compile_s = time.perf_counter() - t0
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - t0)
    return compile_s, statistics.median(times)


def emit(record: dict) -> None:
    print(json.dumps(record), flush=True)


def random_pair(rng: np.random.Generator, batch: int, n: int, m: int | None = None):
    """A random source/reference pair ``(B, n, 6)``, ``(B, m, 6)`` on a unit sphere-ish shell."""
    m = n if m is None else m

    def cloud(k):
        xyz = rng.normal(size=(batch, k, 3))
        xyz /= np.linalg.norm(xyz, axis=-1, keepdims=True)
        return np.concatenate([xyz * 0.8, xyz], -1).astype(np.float32)

    return cloud(n), cloud(m)
