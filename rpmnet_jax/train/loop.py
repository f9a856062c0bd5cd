"""The training loop: data, resume, steps, periodic validation and checkpoints, stopping on SIGINT/SIGTERM."""

from __future__ import annotations

import contextlib
import itertools
import json
import logging
import math
import os
import signal
import threading
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


def datasets(cfg: TrainConfig):
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
    sets = [(data.ModelNet40(r, "train", rot_mag=cfg.rot_mag, views_share=cfg.views_share, **kw),
             data.ModelNet40(r, "val", **kw)) for r in roots]
    if len(sets) == 1:
        return sets[0]
    return data.Concat(s[0] for s in sets), data.Concat(s[1] for s in sets if len(s[1]))


def validate(params, val_set, cfg: TrainConfig, eval_fn=None, progress: bool = True, stop=None) -> dict | None:
    """Mean official metrics of ``cfg.model.num_reg_iters``-iteration registration on ``val_set``; ``None`` when
    ``stop()`` (checked before each batch) turns true."""
    eval_fn = eval_fn or make_eval_fn(cfg)
    n = len(val_set) if cfg.val_limit is None else min(cfg.val_limit, len(val_set))
    subset = data.Spread(val_set, n)
    per_pair: dict = {}
    from tqdm.auto import tqdm
    for batch in tqdm(loader.batches(subset, cfg.resolved_batch_size), desc="validate", leave=False,
                      disable=not progress, total=math.ceil(n / cfg.resolved_batch_size)):
        if stop is not None and stop():
            return None
        transforms = np.asarray(eval_fn(params, batch["points_src"], batch["points_ref"]))
        m = metrics.registration_metrics(transforms[-1], batch["transform_gt"], batch["points_src"],
                                         batch["points_ref"], batch["points_raw"])
        for k, v in m.items():
            per_pair.setdefault(k, []).append(v)
    return metrics.summarize_metrics({k: np.concatenate(v) for k, v in per_pair.items()})


