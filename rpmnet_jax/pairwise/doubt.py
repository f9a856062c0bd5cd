"""How likely an :class:`~rpmnet_jax.pairwise.alignment.Alignment` is wrong (rotation more than 5° off): a few
numbers the pipeline already knows (:func:`features`) through the shipped calibrated model (:func:`p_wrong`).

The model (``rpmnet_jax/weights/doubt.json``: logistic regression over standardised :data:`FEATURES`, its score
mapped to a probability by Platt scaling) is fitted offline by ``experiments/fit_doubt.py`` on pairs made from
training files only; here it is plain NumPy. It reads the answer and never changes it.
"""

from __future__ import annotations

import functools
import json
import os

import numpy as np

from rpmnet_jax.ops import se3

WRONG_DEG = 5.0  # an answer is wrong when its rotation is more than this far from the truth
NETWORK_INITS = ("local", "global")
FEATURES = ("tight", "fitness_dense", "rmse_dense", "fitness", "rmse", "tight_share", "second_share", "second_gap",
            "second_fitness_share", "distinct", "support", "support_margin", "agree", "confidence", "converged",
            "conditioning", "rotation_conditioning", "translation_conditioning", "ambiguous")
# not among them: which start won and which stages ran (no better out of fold on the training pairs, and they would
# tie the flag to init="auto"'s rules: init="classical" never runs the network)
LEVER_ROWS = 2048  # at most about this many inlier rows measure the centre and radius of :func:`lever`
MODEL_PATH = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "weights", "doubt.json")
# its weights and threshold (0.35) are chosen on training pairs only (crops of both train files, simulated scans of 12
# training meshes; the threshold out of fold); fitting it on scans too was chosen on the 16 'held-out' meshes' scans
# and the bunny's 90 pairs (tuning data: numbers on that data are not held-out)


