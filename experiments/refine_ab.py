"""Refinement A/B: our ICP (as `align` runs it) against Open3D's robust point-to-plane ICP, same starts.

    python -m experiments.refine_ab --data-root PATH/modelnet40_real_subset --split val --limit 40 --out ab.csv

Pairs of the protocol's deterministic split; starts: the truth perturbed by 3-10 deg (seeded) and/or the
network's answer (`rpmnet`). Prints a JSON summary; `--out` writes the per-pair CSV
(:mod:`rpmnet_jax.evaluation.refine_ab`).
"""

from __future__ import annotations

import argparse
import json
import os
import sys


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--data-root", required=True, help="a modelnet40_ply_hdf5_2048 folder (or its parent)")
    p.add_argument("--dataset", default="partial", choices=("clean", "noisy", "partial"))
    p.add_argument("--split", default="val", choices=("train", "val", "test"))
    p.add_argument("--starts", default="perturbed,rpmnet", help="comma-separated subset of perturbed,rpmnet")
    p.add_argument("--limit", type=int, default=None, help="the first N pairs only")
    p.add_argument("--rot-mag", type=float, default=45.0, help="the protocol's rotation per Euler axis (deg)")
    p.add_argument("--num-points", type=int, default=1024)
    p.add_argument("--seed", type=int, default=0, help="seed of the perturbations and of align's sampling")
    p.add_argument("--checkpoint", default=None, help="network weights for the rpmnet start (default: shipped)")
    p.add_argument("--out", default=None, help="per-pair CSV")
    p.add_argument("--no-progress", action="store_true")
    a = p.parse_args(argv)
    starts = [s.strip() for s in a.starts.split(",") if s.strip()]
    if not os.path.exists(a.data_root):
        p.error(f"--data-root {a.data_root!r} does not exist")
    if a.limit is not None and a.limit < 1:
        p.error("--limit must be >= 1")

    from rpmnet_jax import data
    from rpmnet_jax.evaluation import baselines, refine_ab
    from rpmnet_jax.weights import loading

    why = baselines.open3d_available()
    if why:
        print(f"error: {why}", file=sys.stderr)
        return 2
    try:
        ds = data.ModelNet40(a.data_root, a.split, a.dataset, num_points=a.num_points, rot_mag=a.rot_mag)
        params = loading.load_params(a.checkpoint) if "rpmnet" in starts else None
        rows = refine_ab.run(ds, starts, a.limit, params, a.seed, progress=not a.no_progress)
    except (ValueError, FileNotFoundError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    if a.out:
        refine_ab.write_csv(a.out, rows)
    print(json.dumps({"data_root": a.data_root, "split": a.split, "dataset": a.dataset, "rot_mag": a.rot_mag,
                      "seed": a.seed, "summary": refine_ab.summarize(rows)}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
