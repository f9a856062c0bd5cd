"""Data parallelism over every device of every process: batch sharded on axis 0, state replicated.

Multi-process (``jax.distributed``): every process builds the same global batch (the data order is a pure
function of seed and epoch) and places only its own rows on its own devices, so the global batch and the
data order equal a single-process run's; the state is replicated on every device of every process.
"""

from __future__ import annotations

import os

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

DEVICE_KEYS = ("points_src", "points_ref", "transform_gt")


class Parallel:
    """1-D data-parallel mesh over all devices (all processes): batches sharded on axis 0, state replicated."""

    def __init__(self):
        self.mesh = Mesh(np.array(jax.devices()), ("data",))
        self.batch = NamedSharding(self.mesh, PartitionSpec("data"))
        self.replicated = NamedSharding(self.mesh, PartitionSpec())
        self.size = jax.device_count()
        self.process, self.processes = jax.process_index(), jax.process_count()

    def put_batch(self, batch: dict) -> dict:
        """The global batch (identical on every process) → arrays sharded over all devices."""
        out = {}
        for k in DEVICE_KEYS:
            x = np.asarray(batch[k])
            rows = x.shape[0] // self.processes
            local = x[self.process * rows:(self.process + 1) * rows]
            out[k] = jax.make_array_from_process_local_data(self.batch, local, x.shape)
        return out

    def any(self, flag: bool) -> bool:
        """Whether ``flag`` is set on any process (a collective: every process calls it at the same point)."""
        if self.processes == 1:
            return bool(flag)
        from jax.experimental import multihost_utils
        return bool(np.any(multihost_utils.process_allgather(np.int32(bool(flag)))))

    def put_state(self, state):
        """A host pytree (identical on every process) → arrays replicated on every device."""
        return jax.tree.map(lambda x: jax.make_array_from_process_local_data(self.replicated, np.asarray(x)), state)


def to_host(tree):
    """NumPy copies of replicated (or fully addressable) arrays; works when other processes hold devices too."""
    def get(x):
        if isinstance(x, jax.Array) and not x.is_fully_addressable:
            return np.asarray(x.addressable_data(0))
        return np.asarray(jax.device_get(x))
    return jax.tree.map(get, tree)


def initialize_distributed(coordinator: str | None = None, num_processes: int | None = None,
                           process_id: int | None = None) -> bool:
    """Joins a multi-process run when a coordinator is given (arguments or the ``JAX_COORDINATOR_ADDRESS``,
    ``JAX_NUM_PROCESSES``, ``JAX_PROCESS_ID`` environment variables); returns whether it did."""
    coordinator = coordinator or os.environ.get("JAX_COORDINATOR_ADDRESS") or os.environ.get("COORDINATOR_ADDRESS")
    if not coordinator:
        return False
    env_int = lambda name: int(os.environ[name]) if name in os.environ else None
    num_processes = num_processes if num_processes is not None else env_int("JAX_NUM_PROCESSES")
    process_id = process_id if process_id is not None else env_int("JAX_PROCESS_ID")
    jax.config.update("jax_cpu_collectives_implementation", "gloo")  # CPU devices talk across processes
    jax.distributed.initialize(coordinator, num_processes, process_id)
    return True

