"""Register your own point clouds: any units, any size, any orientation, normals optional.

The pipeline around the paper's network (which itself is :func:`rpmnet_jax.register`, untouched):

1. prepare: clean, centre each cloud, scale both into the unit sphere, sample ``NetworkOptions.points`` per cloud
   for the network (:mod:`rpmnet_jax.pairwise.prepare`);
2. start: ``init="local"`` runs the network once from the identity; ``init="global"`` runs it from the
   rotation hypotheses of :mod:`rpmnet_jax.pairwise.global_search` in one batched call, polishes each answer
   with a short ICP and keeps the ``top_k`` best (:class:`~rpmnet_jax.pairwise.options.GlobalOptions`);
   ``init="auto"`` (default) refines up to ``GlobalOptions.classical`` FPFH + RANSAC hypotheses
   (:mod:`rpmnet_jax.classical.feature_ransac`: rotation invariant, cheap) first, adds the local start when the
   best refined answer is ambiguous, or when its fitness is below ``GlobalOptions.network_fitness`` and the
   answer it would give is not trusted (its fitness below 0.45, or at least ``GlobalOptions.network_doubt``
   likely wrong by step 6), and the global
   search when still no answer reaches ``GlobalOptions.auto_fitness`` and the best one is not confirmed (reached
   from a classical and from the network's start, nothing close to it: two independent starts agree); ``init="classical"`` refines the classical
   hypotheses alone (no network; the identity when they find none);
3. refine: ``refine="icp"`` (default) runs robust point-to-plane ICP (:mod:`rpmnet_jax.classical.icp`) from
   each start on denser samples of the caller's clouds (``RefineOptions.points`` random source points and
   up to ``prepare.REFERENCE_FACTOR`` × as many of the reference); the
   :class:`~rpmnet_jax.pairwise.candidates.Candidate` with the best
   :func:`~rpmnet_jax.pairwise.candidates.selection_score` wins (with ``init="auto"``, a classical candidate
   that falls below a third of a strong one's score stops refining early: it cannot win);
   ``refine="none"`` returns the winning start as it is (with ``init="local"``: the network's answer, the
   paper's method);
4. score: fitness, inlier RMSE and correspondences of the answer on the full clouds, as Open3D's
   ``evaluate_registration`` (:mod:`rpmnet_jax.classical.scoring`), and the point-to-plane ``information``
   (6×6) of its fit (:meth:`Alignment.covariance` inverts it);
5. say what is uncertain: ``candidates`` lists the distinct refined answers (rotations more than
   ``AMBIGUITY_DEG`` apart), best first, with their scores; ``ambiguous`` is set when the second reaches
   ``AMBIGUITY_SHARE`` of the best's score: the shape fits itself in more than one pose (a vase turned about
   its axis, a box flipped), and the answer may be any of them;
6. say how likely it is wrong: ``p_wrong`` is the calibrated probability that the rotation is more than 5° off,
   from what the steps above measured (:mod:`rpmnet_jax.pairwise.doubt`), ``likely_wrong`` whether it reaches
   the shipped model's threshold; it reads the answer and never changes it.

Scans whose sensors are known (``viewpoints``), or taken from their frame origins (scanner stations, RGB-D frames,
full-density sweeps: their spacing grows with the distance from it, :func:`rpmnet_jax.geometry.sensors.taken_from`,
both clouds): the best distinct candidate that keeps each cloud out of the space the other's sensor saw through
(:mod:`rpmnet_jax.geometry.visibility`) is the answer (a room's half turn fits its walls as well as the truth and
puts its furniture there), and the candidates that do not keep out are no rivals: they leave ``candidates``, the
ambiguity and the doubt; when none keeps out, the answer is ``likely_wrong``.

A cloud of more than ``prepare.MAX_POINTS`` (200,000) finite rows is registered and scored on a seeded random
subset of that many (what Open3D's recipe gets from voxel downsampling first): ``fitness``, ``inlier_rmse`` and
``correspondences`` are then over the subset's rows; ``aligned`` still has every row of the caller's source.

``max_correspondence_distance`` (caller's units) is the inlier threshold of the score and the finest ICP
gate; by default 5% of the clouds' common radius (the largest distance of a non-stray point from its cloud's
centre, :func:`rpmnet_jax.geometry.cloud.robust_centre`):
0.05 on the unit-sphere shapes the network was trained on (measured on 40 real ModelNet40 partial pairs, the
refined error is 0.86° / 0.57° / 0.53° / 0.69° mean at 0.03 / 0.05 / 0.08 / 0.12; chosen on those 40 pairs, file not
recorded: tuning data, numbers on that data are not held-out).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from rpmnet_jax import config as config_lib, stopwatch
from rpmnet_jax.geometry import sampling as sampling_lib, sensors, threads, visibility
from rpmnet_jax.classical import scoring
from rpmnet_jax.ops import se3
from rpmnet_jax.pairwise import candidates as candidates_lib, global_search, options as options_lib, prepare
from rpmnet_jax.pairwise import auto, doubt, starts as starts_lib
from rpmnet_jax.weights import loading

DEFAULT_RELATIVE_DISTANCE = 0.05  # chosen on 40 real ModelNet40 partial pairs (see above; tuning data)
FREE_SPACE_CELL = 0.2  # the free-space check's voxel grid, × the correspondence distance (its margin: 5 cells)


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
    timings: dict  # seconds per stage that ran (``stages``), and total
    candidates: tuple  # the distinct refined answers (:class:`Answer`, > AMBIGUITY_DEG apart), best first
    ambiguous: bool  # another distinct answer scores within AMBIGUITY_SHARE of the best (a symmetric shape)
    information: np.ndarray  # (6, 6): point-to-plane information of ``transform`` (see :meth:`covariance`)
    p_wrong: float = float("nan")  # calibrated probability that the rotation is > 5 deg off (:mod:`doubt`)
    likely_wrong: bool = False  # p_wrong reaches the shipped model's threshold (0.35, :func:`doubt.load`)

    @property
    def stages(self) -> tuple:
        """The stages that ran, in order (of prepare, classical, network, global, refine, score)."""
        return tuple(k for k in self.timings if k != "total")

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
    score: float  # share of the (dense-sampled) source within candidates.SELECT_FRACTION × the distance: ranks
    fitness: float  # the same share within the full distance
    inlier_rmse: float  # RMS distance of those pairs, caller's units
    init: str  # the start it came from: "local", "classical", "global" or "identity"
    support: tuple = ()  # the inits of the refined starts that ended within AMBIGUITY_DEG of it (itself included)


@threads.compiled_loops()  # BLAS leaves the cores to the compiled loops (geometry.threads)
def align(src_points, ref_points, src_normals=None, ref_normals=None, *, init: str = "auto", refine: str = "icp",
          max_correspondence_distance: float | None = None, seed: int = 0, checkpoint=None, params=None,
          network_options: options_lib.NetworkOptions = options_lib.NetworkOptions(),
          refine_options: options_lib.RefineOptions = options_lib.RefineOptions(),
          global_options: options_lib.GlobalOptions = options_lib.GlobalOptions(),
          reestimate_normals: bool = False, viewpoints="auto", cfg: config_lib.RPMNetConfig | None = None) -> Alignment:
    """Rigidly aligns ``src_points (N, 3)`` onto ``ref_points (M, 3)``; see the module docstring.

    Normals (``(N, 3)``, any length > 0) are estimated when missing or when ``reestimate_normals``, facing each
    cloud's sensor where one is known. ``viewpoints``: where the sensors stood: ``"auto"`` (the caller's origin when
    both clouds lie 2-100 radii from it, for the normals, and when both look taken from it, for the free-space
    check), ``"origin"`` (each cloud in its sensor's frame), ``"none"`` (no sensor: closed objects), or
    ``(source, reference)``, each a ``(3,)`` position in its cloud's coordinates, ``None``, or one of those words
    as :func:`rpmnet_jax.geometry.sensors.positions` reads it for one scan (there ``"auto"`` is the scan sets' rule:
    the origin when the cloud surrounds it or its spacing grows with the distance from it). With both sensors
    known, an answer that puts one cloud in the space the other's sensor saw through loses to a candidate that does
    not (else it is ``likely_wrong``).
    ``checkpoint``: orbax dir, ``.npz`` or official ``.pth``; default the shipped model (or pass ``params``).
    The rest is in options objects (:mod:`rpmnet_jax.pairwise.options`): ``network_options`` what the network sees
    (points per cloud, sampling, centring, iterations), ``refine_options`` the ICP's sample size and stopping,
    ``global_options`` the classical hypotheses, the rotation hypotheses, their screening and ``auto``'s bars.
    Deterministic for a ``seed``.
    """
    options_lib.check(init, refine, max_correspondence_distance, network_options, refine_options, global_options)
    net = network_options
    clock = stopwatch.Stopwatch()
    with clock.stage("prepare"):  # 1. what every later stage needs, made once
        inputs = prepare.for_alignment(
            src_points, ref_points, src_normals, ref_normals, num_points=net.points, sampling=net.sampling, seed=seed,
            reestimate_normals=reestimate_normals, centering=net.centering,
            icp=refine == "icp", dense_points=refine_options.points if (refine == "icp" or init != "local") else None,
            max_correspondence_distance=max_correspondence_distance, relative_distance=DEFAULT_RELATIVE_DISTANCE,
            viewpoints=viewpoints)
        free_space = _free_space(inputs)  # scans taken from known sensors: what each sensor saw, made once
    if params is None and checkpoint is not None:  # a caller's checkpoint is checked (and refused) up front
        params = loading.load_params(checkpoint)
    search = _Search(inputs, clock, refine, refine_options, global_options, cfg or config_lib.RPMNetConfig(), params,
                     seed)
    opts = global_options  # 2-3. starts, each refined and scored as it comes (auto: pairwise.auto decides)
    found = search.classical(init) if init != "local" else []
    if init == "auto" and auto.keeps_classical(found, starts_lib.dense(inputs.pair), opts):
        return _report(inputs, search.select(found), src_points, clock, free_space)
    if init == "auto" and found and auto.may_stand(opts) and auto.weak(found, opts):
        classical_answer = _report(inputs, search.select(found), src_points, clock, free_space)
        if auto.stands(classical_answer, opts):
            return classical_answer
    if init == "local" or (init == "auto" and auto.runs("network", found, opts)):
        found += search.local(net.iters)
    if init == "global" or (init == "auto" and auto.runs("global", found, opts)):
        found += search.global_search()
    # 4-5. select the distinct answers, best first; report in the caller's units, on the full clouds
    return _report(inputs, search.select(found), src_points, clock, free_space)


class _Search:
    """The starts of one :func:`align` call, each refined as it comes (step 2–3), and the final selection."""

    def __init__(self, inputs, clock, refine, refine_options, global_options, cfg, params, seed):
        self.inputs, self.clock, self.refine, self.refine_options = inputs, clock, refine, refine_options
        self.opts, self.cfg, self._params, self.seed = global_options, cfg, params, seed

    def params(self):
        """The network's parameters: the shipped model is loaded when the network runs (a classical answer never
        reads it)."""
        self._params = self._params if self._params is not None else loading.load_params(None)
        return self._params

    def refined(self, starts, strong: float = 1.0) -> list:
        with self.clock.stage("refine"):
            return candidates_lib.refine_starts(starts, self.inputs.dense, self.inputs.max_distance_unit, self.refine,
                                                self.refine_options, strong)

    def classical(self, init: str) -> list:
        """FPFH + RANSAC hypotheses refined (the identity for ``classical``/``global`` when there are none; auto
        ends a candidate's refinement early below a strong one's)."""
        starts = []
        if self.opts.classical:
            with self.clock.stage("classical"):
                starts = starts_lib.classical_starts(self.inputs.pair, self.opts.classical, self.seed)
        if not starts and init in ("classical", "global"):  # no hypothesis: the clouds as they lie
            starts = [starts_lib.identity_start()]
        return self.refined(starts, self.opts.network_fitness if init == "auto" else 1.0) if starts else []

    def local(self, num_iters: int) -> list:
        """The network from the identity, refined."""
        with self.clock.stage("network"):
            start = starts_lib.local_start(self.params(), self.inputs.pair, self.cfg, num_iters)
        return self.refined([start])

    def global_search(self) -> list:
        """The network from the rotation hypotheses, screened, the best refined (as they are with refine none)."""
        with self.clock.stage("global"):
            screened = global_search.screen_hypotheses(self.params(), self.inputs.pair, self.inputs.dense, self.cfg,
                                                       self.opts, self.inputs.max_distance_unit, self.seed)
        if self.refine != "icp":
            screened = [s._replace(transform=s.network_transforms[-1]) for s in screened]
        return self.refined(screened)

    def select(self, found: list) -> candidates_lib.Selection:
        """The distinct answers, best first, the best one's refinement finished."""
        with self.clock.stage("refine"):
            return candidates_lib.select(found, self.inputs.dense, self.inputs.max_distance_unit, self.refine,
                                         self.refine_options)


