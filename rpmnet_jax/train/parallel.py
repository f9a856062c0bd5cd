"""Data parallelism over every device (all processes): batch sharded on axis 0, state replicated."""

from __future__ import annotations

import os

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

DEVICE_KEYS = ("points_src", "points_ref", "transform_gt")


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
