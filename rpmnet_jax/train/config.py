"""The configuration of a training run (saved as ``config.json`` beside its checkpoints)."""

from __future__ import annotations

import dataclasses
import json
import os

from rpmnet_jax import config as config_lib


class ConfigMismatchError(ValueError):
    """The workdir holds a run whose configuration differs from the requested one; ``settings`` names the fields."""

    def __init__(self, message: str, settings: tuple[str, ...] = ()):
        super().__init__(message)
        self.settings = settings


# What a resumed run must keep, and why: the data, the network, the data order and the optimizer's schedule.
_FIXED = {"dataset": "the data", "data_root": "the data", "synthetic": "the data", "num_points": "the data",
          "rot_mag": "the data", "views_share": "the data", "seed": "the data order", "model": "the network",
          "batch_size": "the data order and the step count",
          "lr": "the schedule", "lr_schedule": "the schedule", "warmup_steps": "the schedule",
          "lr_final": "the schedule", "clip_norm": "the optimizer", "ema_decay": "the optimizer"}
# With the cosine schedule the run's length is its horizon; a constant schedule can be extended or shortened.
_COSINE_FIXED = {"epochs": "the cosine schedule's length", "max_steps": "the cosine schedule's length"}


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
    rot_mag: float = 45.0  # largest training rotation per Euler axis (degrees); validation stays at 45
    views_share: float = 0.0  # partial training pairs cut as camera views with self-occlusion (data.views)
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
        return default_batch_size(self.dataset) if self.batch_size is None else self.batch_size

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["model"] = self.model.to_dict()
        return d


def default_batch_size(dataset: str) -> int:
    """The official batch size: 8 for partial, 4 for clean/noisy."""
    return 8 if dataset == "partial" else 4


def _comparable(d: dict, key: str):
    if key == "model":  # fused_prepool changes speed only
        return {k: v for k, v in (d.get("model") or {}).items() if k != "fused_prepool"}
    if key == "batch_size":
        return d.get("batch_size") or default_batch_size(d.get("dataset", "noisy"))
    if key == "rot_mag":  # runs saved before the setting existed trained at the paper's 45 degrees
        return d.get("rot_mag", 45.0)
    if key == "views_share":  # runs saved before the setting existed used the paper's crops only
        return d.get("views_share", 0.0)
    return d.get(key)


def resume_conflicts(saved: dict, current: dict) -> dict:
    """``{setting: (saved, requested, why it must stay)}`` for each setting a resume may not change."""
    fixed = dict(_FIXED, **(_COSINE_FIXED if current.get("lr_schedule") == "cosine" else {}))
    return {k: (_comparable(saved, k), _comparable(current, k), why) for k, why in fixed.items()
            if _comparable(saved, k) != _comparable(current, k)}


def check_and_save(cfg: TrainConfig) -> None:
    """Refuses (:class:`ConfigMismatchError`) to resume a run in ``cfg.workdir`` with settings that define its
    data, network or schedule changed; then writes ``config.json``."""
    path = os.path.join(cfg.workdir, "config.json")
    current = json.loads(json.dumps(cfg.to_dict()))  # as it reads back (tuples as lists)
    if os.path.isfile(path):
        with open(path) as f:
            saved = json.load(f)
        conflicts = resume_conflicts(saved, current)
        if conflicts:
            what = "; ".join(f"{k} {a!r} there, {b!r} now (it sets {why})" if k != "model" else
                             f"model {_model_diff(a, b)} (it sets {why})" for k, (a, b, why) in conflicts.items())
            raise ConfigMismatchError(f"{cfg.workdir} holds a run with a different {', '.join(conflicts)}: {what}",
                                      tuple(conflicts))
    os.makedirs(cfg.workdir, exist_ok=True)
    import jax
    if jax.process_index() != 0:  # one writer in a multi-process run
        return
    tmp = path + ".tmp"
    with open(tmp, "w") as f:
        json.dump(current, f, indent=2)
    os.replace(tmp, path)


def _model_diff(saved: dict, current: dict) -> str:
    return ", ".join(f"{k} {saved.get(k)!r} there, {current.get(k)!r} now" for k in sorted(set(saved) | set(current))
                     if saved.get(k) != current.get(k))