def _report(inputs: prepare.Inputs, selection: candidates_lib.Selection, src_points,
            clock: stopwatch.Stopwatch, free_space) -> Alignment:
    """The :class:`Alignment` of the best selected candidate, in the caller's units and rows: its fitness, RMSE and
    correspondences on the full clouds and the point-to-plane information over them (the reference's normals
    where the caller gave none: those the dense samples estimated, and the missing rows)."""
    selection, blocked = _clear_of_free_space(inputs, selection, free_space)
    pair, best = inputs.pair, selection.ranked[0]
    answers = tuple(Answer(pair.to_callers_units(c.transform[:3]), float(c.score[0]), float(c.score[1]),
                           -float(c.score[2]) * pair.scale, c.init, tuple(support))
                    for c, support in zip(selection.ranked, selection.support or [()] * len(selection.ranked)))
    transform = answers[0].transform
    with clock.stage("score"):
        s = scoring.evaluate_registration(pair.src, pair.ref, transform, inputs.max_distance,
                                          ref_tree=inputs.ref_tree)
        normals = np.zeros_like(pair.ref)
        paired = np.unique(s.correspondences[:, 1])
        normals[paired] = inputs.ref_normals(paired)
        information = scoring.plane_fit(pair.src, pair.ref, normals, transform, s.correspondences).information
    aligned = se3.apply(transform, np.asarray(src_points, np.float64))  # every row of the caller's
    rows = np.stack([pair.src_rows[s.correspondences[:, 0]], pair.ref_rows[s.correspondences[:, 1]]], 1)
    a = Alignment(transform, aligned, pair.to_callers_units(best.network_transforms), best.confidence,
                  (len(pair.samples[0]), len(pair.samples[1])), s.fitness, s.inlier_rmse, rows, best.converged,
                  best.num_iterations, inputs.max_distance, best.init, clock.timings(), answers,
                  selection.ambiguous, information)
    p, likely = doubt.p_wrong(a)  # 6. how likely the answer is wrong: read off it, never changes it
    return a._replace(p_wrong=p, likely_wrong=likely or blocked)


