"""The train state, the optimizer (schedule, clipping) and the jitted, donated train step."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import optax

from rpmnet_jax import losses, registration
from rpmnet_jax.nn import pointnets
from rpmnet_jax.train.config import TrainConfig


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
    params = pointnets.init_params(key, cfg.model) if params is None else params
    zero = lambda: jnp.zeros((), jnp.int32)  # distinct buffers: the state is donated
    ema = jax.tree.map(jnp.array, params)
    return TrainState(zero(), params, make_optimizer(cfg, total_steps).init(params), zero(), zero(), ema)


def _is_schedule(x) -> bool:
    return isinstance(x, optax.ScaleByScheduleState)


def _advance_schedule(kept, updated):
    """``kept`` (the optimizer state of a skipped update) with the schedule's count of ``updated``: the learning
    rate follows ``state.step`` whether or not an update was applied."""
    return jax.tree.map(lambda k, u: u if _is_schedule(u) else k, kept, updated, is_leaf=_is_schedule)


def make_train_step(cfg: TrainConfig, total_steps: int = 0):
    """``train_step(state, batch) -> (state, scalars)``; skips (and counts) non-finite updates."""
    optimizer = make_optimizer(cfg, total_steps)
    decay = cfg.ema_decay
    mcfg = cfg.model

    def loss_fn(params, batch):
        reg = registration.register(params, batch["points_src"], batch["points_ref"], mcfg,
                                    num_iters=mcfg.num_train_reg_iters, unroll=True)
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
        new_state = TrainState(state.step + 1, params, _advance_schedule(keep(opt_state, state.opt_state), opt_state),
                               jnp.where(finite, 0, state.nonfinite + 1), state.skipped + (~finite).astype(jnp.int32),
                               ema)
        scalars = {"loss": loss, "mae": terms["mae"], "inlier": terms["inlier"], "alpha": alpha, "beta": beta,
                   "finite": finite}
        return new_state, scalars

    return jax.jit(train_step, donate_argnums=0)


def make_eval_fn(cfg: TrainConfig):
    """``eval_fn(params, src, ref) -> transforms (I, B, 3, 4)`` with ``cfg.model.num_reg_iters`` iterations
    (jitted)."""
    return registration.jitted(cfg.model, None, "transforms")