def lever(alignment) -> tuple:
    """``(centre (3,), radius)``: the mean of the inlier source points in the source frame and their RMS distance
    from it, caller's units (``(0, 1)`` without inliers): where :func:`features` measures the fit's conditioning."""
    rows = np.asarray(alignment.correspondences, np.int64).reshape(-1, 2)[:, 0]
    rows = rows[::max(1, len(rows) // LEVER_ROWS)]  # evenly spread: the centre and spread, not every row
    if len(rows) == 0:
        return np.zeros(3), 1.0
    moved = np.asarray(alignment.aligned, np.float64)[rows]
    centre_moved = moved.mean(axis=0)
    radius = float(np.sqrt(np.mean(np.sum((moved - centre_moved) ** 2, axis=1)))) or 1.0
    t = np.asarray(alignment.transform, np.float64)
    return t[:3, :3].T @ (centre_moved - t[:3, 3]), radius


def _log_ratio(matrix) -> float:
    """``log10(λmin / λmax)`` of a symmetric PSD matrix, floored at -12 (0 for a zero matrix)."""
    eig = np.linalg.eigvalsh(matrix)
    if eig[-1] <= 0:
        return -12.0
    return float(np.log10(max(eig[0] / eig[-1], 1e-12)))


def conditioning(information, centre, radius) -> tuple:
    """``log10(λmin/λmax)`` of the ``(6, 6)`` point-to-plane ``information`` (rotation first) about ``centre``
    with rotations scaled by ``radius`` (so both blocks are in length units), and of its rotation and translation
    blocks: near -12 where the fit slides along itself (a plane, a sphere, a surface of revolution)."""
    info = np.asarray(information, np.float64)
    b = se3.pivot_adjoint(centre)  # ξ' = B ξ moves the rotation's pivot to the centre: v' = v + ω × c
    b_inv = np.linalg.inv(b)
    centred = b_inv.T @ info @ b_inv
    s = np.diag([1.0 / radius] * 3 + [1.0] * 3)
    scaled = s @ centred @ s
    return _log_ratio(scaled), _log_ratio(scaled[:3, :3]), _log_ratio(scaled[3:, 3:])


def features(alignment, centre, radius) -> np.ndarray:
    """The :data:`FEATURES` ``(F,)`` of an alignment (anything with its fields: ``candidates``, ``fitness``,
    ``inlier_rmse``, ``max_correspondence_distance``, ``information``, ``confidence``, ``converged``,
    ``ambiguous``); ``centre``, ``radius`` from :func:`lever`."""
    a, d = alignment, float(alignment.max_correspondence_distance)
    cands = a.candidates
    best = cands[0] if cands else None
    tight = float(best.score) if best else 0.0
    fit_dense = float(best.fitness) if best else 0.0
    second = cands[1] if len(cands) > 1 else None
    share = float(second.score) / tight if second is not None and tight > 0 else 0.0
    fit_share = float(second.fitness) / fit_dense if second is not None and fit_dense > 0 else 0.0
    gap = (float(se3.rotation_angle_deg(np.asarray(second.transform)[:3, :3] @ np.asarray(best.transform)[:3, :3].T))
           / 180.0) if second is not None else 0.0
    support = tuple(getattr(best, "support", ())) if best else ()
    second_support = tuple(getattr(second, "support", ())) if second is not None else ()
    cond = conditioning(a.information, centre, radius)
    values = {
        "tight": tight, "fitness_dense": fit_dense,
        "rmse_dense": float(best.inlier_rmse) / d if best else 1.0,
        "fitness": float(a.fitness), "rmse": float(a.inlier_rmse) / d,
        "tight_share": tight / fit_dense if fit_dense > 0 else 0.0,
        "second_share": share, "second_gap": gap, "second_fitness_share": fit_share,
        "distinct": float(np.log1p(len(cands))), "support": float(np.log1p(len(support))),
        "support_margin": float(len(support) - len(second_support)) / max(len(support) + len(second_support), 1),
        "agree": float("classical" in support and any(i in NETWORK_INITS for i in support)),
        "confidence": float(a.confidence),
        "converged": float(a.converged), "conditioning": cond[0] / 12.0, "rotation_conditioning": cond[1] / 12.0,
        "translation_conditioning": cond[2] / 12.0, "ambiguous": float(a.ambiguous)}
    return np.array([values[k] for k in FEATURES])


class Model:
    """The shipped model: ``score = ((x - mean) / scale) · coef + intercept``, then Platt's calibration
    ``p = 1 / (1 + exp(-(platt_a · score + platt_b)))``; ``threshold``: the default bar of ``likely_wrong``.
    ``FEATURES``: the names this code makes, which the file's must equal (a subclass names its own)."""

    FEATURES = FEATURES
    NAME = "doubt model"

    def __init__(self, spec: dict):
        if tuple(spec["features"]) != self.FEATURES:
            raise ValueError(f"the {self.NAME} was fitted on features {spec['features']}, this code makes "
                             f"{self.FEATURES}")
        self.mean, self.scale = np.asarray(spec["mean"], np.float64), np.asarray(spec["scale"], np.float64)
        self.coef, self.intercept = np.asarray(spec["coef"], np.float64), float(spec["intercept"])
        self.platt_a, self.platt_b = float(spec["platt_a"]), float(spec["platt_b"])
        self.threshold = float(spec["threshold"])

    def score(self, x) -> np.ndarray:
        """Logistic-regression score of features ``x (..., F)`` → ``(...)``."""
        return ((np.asarray(x, np.float64) - self.mean) / self.scale) @ self.coef + self.intercept

    def probability(self, x) -> np.ndarray:
        """Calibrated probability of a wrong answer for features ``x (..., F)`` → ``(...)``, in [0, 1]."""
        return 1.0 / (1.0 + np.exp(-(self.platt_a * self.score(x) + self.platt_b)))


@functools.lru_cache(maxsize=8)
def read_model(model_class: type, path: str):
    """A ``model_class`` (:class:`Model` or a subclass) of a JSON file, read once."""
    with open(path) as f:
        return model_class(json.load(f))


def load(path: str = MODEL_PATH) -> Model:
    """The model of a JSON file (default the shipped one), read once."""
    return read_model(Model, path)


def p_wrong(alignment, model: Model | None = None) -> tuple:
    """``(p_wrong, likely_wrong)`` of an alignment: the probability that its rotation is more than
    ``WRONG_DEG`` off, and whether it reaches the model's threshold."""
    model = model or load()
    p = float(model.probability(features(alignment, *lever(alignment))))
    return p, bool(p >= model.threshold)
