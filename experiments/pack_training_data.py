"""Write the compact training data a GPU run carries (``rpmnet_jax.data.pack``; float16, 1,280 points a shape).

    python -m experiments.pack_training_data --data-root ../shared/data/modelnet40_real_subset,../shared/data/real_meshes_train \
        --out runs/pack

Prints one JSON line: per folder the shapes packed and the bytes written, and the total in MiB.
"""

from __future__ import annotations

import argparse
import json
import sys


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--data-root", required=True, help="comma-separated ModelNet40-format folders")
    p.add_argument("--out", required=True, help="a new folder")
    p.add_argument("--num-points", type=int, default=1280, help="points kept per shape (of 2,048)")
    p.add_argument("--val-shapes", type=int, default=32, help="validation shapes kept per folder")
    p.add_argument("--seed", type=int, default=0)
    a = p.parse_args(argv)
    from rpmnet_jax.data import pack
    roots = [r for r in a.data_root.split(",") if r]
    try:
        if a.num_points < 1 or a.val_shapes < 1:
            raise ValueError("--num-points and --val-shapes must be >= 1")
        report = pack.pack(roots, a.out, a.num_points, a.val_shapes, a.seed)
    except (OSError, ValueError, KeyError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    mib = sum(r["bytes"] for r in report.values()) / 2**20
    print(json.dumps({"out": a.out, "num_points": a.num_points, "folders": report, "mib": round(mib, 1)}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