def _free_space(inputs: prepare.Inputs) -> tuple | None:
    """``(src grid, ref grid, their range images)`` when both clouds' sensors are known: the caller's, else (``"auto"``)
    their frame origins when both clouds look taken from there by their spacing
    (:func:`rpmnet_jax.geometry.sensors.taken_from` without the surround rule, which a whole object centred on its
    origin can meet: scanner stations, RGB-D frames, full-density sweeps); else None. On a voxel grid of
    ``FREE_SPACE_CELL`` (space weighed evenly: a scanner's dense floor around it would dilute the share)."""
    pair, origin = inputs.pair, np.zeros(3)
    if pair.sensors is not None:
        seen_from = pair.sensors
    elif (sensors.taken_from(pair.src, origin, surround=False)
          and sensors.taken_from(pair.ref, origin, surround=False, tree=inputs.ref_tree)):
        seen_from = (origin, origin)
    else:
        return None
    if seen_from[0] is None or seen_from[1] is None:
        return None
    cell = FREE_SPACE_CELL * inputs.max_distance
    src, ref = (sampling_lib.voxel_downsample(c, None, cell)[0] for c in (pair.src, pair.ref))
    return src, ref, visibility.range_image(src, seen_from[0]), visibility.range_image(ref, seen_from[1])


