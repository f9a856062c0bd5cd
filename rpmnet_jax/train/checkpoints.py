"""Orbax checkpoints of the train state: the latest few and the best by validation, atomic writes."""

from __future__ import annotations

import logging
import os
import shutil

import jax
import numpy as np
import orbax.checkpoint as ocp

from rpmnet_jax.train.parallel import to_host
from rpmnet_jax.train.step import TrainState

log = logging.getLogger("rpmnet_jax.train")


class CheckpointError(RuntimeError):
    """A checkpoint exists but cannot be resumed from; the message says which one and why."""


def _path_str(path) -> str:
    return "/".join(str(getattr(k, "key", getattr(k, "idx", getattr(k, "name", k)))) for k in path)


def structure_mismatch(saved, expected) -> str | None:
    """The first difference between a checkpoint's tree metadata and the expected host tree (names, shapes,
    dtypes), or ``None`` when they fit."""
    shape = lambda x: (tuple(np.shape(x) if not hasattr(x, "shape") else x.shape), np.dtype(x.dtype).name)
    have = {_path_str(p): shape(x) for p, x in jax.tree_util.tree_leaves_with_path(saved)}
    want = {_path_str(p): shape(x) for p, x in jax.tree_util.tree_leaves_with_path(expected)}
    for name in sorted(set(have) | set(want)):
        if name not in have:
            return f"it has no {name}"
        if name not in want:
            return f"it has {name}, which this run does not"
        if have[name] != want[name]:
            return f"{name} is {have[name][1]}{list(have[name][0])} there, {want[name][1]}{list(want[name][0])} here"
    return None


class Checkpoints:
    """Latest ``keep`` checkpoints plus the best by validation Chamfer distance (orbax; atomic writes)."""

    def __init__(self, workdir: str, keep: int):
        self.root = os.path.abspath(os.path.join(workdir, "checkpoints"))
        handler = ocp.StandardCheckpointHandler
        self.latest = ocp.CheckpointManager(os.path.join(self.root, "latest"), item_handlers=handler(),
                                            options=ocp.CheckpointManagerOptions(
                                                max_to_keep=keep, create=True, enable_async_checkpointing=False))
        self.best = ocp.CheckpointManager(os.path.join(self.root, "best"), item_handlers=handler(),
                                          options=ocp.CheckpointManagerOptions(
                                              max_to_keep=1, create=True, best_fn=lambda m: m["chamfer_dist"],
                                              best_mode="min", keep_checkpoints_without_metrics=False,
                                              enable_async_checkpointing=False))

    @staticmethod
    def _host_state(state: TrainState) -> dict:
        return to_host(state._asdict())

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
        """The newest checkpoint (``None`` when there is none).

        A damaged one (files missing or unreadable) is reported, moved to ``checkpoints/damaged/`` so that it
        is never tried again, and the one before it is used. A checkpoint of another structure (a different
        network or optimizer) raises :class:`CheckpointError`: older ones of the same run would not fit either.
        """
        expected = self._host_state(template)
        abstract = jax.tree.map(ocp.utils.to_shape_dtype_struct, expected)
        steps = sorted(self.latest.all_steps(), reverse=True)
        damaged = []
        for step in steps:
            try:
                saved = self.latest.item_metadata(step)
                mismatch = None if saved is None else structure_mismatch(saved, expected)
            except Exception:  # noqa: BLE001 - unreadable metadata: the restore below says what is wrong
                mismatch = None
            if mismatch:
                raise CheckpointError(f"checkpoint at step {step} in {self.latest.directory} does not fit this "
                                      f"run: {mismatch}")
            try:
                host = self.latest.restore(step, args=ocp.args.StandardRestore(abstract))
            except PermissionError:
                raise
            except Exception as e:  # noqa: BLE001 - any other failure means the files are damaged
                what = "has files missing" if isinstance(e, FileNotFoundError) else "is damaged"
                reason = str(e).splitlines()[0][:300] if str(e) else ""
                log.warning("checkpoint at step %d %s (%s: %s); moved aside, trying an older one", step, what,
                            type(e).__name__, reason)
                damaged.append(f"step {step} {what} ({type(e).__name__})")
                self._move_aside(step)
                continue
            return TrainState(**host)
        if damaged:
            raise CheckpointError(f"no usable checkpoint in {self.latest.directory}: {'; '.join(damaged)}; "
                                  f"moved to {os.path.join(self.root, 'damaged')}")
        return None

    def _move_aside(self, step: int) -> None:
        """Moves a damaged step out of ``latest`` (one writer in a multi-process run)."""
        if jax.process_index() == 0:
            target = os.path.join(self.root, "damaged", str(step))
            while os.path.exists(target):
                target += "_"
            os.makedirs(os.path.dirname(target), exist_ok=True)
            shutil.move(os.path.join(str(self.latest.directory), str(step)), target)
        self.latest.reload()

    def close(self) -> None:
        self.latest.close()
        self.best.close()
