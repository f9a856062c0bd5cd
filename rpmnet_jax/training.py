"""Training: one jitted, donated train step; data-parallel over local devices; orbax checkpoints with
exact resume; validation with the paper's metrics."""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import os
import signal
import time
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax
import orbax.checkpoint as ocp
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from rpmnet_jax import config as config_lib
from rpmnet_jax import data, loader, losses, metrics, model, registration, synthetic

log = logging.getLogger("rpmnet_jax.training")
DEVICE_KEYS = ("points_src", "points_ref", "transform_gt")


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """Everything a training run depends on (saved as ``config.json`` beside the checkpoints)."""

    dataset: str = "noisy"  # clean | noisy | partial
    data_root: str | None = None
    synthetic: bool = False
    synthetic_train: int = 400
    synthetic_test: int = 100
    workdir: str = "runs/rpmnet"
    epochs: int = 100
    max_steps: int | None = None
    batch_size: int | None = None  # None: 8 for partial, 4 for clean/noisy (official README)
    num_points: int = 1024
    lr: float = 1e-4
    val_every: int = 1  # epochs
    val_limit: int | None = None  # pairs per validation (None: all)
    save_every: int = 100  # steps
    keep: int = 3
    seed: int = 0
    max_nonfinite: int = 20  # consecutive skipped updates before giving up
    init_from: str | None = None  # params to start from (.npz, .pth or orbax); fresh optimizer state
    lr_schedule: str = "constant"  # constant | cosine (linear warmup, cosine decay to lr_final over the run)
    warmup_steps: int = 0
    lr_final: float = 0.0
    clip_norm: float | None = None  # global gradient-norm clipping
    ema_decay: float | None = None  # exponential moving average of the params (validated and saved as best)
    val_every_steps: int | None = None  # also validate every N steps
    model: config_lib.RPMNetConfig = config_lib.RPMNetConfig()

    @property
    def resolved_batch_size(self) -> int:
        if self.batch_size is not None:
            return self.batch_size
        return 8 if self.dataset == "partial" else 4

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["model"] = self.model.to_dict()
        return d


class TrainState(NamedTuple):
    step: jax.Array
    params: dict
    opt_state: optax.OptState
    nonfinite: jax.Array  # consecutive skipped updates
    skipped: jax.Array  # total skipped updates
    ema: dict  # moving average of params (equal to params when cfg.ema_decay is None)


def learning_rate(cfg: TrainConfig, total_steps: int):
    """The learning rate: a float, or an optax schedule of the step."""
    if cfg.lr_schedule == "constant":
        if not cfg.warmup_steps:
            return cfg.lr
        return optax.linear_schedule(0.0, cfg.lr, cfg.warmup_steps)
    if cfg.lr_schedule == "cosine":
        return optax.warmup_cosine_decay_schedule(0.0, cfg.lr, max(cfg.warmup_steps, 1), max(total_steps, 2),
                                                  end_value=cfg.lr_final)
    raise ValueError(f"lr_schedule must be 'constant' or 'cosine', got {cfg.lr_schedule!r}")


def make_optimizer(cfg: TrainConfig, total_steps: int = 0) -> optax.GradientTransformation:
    adam = optax.adam(learning_rate(cfg, total_steps))
    return adam if cfg.clip_norm is None else optax.chain(optax.clip_by_global_norm(cfg.clip_norm), adam)


def create_train_state(key, cfg: TrainConfig, total_steps: int = 0, params=None) -> TrainState:
    params = model.init_params(key, cfg.model) if params is None else params
    zero = lambda: jnp.zeros((), jnp.int32)  # distinct buffers: the state is donated
    ema = jax.tree.map(jnp.array, params)
    return TrainState(zero(), params, make_optimizer(cfg, total_steps).init(params), zero(), zero(), ema)


