"""Orbax checkpoints of the train state: the latest few and the best by validation, atomic writes."""

from __future__ import annotations

import logging
import os

import jax
import numpy as np
import orbax.checkpoint as ocp

from rpmnet_jax.train.parallel import to_host
from rpmnet_jax.train.step import TrainState

log = logging.getLogger("rpmnet_jax.train")


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
