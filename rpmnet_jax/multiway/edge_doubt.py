"""How likely a pair edge of :func:`rpmnet_jax.align_scans` is wrong (rotation more than 5° off): a few numbers
the pipeline knows about the edge and the pair's other answers (:func:`features`) through the shipped calibrated
model (:func:`p_wrong`); and which scans' poses rest on flagged edges (:func:`resting_on_flagged`).

The model (``rpmnet_jax/weights/edge_doubt.json``: logistic regression over standardised :data:`FEATURES`, Platt
scaling, the same form as the one-pair model of :mod:`rpmnet_jax.pairwise.doubt`) is fitted offline by
``experiments/fit_edge_doubt.py`` on classical edges (``edges.classical_edges``) of simulated range scans of
training meshes and of rings of views of synthetic shapes; here it is plain NumPy. It reads an edge and never
changes it; ``align_scans`` ranks its pose graph's consensus by fitness × (1 − ``p_wrong``). Its two bars:
``threshold`` (0.5, likely wrong; the per-scan report) and ``reject_threshold`` (0.95, keep the edge out of the
graph with ``ScanOptions.edge_doubt="reject"``); measured in ``docs/model_card.md``. Its weights and
``reject_threshold`` are chosen on its training edges (out of fold), ``threshold`` is not chosen on data; its RMSE
features and the weighing were chosen on the 'held-out' rings of a box (tuning data: numbers on them are not held-out).
"""

from __future__ import annotations

import os

import numpy as np

from rpmnet_jax.multiway import options as options_lib, sizes
from rpmnet_jax.pose_graphs import pose_graph
from rpmnet_jax.ops import se3
from rpmnet_jax.pairwise import doubt

WRONG_DEG = doubt.WRONG_DEG  # an edge is wrong when its rotation is more than this far from the truth
FEATURES = ("fitness", "plane", "rmse", "good", "conditioning", "rotation_conditioning", "translation_conditioning",
            "distinct", "rank", "other_fitness", "fitness_margin", "other_gap", "rmse_excess", "rmse_margin")
MODEL_PATH = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "weights", "edge_doubt.json")
_DEFAULTS = options_lib.ScanOptions()  # the "good" feature: align_scans' default rule for a pair edge


def lever(information) -> tuple:
    """``(centre (3,), radius)`` of the pairs behind a point-to-plane ``information (6, 6)`` (rotation first, about
    the source frame's origin): the pivot that decouples rotation from translation best (least squares of the
    cross block) and the RMS lever arm about it, ``sqrt(1.5 tr(rotation block) / tr(translation block))`` (1 for
    a zero matrix): what :func:`doubt.conditioning` needs, read off the matrix."""
    info = np.asarray(information, np.float64)
    cross, trans = info[:3, 3:], info[3:, 3:]  # Σ (p×m) mᵀ, Σ m mᵀ; about a pivot c the first is cross − ĉ trans
    system = np.concatenate([np.asarray(se3.hat(trans[:, k])) for k in range(3)])  # (9, 3): ĉ C[:, k] = −Ĉ[:, k] c
    centre = np.linalg.lstsq(system, -cross.T.reshape(-1), rcond=None)[0]
    b = se3.pivot_adjoint(centre)
    b_inv = np.linalg.inv(b)
    rotation = (b_inv.T @ info @ b_inv)[:3, :3]
    t = np.trace(trans)
    radius = float(np.sqrt(1.5 * np.trace(rotation) / t)) if t > 0 and np.trace(rotation) > 0 else 1.0
    return centre, radius