def make_train_step(cfg: TrainConfig, total_steps: int = 0):
    """``train_step(state, batch) -> (state, scalars)``; skips (and counts) non-finite updates."""
    optimizer = make_optimizer(cfg, total_steps)
    decay = cfg.ema_decay
    mcfg = cfg.model

    def loss_fn(params, batch):
        reg = registration.register(params, batch["points_src"], batch["points_ref"], mcfg,
                                    num_iters=mcfg.num_train_reg_iters)
        terms = losses.loss_terms(reg, batch, mcfg)
        return terms["total"], (terms, jnp.mean(reg.alpha, -1), jnp.mean(reg.beta, -1))

    def train_step(state: TrainState, batch):
        (loss, (terms, alpha, beta)), grads = jax.value_and_grad(loss_fn, has_aux=True)(state.params, batch)
        finite = jnp.isfinite(loss) & jnp.all(jnp.stack([jnp.all(jnp.isfinite(g)) for g in jax.tree.leaves(grads)]))
        updates, opt_state = optimizer.update(grads, state.opt_state, state.params)
        params = optax.apply_updates(state.params, updates)
        keep = lambda new, old: jax.tree.map(lambda a, b: jnp.where(finite, a, b), new, old)
        params = keep(params, state.params)
        ema = params if decay is None else jax.tree.map(lambda e, p: decay * e + (1.0 - decay) * p, state.ema, params)
        new_state = TrainState(state.step + 1, params, keep(opt_state, state.opt_state),
                               jnp.where(finite, 0, state.nonfinite + 1), state.skipped + (~finite).astype(jnp.int32),
                               ema)
        scalars = {"loss": loss, "mae": terms["mae"], "inlier": terms["inlier"], "alpha": alpha, "beta": beta,
                   "finite": finite}
        return new_state, scalars

    return jax.jit(train_step, donate_argnums=0)


def make_eval_fn(cfg: TrainConfig):
    mcfg = cfg.model
    return jax.jit(lambda params, src, ref: registration.register(params, src, ref, mcfg).transforms)


class Parallel:
    """1-D data-parallel mesh over all devices: batches sharded on axis 0, state replicated."""

    def __init__(self):
        self.mesh = Mesh(np.array(jax.devices()), ("data",))
        self.batch = NamedSharding(self.mesh, PartitionSpec("data"))
        self.replicated = NamedSharding(self.mesh, PartitionSpec())
        self.size = len(jax.devices())

    def put_batch(self, batch: dict) -> dict:
        return {k: jax.device_put(np.asarray(batch[k]), self.batch) for k in DEVICE_KEYS}

    def put_state(self, state):
        return jax.device_put(state, self.replicated)


def maybe_initialize_distributed() -> None:
    """Multi-host set-up when the usual coordinator environment is present."""
    if os.environ.get("JAX_COORDINATOR_ADDRESS") or os.environ.get("COORDINATOR_ADDRESS"):
        jax.distributed.initialize()


# --- checkpoints ------------------------------------------------------------------------------------

class Checkpoints:
    """Latest ``keep`` checkpoints plus the best by validation Chamfer distance (orbax; atomic writes)."""

    def __init__(self, workdir: str, keep: int):
        root = os.path.abspath(os.path.join(workdir, "checkpoints"))
        self.latest = ocp.CheckpointManager(os.path.join(root, "latest"), options=ocp.CheckpointManagerOptions(
            max_to_keep=keep, create=True, enable_async_checkpointing=False))
        self.best = ocp.CheckpointManager(os.path.join(root, "best"), options=ocp.CheckpointManagerOptions(
            max_to_keep=1, create=True, best_fn=lambda m: m["chamfer_dist"], best_mode="min",
            keep_checkpoints_without_metrics=False, enable_async_checkpointing=False))

    @staticmethod
    def _host_state(state: TrainState) -> dict:
        return jax.device_get(state._asdict())

    def save(self, state: TrainState, best_metric: float | None = None) -> None:
        host = self._host_state(state)
        if not all(np.all(np.isfinite(x)) for x in jax.tree.leaves(host["params"])):
            raise FloatingPointError("refusing to checkpoint non-finite parameters")
        step = int(host["step"])
        if step not in self.latest.all_steps():
            self.latest.save(step, args=ocp.args.StandardSave(host))
        if best_metric is not None and np.isfinite(best_metric):
            self.best.save(step, args=ocp.args.StandardSave(host), metrics={"chamfer_dist": float(best_metric)})

    def restore_latest(self, template: TrainState) -> TrainState | None:
        """Newest restorable checkpoint; a damaged one is reported and skipped for the one before it."""
        abstract = jax.tree.map(ocp.utils.to_shape_dtype_struct, self._host_state(template))
        steps = sorted(self.latest.all_steps(), reverse=True)
        for step in steps:
            try:
                host = self.latest.restore(step, args=ocp.args.StandardRestore(abstract))
                return TrainState(**host)
            except Exception as e:  # noqa: BLE001 - any failure means this checkpoint is unusable
                log.warning("checkpoint at step %d is unreadable (%s: %s); trying an older one", step,
                            type(e).__name__, e)
        if steps:
            raise RuntimeError(f"no readable checkpoint in {self.latest.directory} (tried steps {steps}); "
                               "delete the folder to start afresh")
        return None

    def close(self) -> None:
        self.latest.close()
        self.best.close()


