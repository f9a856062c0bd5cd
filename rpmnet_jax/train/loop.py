"""The training loop: data, resume, steps, periodic validation and checkpoints, SIGTERM handling."""

from __future__ import annotations

import json
import logging
import math
import os
import signal
import time

import jax
import jax.numpy as jnp
import numpy as np

from rpmnet_jax import data
from rpmnet_jax.data import loader, synthetic
from rpmnet_jax import metrics
from rpmnet_jax.train import config as train_config
from rpmnet_jax.train.checkpoints import Checkpoints
from rpmnet_jax.train.config import TrainConfig
from rpmnet_jax.train.parallel import Parallel, to_host
from rpmnet_jax.train.step import create_train_state, make_eval_fn, make_train_step

log = logging.getLogger("rpmnet_jax.train")


def _datasets(cfg: TrainConfig):
    """Train/val sets: the synthetic set and/or every folder of ``cfg.data_root`` (comma-separated)."""
    roots = [r for r in (cfg.data_root or "").split(",") if r]
    if cfg.synthetic:
        root = os.path.join(cfg.workdir, "synthetic")
        if jax.process_index() == 0:  # one writer; the others wait for it
            synthetic.ensure_dataset(root, cfg.synthetic_train, cfg.synthetic_test, cfg.seed)
        if jax.process_count() > 1:
            from jax.experimental import multihost_utils
            multihost_utils.sync_global_devices("rpmnet_jax: synthetic set written")
        roots.insert(0, root)
    if not roots:
        raise FileNotFoundError("no training data: the config names no data root and no synthetic set")
    kw = dict(protocol=cfg.dataset, num_points=cfg.num_points, seed=cfg.seed)
    sets = [(data.ModelNet40(r, "train", **kw), data.ModelNet40(r, "val", **kw)) for r in roots]
    if len(sets) == 1:
        return sets[0]
    return data.Concat(s[0] for s in sets), data.Concat(s[1] for s in sets if len(s[1]))


def validate(params, val_set, cfg: TrainConfig, eval_fn=None, progress: bool = True) -> dict:
    """Mean official metrics of ``cfg.model.num_reg_iters``-iteration registration on ``val_set``."""
    eval_fn = eval_fn or make_eval_fn(cfg)
    n = len(val_set) if cfg.val_limit is None else min(cfg.val_limit, len(val_set))
    subset = data.Spread(val_set, n)
    per_pair: dict = {}
    from tqdm.auto import tqdm
    for batch in tqdm(loader.batches(subset, cfg.resolved_batch_size), desc="validate", leave=False,
                      disable=not progress, total=math.ceil(n / cfg.resolved_batch_size)):
        transforms = np.asarray(eval_fn(params, batch["points_src"], batch["points_ref"]))
        m = metrics.registration_metrics(transforms[-1], batch["transform_gt"], batch["points_src"],
                                         batch["points_ref"], batch["points_raw"])
        for k, v in m.items():
            per_pair.setdefault(k, []).append(v)
    return metrics.summarize_metrics({k: np.concatenate(v) for k, v in per_pair.items()})


class _Run:
    """What one call of :func:`train_and_evaluate` holds: data, devices, state, step functions, outputs."""

    def __init__(self, cfg: TrainConfig):
        self.cfg = cfg
        self.train_set, self.val_set = _datasets(cfg)
        self.par = Parallel()
        self.bs = cfg.resolved_batch_size
        if self.bs % self.par.size:
            raise ValueError(f"batch size {self.bs} is not divisible by the {self.par.size} devices")
        self.steps_per_epoch = len(self.train_set) // self.bs
        if self.steps_per_epoch == 0:
            raise ValueError(f"the training set has {len(self.train_set)} pairs, fewer than one batch of {self.bs}")
        self.total_steps = cfg.epochs * self.steps_per_epoch
        if cfg.max_steps is not None:
            self.total_steps = min(self.total_steps, cfg.max_steps)
        self.ckpt = Checkpoints(cfg.workdir, cfg.keep)
        self.state = self.par.put_state(self._initial_state())
        self.train_step = make_train_step(cfg, self.total_steps)
        self.eval_fn = make_eval_fn(cfg)
        self.writer = _summary_writer(cfg.workdir) if jax.process_index() == 0 else None
        self.losses: list[float] = []
        self.val_summary = None

    def _initial_state(self):
        cfg = self.cfg
        init = None
        if cfg.init_from:
            from rpmnet_jax.weights import loading
            init = jax.tree.map(jnp.asarray, loading.load_params(cfg.init_from))
        state = create_train_state(jax.random.PRNGKey(cfg.seed), cfg, self.total_steps, init)
        restored = self.ckpt.restore_latest(state)
        if restored is not None:
            log.info("resumed from step %d", int(restored.step))
            return restored
        if cfg.init_from:
            log.info("initialised from %s", cfg.init_from)
        return state

    def step(self, batch) -> None:
        self.state, scalars = self.train_step(self.state, self.par.put_batch(batch))
        scalars = to_host(scalars)
        self.losses.append(float(scalars["loss"]))
        nonfinite, step = int(to_host(self.state.nonfinite)), int(to_host(self.state.step))
        if nonfinite > self.cfg.max_nonfinite:
            raise FloatingPointError(f"{nonfinite} consecutive non-finite losses/gradients at step {step}; "
                                     "stopping (last checkpoint is intact)")
        _log_scalars(self.writer, step, scalars)

    def validate_and_save(self, progress: bool) -> None:
        """Validates the EMA params (the params without EMA), logs, and checkpoints with the metric."""
        step = int(to_host(self.state.step))
        self.val_summary = validate(to_host(self.state.ema), self.val_set, self.cfg, self.eval_fn, progress)
        _log_scalars(self.writer, step, {f"val/{k}": v for k, v in self.val_summary.items()})
        log.info("step %d validation %s", step, json.dumps(self.val_summary))
        self.ckpt.save(self.state, best_metric=self.val_summary["chamfer_dist"])

    def close(self) -> None:
        self.ckpt.close()
        if self.writer is not None:
            self.writer.close()


