"""Register your own point clouds: any units, any size, any orientation, normals optional.

The pipeline around the paper's network (which itself is :func:`rpmnet_jax.register`, untouched):

1. prepare: clean, centre each cloud, scale both into the unit sphere, sample ``num_points`` per cloud for the
   network (:mod:`rpmnet_jax.scans.prepare`);
2. start: ``init="local"`` runs the network once from the identity; ``init="global"`` runs it from the
   rotation hypotheses of :mod:`rpmnet_jax.scans.global_search` in one batched call, polishes each answer
   with a short ICP and keeps the ``top_k`` best (:class:`~rpmnet_jax.scans.options.GlobalOptions`);
   ``init="auto"`` (default) refines up to ``GlobalOptions.classical`` FPFH + RANSAC hypotheses
   (:mod:`rpmnet_jax.scans.feature_ransac`: rotation invariant, cheap) first, adds the local start when the
   best refined answer's fitness is below ``GlobalOptions.network_fitness`` or it is ambiguous, and the global
   search when still no answer reaches ``GlobalOptions.auto_fitness``; ``init="classical"`` refines the classical
   hypotheses alone (no network; the identity when they find none);
3. refine: ``refine="icp"`` (default) runs robust point-to-plane ICP (:mod:`rpmnet_jax.scans.refine`) from
   each start on denser samples of the caller's clouds (``RefineOptions.points`` random source points and
   up to ``starts.REFERENCE_FACTOR`` × as many of the reference); the :class:`Candidate` with the best
   :func:`~rpmnet_jax.scans.starts.selection_score` wins;
   ``refine="none"`` returns the winning start as it is (with ``init="local"``: the network's answer, the
   paper's method);
4. score: fitness, inlier RMSE and correspondences of the answer on the full clouds, as Open3D's
   ``evaluate_registration`` (:mod:`rpmnet_jax.scans.scoring`), and the point-to-plane ``information``
   (6×6) of its fit (:meth:`Alignment.covariance` inverts it);
5. say what is uncertain: ``candidates`` lists the distinct refined answers (rotations more than
   ``AMBIGUITY_DEG`` apart), best first, with their scores; ``ambiguous`` is set when the second reaches
   ``AMBIGUITY_SHARE`` of the best's score: the shape fits itself in more than one pose (a vase turned about
   its axis, a box flipped), and the answer may be any of them.

``max_correspondence_distance`` (caller's units) is the inlier threshold of the score and the finest ICP
gate; by default 5% of the clouds' common radius (the largest distance of a non-stray point from its cloud's
centre, :func:`rpmnet_jax.scans.prepare.robust_centre`):
0.05 on the unit-sphere shapes the network was trained on (measured on 40 real ModelNet40 partial pairs, the
refined error is 0.86° / 0.57° / 0.53° / 0.69° mean at 0.03 / 0.05 / 0.08 / 0.12).
"""

from __future__ import annotations

import time
from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree

from rpmnet_jax import config as config_lib
from rpmnet_jax.ops import se3
from rpmnet_jax.scans import options as options_lib, prepare, refine as refine_lib, scoring
from rpmnet_jax.scans import normals as normals_lib
from rpmnet_jax.scans import starts as starts_lib
from rpmnet_jax.weights import loading

DEFAULT_RELATIVE_DISTANCE = 0.05


class Alignment(NamedTuple):
    transform: np.ndarray  # (4, 4): maps source points onto the reference, caller's units
    aligned: np.ndarray  # (N, 3): the caller's source moved by ``transform`` (its NaN rows stay NaN)
    transforms: np.ndarray  # (I, 4, 4): the chosen start's network iterates (classical start: its hypothesis, I=1)
    confidence: float  # network's mean inlier mass in [0, 1] (classical start: its share of inlier correspondences)
    num_points: tuple[int, int]  # points the network saw, source and reference
    fitness: float  # fraction of finite source points with a reference point within max_correspondence_distance
    inlier_rmse: float  # RMS distance of those pairs, caller's units
    correspondences: np.ndarray  # (n, 2): (source row, reference row) of the inlier pairs, in the caller's arrays
    converged: bool  # the refinement met its tolerance (True for refine="none")
    num_iterations: int  # refinement iterations (0 for refine="none")
    max_correspondence_distance: float  # the threshold used, caller's units
    init: str  # the start that won: "local", "classical", "global" (or "identity": init="classical" found none)
    timings: dict  # seconds per stage: prepare, network, classical, global, refine, score, total
    candidates: tuple  # the distinct refined answers (:class:`Answer`, > AMBIGUITY_DEG apart), best first
    ambiguous: bool  # another distinct answer scores within AMBIGUITY_SHARE of the best (a symmetric shape)
    information: np.ndarray  # (6, 6): point-to-plane information of ``transform`` (see :meth:`covariance`)

    def covariance(self) -> np.ndarray:
        """``(6, 6)`` covariance of the right perturbation ``ξ = (ω, v)`` of ``transform · Exp(ξ)`` (rotation
        in radians first, translation in the caller's units): the inverse of ``information``, i.e. the
        Gauss-Newton covariance of the final point-to-plane fit with independent residuals of the measured
        variance. Optimistic: neighbouring residuals are correlated and the fit's bias is not in it. Raises
        ``numpy.linalg.LinAlgError`` when the fit leaves a direction free (a plane, a sphere, a surface of
        revolution slides along itself: its information is singular)."""
        return np.linalg.inv(self.information)