def restore_params(path: str) -> dict:
    """Parameters from a training workdir, its ``checkpoints/{best,latest}`` folder, or a step folder."""
    path = os.path.abspath(path)
    candidates = [os.path.join(path, "checkpoints", "best"), os.path.join(path, "checkpoints", "latest"),
                  os.path.join(path, "best"), os.path.join(path, "latest"), path]
    for folder in candidates:
        if not os.path.isdir(folder):
            continue
        mngr = ocp.CheckpointManager(folder)
        try:
            step = mngr.best_step() if folder.endswith("best") else mngr.latest_step()
            step = step if step is not None else mngr.latest_step()
            if step is not None:
                restored = mngr.restore(step, args=ocp.args.StandardRestore())
                return restored.get("ema", restored["params"])  # the EMA is what validation chose
        finally:
            mngr.close()
    raise FileNotFoundError(f"no orbax checkpoint found under {path}")


# --- the loop ---------------------------------------------------------------------------------------

def _datasets(cfg: TrainConfig):
    """Train/val sets: the synthetic set and/or every folder of ``cfg.data_root`` (comma-separated)."""
    roots = [r for r in (cfg.data_root or "").split(",") if r]
    if cfg.synthetic:
        root = os.path.join(cfg.workdir, "synthetic")
        if not os.path.isfile(os.path.join(root, data.FOLDER, "shape_names.txt")):
            synthetic.write_dataset(root, cfg.synthetic_train, cfg.synthetic_test, seed=cfg.seed)
        roots.insert(0, root)
    if not roots:
        raise FileNotFoundError("no --data-root given; pass the ModelNet40 folder or use --synthetic")
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


def _check_resume_config(cfg: TrainConfig) -> None:
    path = os.path.join(cfg.workdir, "config.json")
    current = cfg.to_dict()
    if os.path.isfile(path):
        with open(path) as f:
            saved = json.load(f)
        keys = ("dataset", "num_points", "lr", "seed", "model", "synthetic", "data_root", "lr_schedule",
                "warmup_steps", "lr_final", "clip_norm", "ema_decay")
        speed_only = lambda m: {k: v for k, v in (m or {}).items() if k != "fused_prepool"}
        diff = {k: (saved.get(k), current.get(k)) for k in keys
                if (speed_only(saved.get(k)) if k == "model" else saved.get(k))
                != (speed_only(current.get(k)) if k == "model" else current.get(k))}
        if diff:
            raise ValueError(f"{cfg.workdir} holds a run with a different configuration {diff}; "
                             "use another --workdir to start a new run")
    os.makedirs(cfg.workdir, exist_ok=True)
    tmp = path + ".tmp"
    with open(tmp, "w") as f:
        json.dump(current, f, indent=2)
    os.replace(tmp, path)


