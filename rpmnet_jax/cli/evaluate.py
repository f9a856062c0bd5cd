"""Evaluate RPM-Net and baselines on the paper's protocol (deterministic test split), paper-style table.

    rpmnet-eval --dataset=partial --synthetic --limit 64 --methods rpmnet,rpm,identity
    rpmnet-eval --dataset=clean --data-root PATH/modelnet40_ply_hdf5_2048 --checkpoint model-best.pth
    rpmnet-eval --dataset=partial --synthetic --transforms-file pred.npy

Writes to --output: metrics.json, per_pair.csv / transforms.npy (first method; all methods with a
_<method> suffix), chamfer_per_iteration.png and qualitative.png.
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np


def parse_args(argv=None):
    from rpmnet_jax.evaluation import protocol
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--dataset", choices=("clean", "noisy", "partial"), default="partial")
    p.add_argument("--data-root", default=None, help="ModelNet40 modelnet40_ply_hdf5_2048 folder (or its parent)")
    p.add_argument("--synthetic", action="store_true",
                   help="evaluate on the synthetic dataset (generated into OUTPUT/synthetic unless --data-root)")
    p.add_argument("--split", choices=("test", "val"), default="test",
                   help="test = unseen last 20 categories (paper); val = test files, first 20 categories")
    p.add_argument("--checkpoint", default=None,
                   help="orbax training dir, .npz of official weights, or official .pth (default: shipped model)")
    p.add_argument("--methods", default="rpmnet,rpmnet_auto,ransac_icp,fgr_icp,rpm,icp,fgr,identity",
                   help=f"comma-separated subset of {','.join(protocol.METHODS)}")
    p.add_argument("--transforms-file", default=None,
                   help=".npy of (N, I, 3, 4) or (N, 3, 4) transforms produced elsewhere, evaluated as 'file'")
    p.add_argument("--output", default="eval_out", help="output folder")
    p.add_argument("--limit", type=int, default=None, help="evaluate the first N pairs only")
    p.add_argument("--num-points", type=int, default=1024)
    p.add_argument("--iters", type=int, default=5, help="RPM-Net registration iterations")
    p.add_argument("--rot-mag", type=float, default=45.0,
                   help="largest rotation per Euler axis in degrees (45: the paper; 180: any orientation)")
    p.add_argument("--batch-size", type=int, default=8)
    p.add_argument("--figures", type=int, default=4, help="qualitative examples to plot (0: none)")
    p.add_argument("--no-progress", action="store_true")
    a = p.parse_args(argv)
    methods = [m.strip() for m in a.methods.split(",") if m.strip()]
    unknown = [m for m in methods if m not in protocol.METHODS]
    if unknown:
        p.error(f"unknown methods {unknown}; choose from {','.join(protocol.METHODS)}")
    if a.transforms_file:
        methods = ["file"]
    if not a.synthetic and a.data_root is None:
        p.error("give --data-root (ModelNet40 modelnet40_ply_hdf5_2048) or --synthetic")
    if a.data_root is not None and not os.path.exists(a.data_root):
        p.error(f"--data-root {a.data_root!r} does not exist")
    for name in ("num_points", "iters", "batch_size"):
        if getattr(a, name) < 1:
            p.error(f"--{name.replace('_', '-')} must be >= 1")
    if not 0.0 <= a.rot_mag <= 180.0:
        p.error("--rot-mag must be in [0, 180]")
    if a.limit is not None and a.limit < 1:
        p.error("--limit must be >= 1")
    return a, methods


def main(argv=None) -> int:
    a, methods = parse_args(argv)
    from rpmnet_jax import data
    from rpmnet_jax.data import synthetic
    from rpmnet_jax import metrics
    from rpmnet_jax.evaluation import protocol
    from rpmnet_jax.weights import loading
    from rpmnet_jax.cli import plots

    os.makedirs(a.output, exist_ok=True)
    root = a.data_root
    if root is None:
        root = synthetic.ensure_dataset(os.path.join(a.output, "synthetic"), 40, 100, seed=0)
    try:
        ds = data.ModelNet40(root, a.split, a.dataset, num_points=a.num_points, rot_mag=a.rot_mag)
        if len(ds) == 0:
            raise ValueError(f"the {a.split} split of {root} is empty (the real subset has no test-category "
                             "shapes: use --split val)")
        params = loading.load_params(a.checkpoint) if any(m in protocol.NETWORK_METHODS for m in methods) else None
        file_t = None
        if a.transforms_file:
            file_t = np.load(a.transforms_file)
            file_t = file_t[:, None] if file_t.ndim == 3 else file_t
            n = len(ds) if a.limit is None else min(a.limit, len(ds))
            if file_t.ndim != 4 or file_t.shape[2:] != (3, 4) or len(file_t) < n:
                raise ValueError(f"--transforms-file must hold (N, I, 3, 4) or (N, 3, 4) with N >= {n}, "
                                 f"got {file_t.shape}")
    except (ValueError, FileNotFoundError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2

    rows, curves, first = {}, {}, None
    for name in methods:
        if name == "file":
            counter = iter(range(10**9))
            fn = lambda s, r: file_t[[next(counter) for _ in range(len(s))]]
        else:
            try:
                fn = protocol.method_fn(name, params, num_iters=a.iters)
            except RuntimeError as e:
                rows[name] = {"error": str(e)}
                continue
        per_pair, transforms, chamfer, sec = protocol.run_method(fn, ds, a.batch_size, a.limit,
                                                                   not a.no_progress, desc=name)
        summary = metrics.summarize_metrics({k: v for k, v in per_pair.items() if k not in ("idx", "label")})
        rows[name] = {"summary": summary, "seconds_per_pair": sec, "pairs": int(len(per_pair["idx"])),
                      "chamfer_per_iteration": chamfer.mean(axis=0).tolist()}
        curves[name] = chamfer.mean(axis=0)
        protocol.write_outputs(a.output, name, per_pair, transforms)
        if first is None:
            first = (name, transforms)
            protocol.write_outputs(a.output, "", per_pair, transforms)
    for suffix in ("per_pair_.csv", "transforms_.npy"):
        src = os.path.join(a.output, suffix)
        if os.path.exists(src):
            os.replace(src, os.path.join(a.output, suffix.replace("_.", ".")))
    table = protocol.format_table(rows)
    print(f"{a.dataset} / {a.split} split of {root}: {rows[first[0]]['pairs'] if first else 0} pairs")
    print(table)
    protocol.save_json(os.path.join(a.output, "metrics.json"),
                         {"dataset": a.dataset, "split": a.split, "root": root, "rot_mag": a.rot_mag, "methods": rows, "table": table})
    if first is not None:
        multi = {k: v for k, v in curves.items()}
        plots.plot_chamfer(os.path.join(a.output, "chamfer_per_iteration.png"), multi)
        if a.figures > 0:
            k = min(a.figures, len(first[1]))
            plots.plot_examples(os.path.join(a.output, "qualitative.png"), [ds[i] for i in range(k)], first[1][:k, -1])
    return 0


def entry() -> None:
    """Console script ``rpmnet-eval``."""
    from rpmnet_jax.cli import runtime
    runtime.run(main)


if __name__ == "__main__":
    entry()
