"""Training: config, state and step, data parallelism, checkpoints, the loop."""

from rpmnet_jax.train.checkpoints import CheckpointError, Checkpoints
from rpmnet_jax.train.config import ConfigMismatchError, TrainConfig
from rpmnet_jax.train.loop import train_and_evaluate, validate
from rpmnet_jax.train.parallel import DEVICE_KEYS, Parallel, initialize_distributed, to_host
from rpmnet_jax.train.step import TrainState, create_train_state, make_eval_fn, make_optimizer, make_train_step
from rpmnet_jax.weights.loading import restore_params

__all__ = ["CheckpointError", "Checkpoints", "ConfigMismatchError", "DEVICE_KEYS", "Parallel", "TrainConfig",
           "TrainState", "create_train_state", "initialize_distributed", "make_eval_fn", "make_optimizer",
           "make_train_step", "restore_params", "to_host", "train_and_evaluate", "validate"]
