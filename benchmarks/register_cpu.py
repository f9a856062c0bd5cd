"""Time one jitted registration (default config, 5 iterations) and print one JSON line per size.

    python benchmarks/register_cpu.py --points 1024 --batch 1
"""

import argparse
import os
import sys

sys.path.insert(0, os.path.dirname(__file__))

import jax
import numpy as np

import rpmnet_jax
from common import emit, environment, peak_rss_mb, random_pair, time_jitted


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--points", type=int, nargs="+", default=[1024])
    parser.add_argument("--batch", type=int, nargs="+", default=[1])
    parser.add_argument("--repeats", type=int, default=10)
    args = parser.parse_args()
    params = rpmnet_jax.init_params(jax.random.PRNGKey(0))
    fn = jax.jit(rpmnet_jax.register)
    for n in args.points:
        for b in args.batch:
            src, ref = random_pair(np.random.default_rng(0), b, n)
            compile_s, run_s = time_jitted(fn, params, src, ref, repeats=args.repeats)
            emit({"impl": "jax", "task": "infer", "points": n, "batch": b, "iters": 5,
                  "seconds": run_s / b, "seconds_per_call": run_s, "compile_seconds": compile_s,
                  "peak_rss_mb": round(peak_rss_mb(), 1), **environment()})


if __name__ == "__main__":
    main()
