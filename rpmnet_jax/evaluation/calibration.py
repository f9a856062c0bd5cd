"""How well probabilities of a binary event are ranked and calibrated: AUROC, expected calibration error and the
reliability diagram's bins (NumPy; the likely-wrong flag's evaluation, :mod:`rpmnet_jax.pairwise.doubt`)."""

from __future__ import annotations

import numpy as np


def auroc(scores, labels) -> float:
    """Area under the ROC curve of ``scores (R,)`` for bool ``labels (R,)`` (ties count one half); NaN when
    one class is missing."""
    s, y = np.asarray(scores, np.float64), np.asarray(labels, bool)
    pos, neg = s[y], s[~y]
    if len(pos) == 0 or len(neg) == 0:
        return float("nan")
    greater = (pos[:, None] > neg[None, :]).sum() + 0.5 * (pos[:, None] == neg[None, :]).sum()
    return float(greater / (len(pos) * len(neg)))


def bins(probabilities, labels, num_bins: int = 10) -> tuple:
    """``(count, mean probability, observed frequency)`` per equal-width bin of [0, 1], each ``(num_bins,)``
    (mean and frequency NaN in an empty bin)."""
    p, y = np.asarray(probabilities, np.float64), np.asarray(labels, np.float64)
    idx = np.clip((p * num_bins).astype(int), 0, num_bins - 1)
    count = np.bincount(idx, minlength=num_bins).astype(float)
    with np.errstate(invalid="ignore"):
        mean_p = np.bincount(idx, p, num_bins) / count
        freq = np.bincount(idx, y, num_bins) / count
    return count, mean_p, freq


def ece(probabilities, labels, num_bins: int = 10) -> float:
    """Expected calibration error: ``Σ_b (n_b / n) |mean p_b - frequency_b|`` over ``num_bins`` equal-width bins."""
    count, mean_p, freq = bins(probabilities, labels, num_bins)
    full = count > 0
    return float(np.sum(count[full] * np.abs(mean_p[full] - freq[full])) / max(count.sum(), 1))