def _run_epoch(run: _Run, step: int, stop: dict, progress: bool) -> int:
    """Trains from ``step`` to the end of its epoch (or the run, or a SIGTERM); returns the new step."""
    from tqdm.auto import tqdm

    cfg = run.cfg
    epoch, start_batch = divmod(step, run.steps_per_epoch)
    n_this = min(run.steps_per_epoch - start_batch, run.total_steps - step)
    bar = tqdm(total=n_this, desc=f"epoch {epoch}", disable=not progress, leave=False)
    t_epoch = time.time()
    for batch in loader.batches(run.train_set, run.bs, shuffle=True, drop_remainder=True, seed=cfg.seed,
                                epoch=epoch, start_batch=start_batch):
        run.step(batch)
        step += 1
        bar.update(1)
        bar.set_postfix(loss=f"{run.losses[-1]:.4f}", pairs_s=f"{bar.n * run.bs / (time.time() - t_epoch):.1f}")
        if cfg.val_every_steps and step % cfg.val_every_steps == 0 and step < run.total_steps:
            run.validate_and_save(progress)
        elif step % cfg.save_every == 0:
            run.ckpt.save(run.state)
        if stop["flag"] or step >= run.total_steps or bar.n >= n_this:
            break
    bar.close()
    return step


def train_and_evaluate(cfg: TrainConfig, progress: bool = True) -> dict:
    """Trains (resuming from ``cfg.workdir`` if it holds checkpoints); returns a summary dict."""
    train_config.check_and_save(cfg)
    run = _Run(cfg)
    stop = {"flag": False}
    previous = signal.signal(signal.SIGTERM, lambda *_: stop.__setitem__("flag", True))
    step, t_start = int(to_host(run.state.step)), time.time()
    try:
        while step < run.total_steps and not stop["flag"]:
            step = _run_epoch(run, step, stop, progress)
            epoch_done = step % run.steps_per_epoch == 0
            due = epoch_done and (step // run.steps_per_epoch) % cfg.val_every == 0
            if not stop["flag"] and (due or step >= run.total_steps):
                run.validate_and_save(progress)
            elif epoch_done or stop["flag"]:
                run.ckpt.save(run.state)
        run.ckpt.save(run.state)
    finally:
        signal.signal(signal.SIGTERM, previous)
        run.close()
    return {"step": step, "interrupted": stop["flag"], "skipped_updates": int(to_host(run.state.skipped)),
            "seconds": round(time.time() - t_start, 1), "last_loss": run.losses[-1] if run.losses else None,
            "losses": run.losses, "validation": run.val_summary, "devices": run.par.size}


def _summary_writer(workdir: str):
    try:
        from tensorboardX import SummaryWriter
    except ImportError:
        log.warning("tensorboardX is not installed; no TensorBoard logs (pip install tensorboardX)")
        return None
    return SummaryWriter(os.path.join(workdir, "tb"))


def _log_scalars(writer, step: int, scalars: dict) -> None:
    if writer is None:
        return
    for key, value in scalars.items():
        value = np.asarray(value)
        if value.ndim == 0:
            writer.add_scalar(key, float(value), step)
        else:
            for i, v in enumerate(value.reshape(-1)):
                writer.add_scalar(f"{key}_{i}", float(v), step)
