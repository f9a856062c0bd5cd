"""The configuration of a training run (saved as ``config.json`` beside its checkpoints)."""

from __future__ import annotations

import dataclasses
import json
import os

from rpmnet_jax import config as config_lib


class ConfigMismatchError(ValueError):
    """The workdir holds a run whose configuration differs from the requested one."""


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


def check_and_save(cfg: TrainConfig) -> None:
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
            raise ConfigMismatchError(f"{cfg.workdir} holds a run with a different configuration {diff}")
    os.makedirs(cfg.workdir, exist_ok=True)
    import jax
    if jax.process_index() != 0:  # one writer in a multi-process run
        return
    tmp = path + ".tmp"
    with open(tmp, "w") as f:
        json.dump(current, f, indent=2)
    os.replace(tmp, path)
