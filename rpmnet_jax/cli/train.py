"""Train RPM-Net on one of the paper's ModelNet40 protocols (or on the synthetic dataset).

    python -m experiments.train --dataset=noisy --data-root PATH/modelnet40_ply_hdf5_2048
    python -m experiments.train --dataset=partial --synthetic --max-steps 200

Running the same command again resumes from the last checkpoint in --workdir (exactly: same step,
optimiser state and data order); settings that define the data, the network or the learning-rate schedule
(--batch-size; with --lr-schedule cosine also --epochs and --max-steps) cannot change on resume. Ctrl-C
(SIGINT) or SIGTERM saves a checkpoint at the next step and exits; a second Ctrl-C aborts at once.
"""

import argparse
import json
import os
import sys

from rpmnet_jax import config as config_lib
from rpmnet_jax import data
from rpmnet_jax import train as training
from rpmnet_jax.cli import runtime


def parse_args(argv=None) -> training.TrainConfig:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--dataset", choices=data.PROTOCOLS, default="noisy",
                   help="protocol: clean (same points), noisy (resampled + jitter), partial (+ crop to 70%%)")
    p.add_argument("--data-root", default=None, help="ModelNet40 folder modelnet40_ply_hdf5_2048 (or its parent); several folders comma-separated "
                   "are concatenated, and with --synthetic they are used next to the synthetic set")
    p.add_argument("--synthetic", action="store_true", help="train on the synthetic dataset, generated into the workdir")
    p.add_argument("--synthetic-train", type=int, default=400, help="synthetic training shapes (default 400)")
    p.add_argument("--synthetic-test", type=int, default=100, help="synthetic test shapes (default 100)")
    p.add_argument("--workdir", default=None, help="checkpoints, config.json, TensorBoard logs (default runs/<dataset>)")
    p.add_argument("--epochs", type=int, default=100)
    p.add_argument("--max-steps", type=int, default=None, help="stop after this many steps in total (resumed ones count)")
    p.add_argument("--batch-size", type=int, default=None, help="default 8 for partial, 4 for clean/noisy")
    p.add_argument("--num-points", type=int, default=1024, help="points per full cloud (partial keeps 70%%)")
    p.add_argument("--rot-mag", type=float, default=45.0,
                   help="largest training rotation per Euler axis, degrees (default 45 as the paper; validation stays at 45)")
    p.add_argument("--views-share", type=float, default=0.0,
                   help="partial only: share of training pairs cut as camera views with self-occlusion instead of "
                        "the paper's half-space crop (default 0; validation keeps the paper's crops)")
    p.add_argument("--lr", type=float, default=1e-4, help="Adam learning rate (default 1e-4)")
    p.add_argument("--val-every", type=int, default=1, help="validate every N epochs")
    p.add_argument("--val-limit", type=int, default=None, help="validate on at most N pairs")
    p.add_argument("--save-every", type=int, default=100, help="checkpoint every N steps (and every epoch)")
    p.add_argument("--keep", type=int, default=3, help="latest checkpoints to keep (the best is kept apart)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--features", default="xyz,dxyz,ppf", help="feature subset for the ablation, e.g. ppf or dxyz,ppf")
    p.add_argument("--anneal", choices=("network", "constant"), default="network",
                   help="annealing parameters from the parameter network, or one learned constant pair")
    p.add_argument("--train-iters", type=int, default=2, help="registration iterations in training (default 2)")
    p.add_argument("--val-iters", type=int, default=5, help="registration iterations at validation (default 5)")
    p.add_argument("--wt-inliers", type=float, default=1e-2, help="weight of the inlier loss (default 0.01)")
    p.add_argument("--autodiff-prepool", action="store_true",
                   help="differentiate the per-neighbour MLP with JAX autodiff (float32 gradients identical to "
                        "the official code) instead of the ~2x faster hand-written backward")
    p.add_argument("--init-from", default=None,
                   help="start from these params (.npz, official .pth or an orbax workdir) with a fresh optimizer; "
                        "ignored when --workdir already holds checkpoints (the run resumes)")
    p.add_argument("--lr-schedule", choices=("constant", "cosine"), default="constant",
                   help="constant (default) or linear warmup + cosine decay to --lr-final over the run")
    p.add_argument("--warmup-steps", type=int, default=0, help="linear learning-rate warmup steps")
    p.add_argument("--lr-final", type=float, default=0.0, help="final learning rate of the cosine schedule")
    p.add_argument("--clip-norm", type=float, default=None, help="clip gradients to this global norm")
    p.add_argument("--ema-decay", type=float, default=None,
                   help="validate and keep an exponential moving average of the params (e.g. 0.999)")
    p.add_argument("--val-every-steps", type=int, default=None, help="also validate every N steps")
    p.add_argument("--coordinator-address", default=None,
                   help="multi-process training: HOST:PORT of process 0 (or JAX_COORDINATOR_ADDRESS); run the same "
                        "command on every machine with its own --process-id")
    p.add_argument("--num-processes", type=int, default=None, help="processes in a multi-process run (JAX_NUM_PROCESSES)")
    p.add_argument("--process-id", type=int, default=None, help="this process's index, 0 first (JAX_PROCESS_ID)")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    a = p.parse_args(argv)
    if not a.synthetic and a.data_root is None:
        p.error("give --data-root (the ModelNet40 modelnet40_ply_hdf5_2048 folder) or --synthetic")
    for root in (a.data_root or "").split(","):
        if root and not os.path.exists(root):
            p.error(f"--data-root {root!r} does not exist; download ModelNet40 (PointNet's "
                    "modelnet40_ply_hdf5_2048) or use --synthetic")
    for name in ("epochs", "num_points", "val_every", "save_every", "keep", "train_iters", "val_iters"):
        if getattr(a, name) < 1:
            p.error(f"--{name.replace('_', '-')} must be >= 1")
    if a.init_from is not None and not os.path.exists(a.init_from):
        p.error(f"--init-from {a.init_from!r} does not exist")
    if not 0.0 <= a.rot_mag <= 180.0:
        p.error("--rot-mag must be in [0, 180]")
    if not 0.0 <= a.views_share <= 1.0:
        p.error("--views-share must be in [0, 1]")
    if a.views_share and a.dataset != "partial":
        p.error("--views-share needs --dataset=partial")
    if a.ema_decay is not None and not 0.0 < a.ema_decay < 1.0:
        p.error("--ema-decay must be in (0, 1)")
    if a.batch_size is not None and a.batch_size < 1:
        p.error("--batch-size must be >= 1")
    try:
        model_cfg = config_lib.RPMNetConfig(features=tuple(f.strip() for f in a.features.split(",") if f.strip()),
                                            anneal=a.anneal, fused_prepool=not a.autodiff_prepool, num_train_reg_iters=a.train_iters,
                                            num_reg_iters=a.val_iters, wt_inliers=a.wt_inliers)
    except ValueError as e:
        p.error(str(e))
    return training.TrainConfig(
        dataset=a.dataset, data_root=a.data_root, synthetic=a.synthetic, synthetic_train=a.synthetic_train,
        synthetic_test=a.synthetic_test, workdir=a.workdir or os.path.join("runs", a.dataset), epochs=a.epochs,
        max_steps=a.max_steps, batch_size=a.batch_size, num_points=a.num_points, rot_mag=a.rot_mag,
        views_share=a.views_share, lr=a.lr, val_every=a.val_every,
        val_limit=a.val_limit, save_every=a.save_every, keep=a.keep, seed=a.seed, init_from=a.init_from,
        lr_schedule=a.lr_schedule, warmup_steps=a.warmup_steps, lr_final=a.lr_final, clip_norm=a.clip_norm,
        ema_decay=a.ema_decay, val_every_steps=a.val_every_steps, model=model_cfg), not a.no_progress, a


def main(argv=None):
    cfg, progress, a = parse_args(argv)
    training.initialize_distributed(a.coordinator_address, a.num_processes, a.process_id)
    try:
        summary = training.train_and_evaluate(cfg, progress=progress)
    except (FileNotFoundError, FloatingPointError, ValueError, training.CheckpointError) as e:
        hint = ""
        if isinstance(e, training.ConfigMismatchError):
            flags = ", ".join("the model flags" if k == "model" else "--" + k.replace("_", "-") for k in e.settings)
            hint = f"; resume with the saved {flags}, or use another --workdir to start a new run"
        elif isinstance(e, training.CheckpointError) and "no usable checkpoint" in str(e):
            hint = "; run the same command again to start from step 0"
        print(f"rpmnet-train: error: {e}{hint}", file=sys.stderr)
        return 2
    summary.pop("losses")
    print("summary " + json.dumps(summary))
    return 0


def entry() -> None:
    """Console script ``rpmnet-train`` (with the training malloc tunables, :mod:`rpmnet_jax.cli.runtime`)."""
    runtime.run(main, huge_pages=True)


if __name__ == "__main__":
    entry()