def features(edge, max_distance: float, answers=()) -> np.ndarray:
    """The :data:`FEATURES` ``(F,)`` of ``edge`` (an :class:`~rpmnet_jax.pair_edges.edges.Edge`, or anything with
    its ``transform``, ``fitness``, ``inlier_rmse``, ``information``, ``plane_residual``) measured within
    ``max_distance``; ``answers``: all distinct answers of its pair (``edges.classical_edges``, before the good
    rule; the edge among them or not), which give its rank by fitness, the best other answer's fitness, the
    nearest other answer's rotation gap and how far its inlier RMSE lies above the pair's lowest (a symmetric
    shape's flip can overlap more than the right answer, but its inliers lie farther apart)."""
    d = float(max_distance)
    t = np.asarray(edge.transform, np.float64)
    others = [a for a in answers if not np.array_equal(np.asarray(a.transform, np.float64), t)]
    other_fit = max((float(a.fitness) for a in others), default=0.0)
    gap = min((float(se3.rotation_angle_deg(np.asarray(a.transform, np.float64)[:3, :3] @ t[:3, :3].T))
               for a in others), default=0.0)
    other_rmse = min((float(a.inlier_rmse) for a in others), default=float(edge.inlier_rmse))
    plane = min(float(edge.plane_residual) / d, 1.0)  # inf without pairs
    cond = doubt.conditioning(edge.information, *lever(edge.information))
    values = {
        "fitness": float(edge.fitness), "plane": plane, "rmse": float(edge.inlier_rmse) / d,
        "good": float(edge.fitness >= _DEFAULTS.min_fitness and plane <= sizes.OBJECT_PLANE_RESIDUAL),
        "conditioning": cond[0] / 12.0, "rotation_conditioning": cond[1] / 12.0,
        "translation_conditioning": cond[2] / 12.0,
        "distinct": float(np.log1p(len(others) + 1)),
        "rank": float(sum(float(a.fitness) > float(edge.fitness) for a in others)),
        "other_fitness": other_fit, "fitness_margin": float(edge.fitness) - other_fit, "other_gap": gap / 180.0,
        "rmse_excess": max(float(edge.inlier_rmse) - other_rmse, 0.0) / d,
        "rmse_margin": (float(edge.inlier_rmse) - other_rmse) / d}
    return np.array([values[k] for k in FEATURES])


class Model(doubt.Model):
    """:class:`doubt.Model` (standardise, logistic score, Platt) over the :data:`FEATURES` of an edge;
    ``threshold``: the bar of ``likely_wrong`` (and of :func:`resting_on_flagged`), ``reject_threshold``: the
    higher bar at which an edge is best kept out of the pose graph."""

    FEATURES = FEATURES
    NAME = "edge doubt model"

    def __init__(self, spec: dict):
        super().__init__(spec)
        self.reject_threshold = float(spec["reject_threshold"])


def load(path: str = MODEL_PATH) -> Model:
    """The model of a JSON file (default the shipped one), read once."""
    return doubt.read_model(Model, path)


def p_wrong(edge, max_distance: float, answers=(), model: Model | None = None) -> float:
    """The probability that the rotation of one edge (see :func:`features`) is more than ``WRONG_DEG`` off; likely
    wrong at ``model.threshold`` and up, best kept out of the pose graph at ``model.reject_threshold`` and up."""
    model = model or load()
    return float(model.probability(features(edge, max_distance, answers)))


def p_wrong_of_pairs(answers_per_pair, max_distance: float, model: Model | None = None) -> list:
    """``[(E_k,) probabilities, ...]``: :func:`p_wrong` of every answer of every pair, ``answers_per_pair`` a list
    of each pair's distinct answers (as ``edges.classical_edges`` returns them, before the good rule)."""
    model = model or load()
    out = []
    for answers in answers_per_pair:
        x = [features(e, max_distance, answers) for e in answers]
        out.append(model.probability(np.stack(x)) if x else np.zeros(0))
    return out


def resting_on_flagged(num_scans: int, pairs, flagged, anchor: int) -> np.ndarray:
    """``(S,)`` bool: scans joined to ``anchor`` by the kept edges ``pairs (E, 2)`` but not by those of them that
    are not ``flagged (E,)``: every path of their pose to the anchor crosses a likely wrong edge."""
    pairs = np.asarray(pairs, np.int64).reshape(-1, 2)
    flagged = np.asarray(flagged, bool).reshape(-1)
    return pose_graph.component(num_scans, pairs, anchor) & ~pose_graph.component(num_scans, pairs[~flagged], anchor)