def _clear_of_free_space(inputs: prepare.Inputs, selection: candidates_lib.Selection, free_space) -> tuple:
    """With ``free_space`` (:func:`_free_space`): the selection of the candidates that keep each cloud out of the
    space the other's sensor saw through (:mod:`rpmnet_jax.geometry.visibility`), best first, their ambiguity
    measured among themselves: an answer that puts one cloud where the other's sensor saw through (a room's half
    turn puts its furniture there) is no rival, and the doubt model (step 6) does not count it as one. When no
    candidate keeps out, the selection as it is and True (the answer is then reported ``likely_wrong``).
    Otherwise (no free space known) the selection as it is, and False."""
    if free_space is None:
        return selection, False
    src, ref, src_image, ref_image = free_space
    margin = visibility.margin(FREE_SPACE_CELL * inputs.max_distance)
    clear = [visibility.violation(src, src_image, ref, ref_image, inputs.pair.to_callers_units(c.transform[:3]),
                                  margin)
             <= visibility.MAX_FREE_SPACE_SHARE for c in selection.ranked]
    if not any(clear):
        return selection, True
    keep = [i for i, ok in enumerate(clear) if ok]
    ranked = [selection.ranked[i] for i in keep]
    support = tuple(selection.support[i] for i in keep) if selection.support else selection.support
    return candidates_lib.Selection(ranked, candidates_lib.is_ambiguous(ranked), support), False