class Answer(NamedTuple):
    """One distinct refined answer of :attr:`Alignment.candidates`."""

    transform: np.ndarray  # (4, 4), caller's units
    score: float  # share of the (dense-sampled) source within starts.SELECT_FRACTION × the distance: ranks
    fitness: float  # the same share within the full distance
    inlier_rmse: float  # RMS distance of those pairs, caller's units
    init: str  # the start it came from: "local", "classical" or "global"


class Candidate(NamedTuple):
    """A refined start, in the normalised frame; the largest ``score`` wins."""

    transform: np.ndarray  # (4, 4): the refined answer, maps source onto reference
    score: tuple  # :func:`starts.selection_score`: (tight fitness, fitness, -RMSE)
    init: str  # "local", "classical" or "global"
    network_transforms: np.ndarray  # (I, 3, 4): the network's iterates from this start (a classical one: itself)
    confidence: float
    converged: bool  # the refinement met its tolerance (True for refine="none")
    num_iterations: int  # refinement iterations (0 for refine="none")


SLID_SHARE = 0.5  # a refined candidate scoring below this share of its own start slid away; the start is kept
# (real_meshes_train's pair 77, partial, any orientation: a classical start 2.2 deg off, score 0.37, slid to 0.0 and
# 45 deg; keeping the start whenever it scores higher at all cost precision on noisy pairs: median 0.25 -> 0.30 deg
# on 20 of real_meshes_train's noisy pairs, one at 3.2 deg)
def _refine(starts, dense: starts_lib.DenseClouds | None, max_dist_unit: float, refine: str,
            refine_options: options_lib.RefineOptions) -> list:
    """Each :class:`~rpmnet_jax.scans.starts.Start` → a :class:`Candidate` (ICP on ``dense`` for
    ``refine="icp"``, else as it is)."""
    out = []
    for s in starts:
        start = se3.to_homogeneous(s.transform)
        if refine == "icp":
            r = _icp(dense, start, max_dist_unit, **refine_options.icp_kwargs())
            final, converged, iters = r.transform, r.converged, r.num_iterations
        else:
            final, converged, iters = start, True, 0
        score = starts_lib.selection_score(dense, final, max_dist_unit) if dense is not None else (1.0, 1.0, 0.0)
        if refine == "icp":  # an ICP that slid far from a start that lay on the surface: keep the start
            start_score = starts_lib.selection_score(dense, start, max_dist_unit)
            if score[0] < SLID_SHARE * start_score[0]:
                final, score = start, start_score
        out.append(Candidate(final, score, s.init, s.network_transforms, s.confidence, converged, iters))
    return out


