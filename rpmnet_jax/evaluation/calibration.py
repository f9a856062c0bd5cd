"""How well probabilities of a binary event are ranked and calibrated: AUROC, expected calibration error and the
reliability diagram's bins (NumPy; the likely-wrong flags' evaluation, :mod:`rpmnet_jax.pairwise.doubt` and
:mod:`rpmnet_jax.multiway.edge_doubt`); and the one fit of those flags' models (logistic regression, grouped
out-of-fold scores, Platt's calibration, the bar: scikit-learn, imported when a fit runs)."""

from __future__ import annotations

from typing import NamedTuple

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


class Fitted(NamedTuple):
    """A logistic regression with Platt's calibration (scikit-learn objects) and its out-of-fold scores."""

    scaler: object  # StandardScaler of the features
    scale: np.ndarray  # (F,) its scale, 1 where a feature is constant
    lr: object  # LogisticRegression on the standardised features, fitted on every row
    platt: object  # LogisticRegression mapping a score to a probability, fitted on the out-of-fold scores
    scores: np.ndarray  # (N,) each row's score from the fold that held it out
    fold: np.ndarray  # (N,) that fold

    def spec(self) -> dict:
        """The numbers a NumPy model needs: ``mean``, ``scale``, ``coef``, ``intercept``, ``platt_a``, ``platt_b``."""
        return {"mean": self.scaler.mean_.tolist(), "scale": self.scale.tolist(), "coef": self.lr.coef_[0].tolist(),
                "intercept": float(self.lr.intercept_[0]), "platt_a": float(self.platt.coef_[0, 0]),
                "platt_b": float(self.platt.intercept_[0])}


def _platt():
    from sklearn import linear_model
    return linear_model.LogisticRegression(C=1e6, max_iter=1000)  # no penalty to speak of: two numbers


def fit_logistic_platt(x, y, groups, folds: int, c: float, max_iter: int) -> Fitted:
    """Logistic regression (inverse L2 strength ``c``) on the standardised ``x (N, F)`` for the labels ``y (N,)``,
    its out-of-fold scores by grouped ``folds``-fold cross-validation (``groups (N,)``: a group in one fold), Platt's
    map fitted on those scores, the regression refitted on every row (scikit-learn: the dev extra)."""
    from sklearn import linear_model, model_selection, preprocessing

    scaler = preprocessing.StandardScaler().fit(x)
    scale = np.where(scaler.scale_ > 0, scaler.scale_, 1.0)
    z = (x - scaler.mean_) / scale
    lr = linear_model.LogisticRegression(C=c, max_iter=max_iter)
    scores, fold = np.zeros(len(y)), np.zeros(len(y), int)
    for k, (train, test) in enumerate(model_selection.GroupKFold(folds).split(z, y, groups)):
        scores[test], fold[test] = lr.fit(z[train], y[train]).decision_function(z[test]), k
    platt = _platt().fit(scores[:, None], y)  # Platt: a logistic map of the out-of-fold scores
    lr.fit(z, y)
    return Fitted(scaler, scale, lr, platt, scores, fold)


def held_out_platt(scores, labels, held) -> np.ndarray:
    """``(N,)`` probabilities of ``scores``: the rows of each value of ``held (N,)`` through Platt's map fitted on
    the other rows (honest out-of-fold probabilities)."""
    out = np.zeros(len(scores))
    for k in np.unique(held):
        rows = held == k
        out[rows] = _platt().fit(scores[~rows, None], labels[~rows]).predict_proba(scores[rows, None])[:, 1]
    return out


def lowest_bar(probabilities, rows, max_share: float) -> float:
    """The lowest bar on a 0.05 grid from 0.1 to 0.95 flagging (``probabilities ≥ bar``) at most ``max_share`` of
    the ``rows (N,)`` (a mask: e.g. the right answers); 0.95 when none does."""
    for t in np.round(np.arange(0.1, 0.951, 0.05), 2):
        if np.mean(probabilities[rows] >= t) <= max_share:
            return float(t)
    return 0.95