def train_and_evaluate(cfg: TrainConfig, progress: bool = True) -> dict:
    """Trains (resuming from ``cfg.workdir`` if it holds checkpoints); returns a summary dict."""
    from tqdm.auto import tqdm

    _check_resume_config(cfg)
    train_set, val_set = _datasets(cfg)
    par = Parallel()
    bs = cfg.resolved_batch_size
    if bs % par.size:
        raise ValueError(f"batch size {bs} is not divisible by the {par.size} devices")
    steps_per_epoch = len(train_set) // bs
    if steps_per_epoch == 0:
        raise ValueError(f"the training set has {len(train_set)} pairs, fewer than one batch of {bs}")
    total_steps = cfg.epochs * steps_per_epoch
    if cfg.max_steps is not None:
        total_steps = min(total_steps, cfg.max_steps)

    ckpt = Checkpoints(cfg.workdir, cfg.keep)
    init_params = None
    if cfg.init_from:
        from rpmnet_jax import pretrained
        init_params = jax.tree.map(jnp.asarray, pretrained.load_params(cfg.init_from))
    state = create_train_state(jax.random.PRNGKey(cfg.seed), cfg, total_steps, init_params)
    restored = ckpt.restore_latest(state)
    if restored is not None:
        state = restored
        log.info("resumed from step %d", int(state.step))
    elif cfg.init_from:
        log.info("initialised from %s", cfg.init_from)
    state = par.put_state(state)
    train_step, eval_fn = make_train_step(cfg, total_steps), make_eval_fn(cfg)
    writer = _summary_writer(cfg.workdir)

    stop = {"flag": False}
    previous = signal.signal(signal.SIGTERM, lambda *_: stop.__setitem__("flag", True))
    step = int(state.step)
    history, val_summary, t_start = [], None, time.time()
    try:
        while step < total_steps and not stop["flag"]:
            epoch, start_batch = divmod(step, steps_per_epoch)
            n_this = min(steps_per_epoch - start_batch, total_steps - step)
            bar = tqdm(total=n_this, desc=f"epoch {epoch}", disable=not progress, leave=False)
            t_epoch = time.time()
            for batch in loader.batches(train_set, bs, shuffle=True, drop_remainder=True, seed=cfg.seed,
                                        epoch=epoch, start_batch=start_batch):
                state, scalars = train_step(state, par.put_batch(batch))
                scalars = jax.device_get(scalars)
                step += 1
                history.append(float(scalars["loss"]))
                if int(state.nonfinite) > cfg.max_nonfinite:
                    raise FloatingPointError(f"{int(state.nonfinite)} consecutive non-finite losses/gradients "
                                             f"at step {step}; stopping (last checkpoint is intact)")
                _log_scalars(writer, step, scalars)
                bar.update(1)
                bar.set_postfix(loss=f"{scalars['loss']:.4f}", pairs_s=f"{bar.n * bs / (time.time() - t_epoch):.1f}")
                if cfg.val_every_steps and step % cfg.val_every_steps == 0 and step < total_steps:
                    val_summary = validate(state.ema, val_set, cfg, eval_fn, progress)
                    _log_scalars(writer, step, {f"val/{k}": v for k, v in val_summary.items()})
                    log.info("step %d validation %s", step, json.dumps(val_summary))
                    ckpt.save(state, best_metric=val_summary["chamfer_dist"])
                elif step % cfg.save_every == 0:
                    ckpt.save(state)
                if stop["flag"] or step >= total_steps or bar.n >= n_this:
                    break
            bar.close()
            epoch_done = step % steps_per_epoch == 0
            finished = step >= total_steps
            if not stop["flag"] and ((epoch_done and (step // steps_per_epoch) % cfg.val_every == 0) or finished):
                val_summary = validate(state.ema, val_set, cfg, eval_fn, progress)
                _log_scalars(writer, step, {f"val/{k}": v for k, v in val_summary.items()})
                log.info("step %d validation %s", step, json.dumps(val_summary))
                ckpt.save(state, best_metric=val_summary["chamfer_dist"])
            elif epoch_done or stop["flag"]:
                ckpt.save(state)
        ckpt.save(state)
    finally:
        signal.signal(signal.SIGTERM, previous)
        ckpt.close()
        if writer is not None:
            writer.close()
    summary = {"step": step, "interrupted": stop["flag"], "skipped_updates": int(state.skipped),
               "seconds": round(time.time() - t_start, 1), "last_loss": history[-1] if history else None,
               "losses": history, "validation": val_summary, "devices": par.size}
    return summary


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