def align(src_points, ref_points, src_normals=None, ref_normals=None, *, checkpoint=None, params=None,
          num_points: int = 1024, num_iters: int = 5, sampling: str = "random", seed: int = 0,
          reestimate_normals: bool = False, centering: str = "separate", init: str = "auto",
          refine: str = "icp", max_correspondence_distance: float | None = None,
          refine_options: options_lib.RefineOptions = options_lib.RefineOptions(),
          global_options: options_lib.GlobalOptions = options_lib.GlobalOptions(),
          cfg: config_lib.RPMNetConfig | None = None) -> Alignment:
    """Rigidly aligns ``src_points (N, 3)`` onto ``ref_points (M, 3)``; see the module docstring.

    Normals (``(N, 3)``, any length > 0) are estimated when missing or when ``reestimate_normals``.
    ``checkpoint``: orbax dir, ``.npz`` or official ``.pth``; default the shipped model (or pass ``params``).
    ``sampling``: ``random`` or ``fps`` down to ``num_points`` per cloud for the network. ``centering``:
    ``separate`` (each cloud on its centroid) or ``common`` (both on their joint centroid).
    ``refine_options`` (:class:`~rpmnet_jax.scans.options.RefineOptions`): the ICP's sample size and
    stopping; ``global_options`` (:class:`~rpmnet_jax.scans.options.GlobalOptions`): the rotation
    hypotheses, their screening and ``auto``'s fitness bars.
    Deterministic for a ``seed``.
    """
    options_lib.check(init, refine, num_iters, max_correspondence_distance, refine_options, global_options)
    t_start = time.perf_counter()
    timings = {"prepare": 0.0, "network": 0.0, "classical": 0.0, "global": 0.0, "refine": 0.0, "score": 0.0}
    pair = prepare.prepare_pair(src_points, ref_points, src_normals, ref_normals, num_points=num_points,
                                sampling=sampling, seed=seed, reestimate_normals=reestimate_normals,
                                centering=centering)
    params = params if params is not None else loading.load_params(checkpoint)
    cfg = cfg or config_lib.RPMNetConfig()
    max_dist = (max_correspondence_distance if max_correspondence_distance is not None
                else DEFAULT_RELATIVE_DISTANCE * pair.scale)
    max_dist_unit = max_dist / pair.scale
    full_ref_tree = cKDTree(pair.ref)  # the caller's whole reference: scoring, information, normals
    dense = (starts_lib.dense_clouds(pair, refine_options.points, seed, full_ref_tree)
             if (refine == "icp" or init != "local") else None)
    timings["prepare"] = time.perf_counter() - t_start

    starts = []
    if init != "local" and global_options.classical:
        t0 = time.perf_counter()
        starts += starts_lib.classical_starts(pair, global_options.classical, seed)
        timings["classical"] = time.perf_counter() - t0
    if not starts and init in ("classical", "global"):  # no hypothesis: the clouds as they lie
        starts.append(starts_lib.Start("identity", np.eye(4)[None, :3], 0.0, np.eye(4)))
    t0 = time.perf_counter()
    candidates = _refine(starts, dense, max_dist_unit, refine, refine_options)
    timings["refine"] += time.perf_counter() - t0
    if init == "local" or (init == "auto" and _needs_network(candidates, global_options)):
        t0 = time.perf_counter()
        local = [starts_lib.local_start(params, pair, cfg, num_iters)]
        timings["network"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        candidates += _refine(local, dense, max_dist_unit, refine, refine_options)
        timings["refine"] += time.perf_counter() - t0
    best_fitness = max((c.score[1] for c in candidates), default=0.0)
    if init == "global" or (init == "auto" and best_fitness < global_options.auto_fitness):
        t0 = time.perf_counter()
        screened = starts_lib.screen_hypotheses(params, pair, dense, cfg, global_options, max_dist_unit, seed)
        if refine != "icp":  # the network's answers as they are
            screened = [s._replace(transform=s.network_transforms[-1]) for s in screened]
        timings["global"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        candidates += _refine(screened, dense, max_dist_unit, refine, refine_options)
        timings["refine"] += time.perf_counter() - t0

    distinct = _distinct(sorted(candidates, key=lambda c: c.score, reverse=True))  # stable: earlier first
    if refine == "icp" and not distinct[0].converged:
        t0 = time.perf_counter()
        distinct[0] = _polish(distinct[0], dense, max_dist_unit, refine_options)
        timings["refine"] += time.perf_counter() - t0
    best = distinct[0]
    answers = tuple(Answer(pair.to_callers_units(c.transform[:3]), float(c.score[0]), float(c.score[1]),
                           -float(c.score[2]) * pair.scale, c.init) for c in distinct)
    ambiguous = _is_ambiguous(distinct)
    transform = answers[0].transform
    t0 = time.perf_counter()
    score = scoring.evaluate_registration(pair.src, pair.ref, transform, max_dist, ref_tree=full_ref_tree)
    information = _information(pair, transform, score.correspondences, full_ref_tree)
    timings["score"] = time.perf_counter() - t0
    timings["total"] = time.perf_counter() - t_start
    aligned = se3.apply(transform, np.asarray(src_points, np.float64))  # every row of the caller's
    rows = np.stack([pair.src_rows[score.correspondences[:, 0]], pair.ref_rows[score.correspondences[:, 1]]], 1)
    return Alignment(transform, aligned, pair.to_callers_units(best.network_transforms), best.confidence,
                     (pair.src6.shape[1], pair.ref6.shape[1]), score.fitness, score.inlier_rmse,
                     rows, best.converged, best.num_iterations, float(max_dist), best.init,
                     timings, answers, bool(ambiguous), information)


def _needs_network(candidates: list, opts: options_lib.GlobalOptions) -> bool:
    """``init="auto"`` runs the network when the best refined classical candidate (by selection score) has a
    fitness below ``opts.network_fitness`` (always at 1), or is ambiguous (a flip scores close to it: the
    network's start may tell them apart), or there is none."""
    if not candidates or opts.network_fitness >= 1.0:
        return True
    ranked = _distinct(sorted(candidates, key=lambda c: c.score, reverse=True))
    return ranked[0].score[1] < opts.network_fitness or _is_ambiguous(ranked)


def _is_ambiguous(distinct: list) -> bool:
    """Whether the second of the distinct :class:`Candidate` s ``distinct`` (best first) reaches
    ``AMBIGUITY_SHARE`` of the best's score."""
    return len(distinct) > 1 and distinct[1].score[0] >= AMBIGUITY_SHARE * distinct[0].score[0] > 0


def _icp(dense: starts_lib.DenseClouds, start: np.ndarray, max_dist_unit: float, **icp_kwargs) -> refine_lib.Refinement:
    """:func:`rpmnet_jax.scans.refine.point_to_plane_icp` from ``start (4, 4)`` on the dense samples."""
    return refine_lib.point_to_plane_icp(dense.src, dense.ref, dense.ref_normals, start, max_dist_unit,
                                         src_normals=dense.src_normals, ref_tree=dense.ref_tree, **icp_kwargs)


POLISH_FACTOR = 3  # the winner, if its refinement stopped on max_iterations, continues for this many times as many


def _polish(best: Candidate, dense: starts_lib.DenseClouds, max_dist_unit: float,
            refine_options: options_lib.RefineOptions) -> Candidate:
    """The winning candidate's refinement continued (``POLISH_FACTOR`` × the iterations per stage) when it had
    not converged: every candidate gets the same short budget for the selection, the answer the whole way
    (the Stanford bunny's bun180 onto bun090, 54% overlap, slides slowly: 1.4-2.2 deg off after 20
    iterations per stage, 0.23-0.25 deg at convergence, 25-46 iterations)."""
    kwargs = refine_options.icp_kwargs()
    kwargs["max_iterations"] = POLISH_FACTOR * kwargs.get("max_iterations", refine_lib.MAX_ITERATIONS)
    r = _icp(dense, best.transform, max_dist_unit, **kwargs)
    score = starts_lib.selection_score(dense, r.transform, max_dist_unit)
    if score < best.score:  # slid away (a shape that slides along itself): keep the shorter run's answer
        return best
    return best._replace(transform=r.transform, score=score, converged=r.converged,
                         num_iterations=best.num_iterations + r.num_iterations)


AMBIGUITY_DEG = 10.0  # candidates whose rotations lie closer than this are one answer (the better one kept)
AMBIGUITY_SHARE = 0.8  # ambiguous: a distinct answer's score reaches this share of the best one's
# (experiments.ambiguity, any orientation, real ModelNet40 subset: on its 9 bottles, bowls, cones and cups it flags
# 5 of the 6 answers > 5 deg off and none of the others; on 60 pairs of its test file, none; the highest second
# share there, 0.79, is an airplane's 180 deg flip of a partial crop)


def _distinct(ranked: list) -> list:
    """The :class:`Candidate` s of ``ranked`` (best first) whose rotation lies more than ``AMBIGUITY_DEG``
    from every better one's."""
    kept = []
    for c in ranked:
        if all(se3.rotation_angle_deg(c.transform[:3, :3] @ k.transform[:3, :3].T) > AMBIGUITY_DEG for k in kept):
            kept.append(c)
    return kept


def _information(pair: prepare.PreparedPair, transform: np.ndarray, correspondences: np.ndarray,
                 full_ref_tree: cKDTree) -> np.ndarray:
    """Point-to-plane information ``(6, 6)`` of ``transform`` over the inlier ``correspondences (n, 2)`` of the
    full clouds (:func:`rpmnet_jax.scans.scoring.plane_fit`; the reference's normals at the paired points,
    estimated from the full reference where the caller gave none)."""
    ref_rows = np.unique(correspondences[:, 1])
    if pair.ref_normals is not None:
        normals = pair.ref_normals
    else:
        normals = np.zeros_like(pair.ref)
        normals[ref_rows] = normals_lib.normals_at(pair.ref, ref_rows, tree=full_ref_tree)
    return scoring.plane_fit(pair.src, pair.ref, normals, transform, correspondences).information
