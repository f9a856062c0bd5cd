"""Paired comparison of two models on the same pairs: is a difference in the target rows more than noise?

A test file of ~150 pairs whose mean is carried by a handful of far misses cannot tell two states a few tenths of
a degree apart. ``compare`` resamples the pairs (a paired bootstrap: the same resampled pairs for both models) and
gives each statistic of model B minus model A with its percentile interval.
"""

from __future__ import annotations

import csv

import numpy as np

THRESHOLD_DEG = 5.0


def read_errors(path: str, column: str = "err_r_deg") -> tuple[np.ndarray, np.ndarray]:
    """``(idx (N,), errors (N,))`` of an evaluation's ``per_pair_<method>.csv``."""
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    if not rows:
        raise ValueError(f"{path}: no pairs")
    if column not in rows[0] or "idx" not in rows[0]:
        raise ValueError(f"{path}: needs the columns 'idx' and {column!r}; has {sorted(rows[0])}")
    return (np.array([int(r["idx"]) for r in rows]), np.array([float(r[column]) for r in rows]))


def _stats(err_RxN: np.ndarray, threshold: float) -> dict:
    """``mean``, ``median`` and ``share_under`` over the last axis: each ``(R,)``."""
    return {"mean": err_RxN.mean(-1), "median": np.median(err_RxN, -1),
            "share_under": (err_RxN < threshold).mean(-1)}


def _interval(x_R: np.ndarray, level: float) -> list[float]:
    """The central ``level`` percentile interval ``[lo, hi]`` of resampled values ``(R,)``."""
    tail = 100.0 * (1.0 - level) / 2.0
    return [float(v) for v in np.percentile(x_R, [tail, 100.0 - tail])]


def compare(err_a: np.ndarray, err_b: np.ndarray, resamples: int = 5000, level: float = 0.95,
            threshold: float = THRESHOLD_DEG, seed: int = 0) -> dict:
    """Model B against model A on the same pairs (``err_* (N,)``, pair ``i`` the same in both).

    Returns ``{stat: {"a", "a_interval", "b", "b_interval", "b_minus_a", "interval", "resolved"}}`` for
    ``mean``, ``median`` and ``share_under`` (share of pairs under ``threshold``); each ``*interval`` is
    ``[lo, hi]`` at ``level``; ``interval`` is that of B - A, and ``resolved``: it excludes 0.
    """
    err_a, err_b = np.asarray(err_a, np.float64), np.asarray(err_b, np.float64)
    if err_a.ndim != 1 or err_a.shape != err_b.shape or not len(err_a):
        raise ValueError(f"need two equal-length 1-D error arrays; got {err_a.shape} and {err_b.shape}")
    if not (np.isfinite(err_a).all() and np.isfinite(err_b).all()):
        raise ValueError("errors must be finite")
    if not 0.0 < level < 1.0:
        raise ValueError(f"level must lie in (0, 1); got {level}")
    rng = np.random.default_rng(seed)
    pick_RxN = rng.integers(0, len(err_a), size=(resamples, len(err_a)))
    full_a, full_b = _stats(err_a[None], threshold), _stats(err_b[None], threshold)
    boot_a, boot_b = _stats(err_a[pick_RxN], threshold), _stats(err_b[pick_RxN], threshold)
    out = {}
    for name in full_a:
        lo, hi = _interval(boot_b[name] - boot_a[name], level)
        out[name] = {"a": float(full_a[name][0]), "a_interval": _interval(boot_a[name], level),
                     "b": float(full_b[name][0]), "b_interval": _interval(boot_b[name], level),
                     "b_minus_a": float(full_b[name][0] - full_a[name][0]),
                     "interval": [lo, hi], "resolved": bool(lo > 0.0 or hi < 0.0)}
    return out