def due(step: int, steps_per_epoch: int, total_steps: int, cfg: TrainConfig) -> tuple[bool, bool]:
    """``(validate, save)`` after ``step`` steps: the one place that decides. Validation (which saves, with its
    metric) every ``val_every_steps`` steps, at every ``val_every``-th epoch end and at the last step; a plain
    save every ``save_every`` steps and at every epoch end."""
    epoch_end = step % steps_per_epoch == 0
    validate = (step >= total_steps or bool(cfg.val_every_steps and step % cfg.val_every_steps == 0)
                or (epoch_end and (step // steps_per_epoch) % cfg.val_every == 0))
    return validate, validate or epoch_end or step % cfg.save_every == 0


class _Stop:
    """SIGINT and SIGTERM ask the run to stop: it saves at the next step boundary (or validation batch) and
    returns. A second SIGINT aborts at once. ``requested()`` is agreed by every process of a multi-process run."""

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self, par: Parallel):
        self.par, self.received, self.previous = par, None, {}

    def _handle(self, signum, frame):
        if self.received is not None and signum == signal.SIGINT:
            raise KeyboardInterrupt
        self.received = signal.Signals(signum).name
        log.warning("%s received: saving a checkpoint at the next step boundary, then stopping", self.received)

    def __enter__(self):
        if threading.current_thread() is threading.main_thread():  # handlers can only be set there
            self.previous = {s: signal.signal(s, self._handle) for s in self.SIGNALS}
        return self

    def __exit__(self, *exc):
        for s, handler in self.previous.items():
            signal.signal(s, handler)

    def requested(self) -> bool:
        return self.par.any(self.received is not None)


class _Run:
    """What one call of :func:`train_and_evaluate` holds: data, devices, state, step functions, outputs."""

    def __init__(self, cfg: TrainConfig):
        self.cfg = cfg
        init = self._init_params()  # first: a bad --init-from fails before anything is written
        self.train_set, self.val_set = datasets(cfg)
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
        self.state = self.par.put_state(self._initial_state(init))
        self.train_step = make_train_step(cfg, self.total_steps)
        self.eval_fn = make_eval_fn(cfg)
        self.writer = _summary_writer(cfg.workdir) if jax.process_index() == 0 else None
        self.losses: list[float] = []
        self.val_summary = None

    def _init_params(self):
        if not self.cfg.init_from:
            return None
        from rpmnet_jax.weights import loading
        return jax.tree.map(jnp.asarray, loading.load_params(self.cfg.init_from))

    def _initial_state(self, init):
        cfg = self.cfg
        state = create_train_state(jax.random.PRNGKey(cfg.seed), cfg, self.total_steps, init)
        restored = self.ckpt.restore_latest(state)
        if self.par.processes > 1:  # every process must resume from the same step
            from jax.experimental import multihost_utils
            steps = multihost_utils.process_allgather(np.int64(-1 if restored is None else int(restored.step)))
            if len(set(np.asarray(steps).tolist())) > 1:
                raise RuntimeError(f"the processes found different checkpoints to resume from: steps {steps}")
        if restored is not None:
            log.info("resumed from step %d", int(restored.step))
            return restored
        if cfg.init_from:
            log.info("initialised from %s", cfg.init_from)
        return state

    def step(self, batch) -> int:
        """One train step; returns the new step count."""
        self.state, scalars = self.train_step(self.state, self.par.put_batch(batch))
        scalars = to_host(scalars)
        self.losses.append(float(scalars["loss"]))
        nonfinite, step = int(to_host(self.state.nonfinite)), int(to_host(self.state.step))
        if nonfinite > self.cfg.max_nonfinite:
            raise FloatingPointError(f"{nonfinite} consecutive non-finite losses/gradients at step {step}; "
                                     "stopping (last checkpoint is intact)")
        _log_scalars(self.writer, step, scalars)
        return step

    def validate(self, step: int, progress: bool, stop) -> dict | None:
        """Validates the EMA params (the params without EMA) and logs; ``None`` when stopped midway."""
        summary = validate(to_host(self.state.ema), self.val_set, self.cfg, self.eval_fn, progress, stop)
        if summary is None:
            log.info("step %d validation interrupted", step)
            return None
        self.val_summary = summary
        _log_scalars(self.writer, step, {f"val/{k}": v for k, v in summary.items()})
        log.info("step %d validation %s", step, json.dumps(summary))
        return summary

    def close(self) -> None:
        self.ckpt.close()
        if self.writer is not None:
            self.writer.close()


def _train(run: _Run, step: int, stop: _Stop, progress: bool) -> tuple[int, bool]:
    """Trains from ``step`` to the end of the run or to an agreed stop; returns ``(step, stopped)``."""
    from tqdm.auto import tqdm

    cfg = run.cfg
    while step < run.total_steps:
        epoch, start_batch = divmod(step, run.steps_per_epoch)
        n_this = min(run.steps_per_epoch - start_batch, run.total_steps - step)
        bar = tqdm(total=n_this, desc=f"epoch {epoch}", disable=not progress, leave=False)
        t_epoch = time.time()
        batches = loader.batches(run.train_set, run.bs, shuffle=True, drop_remainder=True, seed=cfg.seed,
                                 epoch=epoch, start_batch=start_batch)
        with contextlib.closing(batches), bar:
            for batch in itertools.islice(batches, n_this):
                step = run.step(batch)
                bar.update(1)
                bar.set_postfix(loss=f"{run.losses[-1]:.4f}",
                                pairs_s=f"{bar.n * run.bs / (time.time() - t_epoch):.1f}")
                stopped = stop.requested()
                validate, save = (False, True) if stopped else due(step, run.steps_per_epoch, run.total_steps, cfg)
                summary = run.validate(step, progress, stop.requested) if validate else None
                stopped = stopped or (validate and summary is None)
                if save:
                    run.ckpt.save(run.state, best_metric=None if summary is None else summary["chamfer_dist"])
                if stopped:
                    log.info("stopped by %s at step %d with a checkpoint; the same command resumes",
                             stop.received or "another process", step)
                    return step, True
    return step, False


def train_and_evaluate(cfg: TrainConfig, progress: bool = True) -> dict:
    """Trains (resuming from ``cfg.workdir`` if it holds checkpoints); returns a summary dict. SIGINT/SIGTERM
    stop it at the next step boundary with a checkpoint (``interrupted`` in the summary)."""
    train_config.check_and_save(cfg)
    run = _Run(cfg)
    step, t_start = int(to_host(run.state.step)), time.time()
    try:
        with _Stop(run.par) as stop:
            step, interrupted = _train(run, step, stop, progress)
    finally:
        run.close()
    return {"step": step, "interrupted": interrupted, "skipped_updates": int(to_host(run.state.skipped)),
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
