"""Is model B better than model A on the same pairs, beyond the noise of the test file? A paired bootstrap.

    python -m experiments.eval --dataset=partial --split val --data-root PATH --methods rpmnet --checkpoint A.npz --output eval_a
    python -m experiments.eval --dataset=partial --split val --data-root PATH --methods rpmnet --checkpoint B.npz --output eval_b
    python -m experiments.compare_states eval_a/per_pair_rpmnet.csv eval_b/per_pair_rpmnet.csv

Prints JSON: for the mean, the median and the share under 5° of the rotation error, A, B, B - A and the 95%
interval of B - A over resampled pairs; ``resolved`` when the interval excludes 0. The two files must hold the
same pairs (their ``idx`` column).
"""

from __future__ import annotations

import argparse
import json
import os
import sys


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("csv_a", help="per_pair_<method>.csv of model A (the reference)")
    p.add_argument("csv_b", help="per_pair_<method>.csv of model B, on the same pairs")
    p.add_argument("--column", default="err_r_deg", help="the error column (default: isotropic rotation error)")
    p.add_argument("--threshold", type=float, default=5.0, help="the share_under threshold, in the column's unit")
    p.add_argument("--resamples", type=int, default=5000)
    p.add_argument("--level", type=float, default=0.95)
    p.add_argument("--seed", type=int, default=0)
    a = p.parse_args(argv)

    from rpmnet_jax.evaluation import paired

    try:
        if a.resamples < 100:
            raise ValueError(f"--resamples must be at least 100; got {a.resamples}")
        for path in (a.csv_a, a.csv_b):
            if not os.path.isfile(path):
                raise ValueError(f"no such file {path!r}")
        idx_a, err_a = paired.read_errors(a.csv_a, a.column)
        idx_b, err_b = paired.read_errors(a.csv_b, a.column)
        for path, idx in ((a.csv_a, idx_a), (a.csv_b, idx_b)):
            if len(set(idx.tolist())) != len(idx):
                raise ValueError(f"{path}: a pair ('idx') appears more than once")
        if sorted(idx_a.tolist()) != sorted(idx_b.tolist()):
            raise ValueError("the two files hold different pairs (their 'idx' columns differ); "
                             "evaluate both models with the same --dataset, --split, --data-root and --limit")
        err_b = err_b[idx_b.argsort()][idx_a.argsort().argsort()]  # B's rows in A's order
        result = paired.compare(err_a, err_b, resamples=a.resamples, level=a.level, threshold=a.threshold,
                                seed=a.seed)
    except ValueError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(json.dumps({"a": a.csv_a, "b": a.csv_b, "pairs": len(err_a), "column": a.column,
                      "threshold": a.threshold, "level": a.level, "resamples": a.resamples, **result}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
