"""Many scans into one frame: pairwise registration, a robust pose graph on SE(3), a final refinement.

Options: :class:`~rpmnet_jax.multiway.options.ScanOptions`.

0. every scan moved by one common shift near the origin (:mod:`rpmnet_jax.geometry.offsets`: whole units, float64),
   so that scans in a national grid are registered as near the origin; the answers are moved back;
1. prepare: each scan cleaned, voxel-downsampled (``voxel_size``, default a share of the median robust scan
   radius: 2% for objects, 1% for scans seen from inside a scene; every other size a multiple of the voxel,
   :mod:`rpmnet_jax.multiway.sizes`), normals averaged per voxel when given, else estimated (PCA) on the
   downsampled scan and facing its sensor where one is known (else away from its centroid);
2. pair edges: the candidate pairs are every pair up to ``all_pairs_up_to`` scans, else each scan with its
   ``neighbours`` best partners by a cheap overlap estimate (a bag of FPFH words per scan) plus a spanning tree
   of those scores (:mod:`rpmnet_jax.multiway.candidate_pairs`: O(S·k) pairs whatever the file order). Each is
   registered by FPFH + RANSAC on keypoints one per cube of 2 voxels (each one's FPFH from its neighbours in the
   whole scan, computed once per scan) and from the
   identity (scans that come in roughly one frame), each answer refined by a short point-to-plane ICP; the
   candidate pairs those leave between separate groups of scans go through the network from the identity as in
   :func:`rpmnet_jax.align` (``init="local"``), in batched calls, then the same short ICP (with
   ``classical=False``, every candidate pair does). An answer is an edge when its fitness is at least
   ``min_fitness`` and its median point-to-plane distance at most ``max_plane_residual`` × the correspondence
   distance; a pair's distinct answers (a symmetric shape's flip) all go to the graph, each classical answer with
   its ``p_wrong`` from the edge doubt model (:mod:`rpmnet_jax.multiway.edge_doubt`; with
   ``edge_doubt="reject"``, those at ``p_wrong`` ≥ its ``reject_threshold`` stay out). On the 10 bunny scans the
   classical edges connect every scan and the network does not run;
3. robust pose graph (:mod:`rpmnet_jax.multiway.pose_graph`: a consensus spanning tree whose edges are ranked by
   fitness × (1 − ``p_wrong``) (``edge_doubt="weigh"``, the default; a symmetric shape's flip often overlaps
   more than the right answer, and its ``p_wrong`` is what tells them apart), GTSAM's
   Levenberg–Marquardt with a Cauchy kernel, edges beyond the χ² bound rejected) over those edges; wrong
   edges (a flipped pair) are rejected. The largest component of the kept edges is placed; its scans whose every
   path to the anchor crosses a kept classical edge with ``p_wrong`` ≥ the model's ``threshold`` (0.5: more likely
   wrong than right) are reported in ``likely_wrong``;
4. global: each scan outside it is registered onto the merged, placed scans by :func:`rpmnet_jax.align` with
   ``init="global"`` (rotation hypotheses covering every orientation, one batched call); placed when its
   fitness is at least ``min_fitness``, else left out with a warning (it overlaps nothing); a placement
   ``align`` flags ``likely_wrong`` (:mod:`rpmnet_jax.pairwise.doubt`) is reported in ``likely_wrong`` (the
   robust graph, not the flag, decides which edges stay);
5. refine: every placed pair predicted to overlap by ``min_overlap`` at the current poses takes part:
   ``refine="joint"`` (default) moves all poses together on their points (multi-view point-to-plane,
   :mod:`rpmnet_jax.multiway.joint_refine`), then measures each pair as an edge; ``refine="icp"`` gives each
   an ICP edge from the current poses on up to ``refine_points`` points, and the robust pose graph of those
   edges gives the poses (``refine_rounds`` times).

Edge noise: an edge's covariance is the inverse of its point-to-plane information plus a floor of
``edge_sigma_deg`` (rotation) and ``edge_sigma_fraction × max_correspondence_distance`` (translation) per
axis: correlated pairs of neighbouring points and the registration's own bias make the raw information
overconfident, and the floor is what the χ² bound that rejects edges is measured against.
"""

from __future__ import annotations

import itertools
import warnings
from typing import NamedTuple

import numpy as np

from rpmnet_jax import config as config_lib, stopwatch
from rpmnet_jax.geometry import cloud, normals as normals_lib, offsets, sampling, scoring, threads, visibility
from rpmnet_jax.multiway import candidate_pairs, edge_doubt, edges as edges_lib, joint_refine, options as options_lib
from rpmnet_jax.multiway import pair_engine, pose_graph, sizes
from rpmnet_jax.ops import se3
from rpmnet_jax.pairwise import alignment
from rpmnet_jax.weights import loading

MIN_VOXEL_POINTS = 16  # a scan with fewer points after voxel downsampling is too coarse to register
FREE_SPACE_MARGIN = 2.0  # the free-space check's margin, × the correspondence distance (noise, the bins' spread)
NETWORK_ICP_POINTS = 1500  # the short ICP of a pair edge (icp.NETWORK_EDGE), source points per candidate pair
NETWORK_NOISE_SCALE = 3.0  # the pair edges' short ICP is coarser: their noise floor is this many times larger


class LeftOutWarning(UserWarning):
    """Scans were left out of the answer (they overlap no other scan, or no edge of theirs is consistent)."""


class ScanAlignment(NamedTuple):
    poses: np.ndarray  # (S, 4, 4): scan → the first placed scan's frame (scan 0 unless left out); NaN if left out
    edges: tuple  # Edge of the final pose graph (kept by the robust optimisation)
    rejected: tuple  # Edge the robust optimisation rejected: among the pair edges and the final ones
    left_out: tuple  # indices of scans that overlap none of the placed ones (poses NaN)
    voxel_size: float  # caller's units
    max_correspondence_distance: float  # caller's units
    timings: dict  # seconds per stage that ran: prepare, candidates, classical, network (each with its short ICP),
    # graph, global, refine; total
    likely_wrong: tuple = ()  # placed scans whose pose rests on a likely wrong pair edge (step 3) or whose placement
    # by ``align`` (step 4) was flagged ``likely_wrong``
    pairs: dict = {}  # pairs registered per stage: classical, network, global (placements), refine (pairs refined)


def _candidate_pairs(scans, all_pairs_up_to: int, neighbours: int, seed: int) -> list:
    """``[(i, j), ...]``, ``i < j``: every pair up to ``all_pairs_up_to`` scans, else each scan with its
    ``neighbours`` best partners by the bag-of-words overlap score and a spanning tree of those scores
    (:mod:`rpmnet_jax.multiway.candidate_pairs`), whatever the order of the scans."""
    if len(scans) <= all_pairs_up_to:
        return list(itertools.combinations(range(len(scans)), 2))
    return candidate_pairs.select_pairs(candidate_pairs.overlap_scores(scans, seed=seed), neighbours)


class Prepared(NamedTuple):
    scans: list  # edges.Scan of each scan, moved by -shift
    voxel: float  # caller's units
    sensors: list  # each scan's sensor (3,) in the moved frame, or None
    scene: bool  # scans seen from inside a scene (sizes.voxel)


def _prepare_scans(clouds, normals, voxel_size, shift=np.zeros(3), viewpoints="auto") -> Prepared:
    """The cleaned scans moved by ``-shift``, voxel-downsampled, with normals (the caller's, else estimated, facing
    each scan's sensor where :func:`rpmnet_jax.multiway.sizes.sensors` knows it) and features."""
    if len(clouds) < 2:
        raise ValueError(f"need at least two scans, got {len(clouds)}")
    normals = [None] * len(clouds) if normals is None else list(normals)
    if len(normals) != len(clouds):
        raise ValueError(f"got {len(normals)} normal arrays for {len(clouds)} scans")
    cleaned = [cloud.clean_cloud(f"scan {i}", c, n)[:2] for i, (c, n) in enumerate(zip(clouds, normals))]
    seen_from = [None if v is None else v - shift for v in sizes.sensors([p for p, _ in cleaned], viewpoints)]
    cleaned = [(p - shift, n) for p, n in cleaned]  # float64: the shift loses nothing
    voxel, scene = sizes.voxel([p for p, _ in cleaned], seen_from, voxel_size)
    scans = []
    for i, ((p, n), sensor) in enumerate(zip(cleaned, seen_from)):
        p, n = sampling.voxel_downsample(p, n, voxel)
        if len(p) < MIN_VOXEL_POINTS:
            raise ValueError(f"scan {i}: {len(p)} points after voxel downsampling at {voxel:.4g}; "
                             "a smaller voxel size is needed")
        if n is None:
            n = normals_lib.estimate_normals(p) if sensor is None else normals_lib.facing(p, sensor)
        scans.append(edges_lib.make_scan(p, n, sizes.FEATURE_VOXELS * voxel, voxel, seed=i))
    return Prepared(scans, voxel, seen_from, scene)


def _screened(answers_per_pair, max_dist: float, good, reject: bool, visible=None):
    """Step 2's classical answers of each pair through the edge doubt model: (the good answers of each pair,
    less those with ``p_wrong ≥ reject_threshold`` when ``reject`` and those ``visible(edge)`` refuses (an
    answer that puts one scan in the space the other's sensor saw through); ``{id(edge): p_wrong}`` of those)."""
    model = edge_doubt.load()
    found, p_of = [], {}
    for answers, p in zip(answers_per_pair, edge_doubt.p_wrong_of_pairs(answers_per_pair, max_dist, model)):
        kept = [(e, float(q)) for e, q in zip(answers, p) if good(e) and not (reject and q >= model.reject_threshold)
                and (visible is None or visible(e))]
        found.append([e for e, _ in kept])
        p_of.update((id(e), q) for e, q in kept)
    return found, p_of


def _free_space_check(scans, sensors, max_dist):
    """``visible(edge) -> bool``: whether the edge keeps each scan out of the other's free space
    (:mod:`rpmnet_jax.geometry.visibility`); edges between scans without known sensors pass."""
    images = {}

    def image(k):
        if k not in images:
            images[k] = visibility.range_image(scans[k].points, sensors[k])
        return images[k]

    def visible(e) -> bool:
        if sensors[e.source] is None or sensors[e.target] is None:
            return True
        return visibility.violation(scans[e.source].points, image(e.source), scans[e.target].points,
                                    image(e.target), e.transform, FREE_SPACE_MARGIN * max_dist
                                    ) <= visibility.MAX_FREE_SPACE_SHARE
    return visible


def _resting_on_doubt(num_scans: int, kept_edges, p_of: dict, anchor: int, threshold: float | None = None) -> list:
    """The scans whose every path to ``anchor`` over ``kept_edges`` crosses one with ``p_wrong`` (``p_of``, by
    ``id``; edges not in it are not flagged) at or above ``threshold`` (default the edge doubt model's)."""
    threshold = edge_doubt.load().threshold if threshold is None else threshold
    flagged = [p_of.get(id(e), 0.0) >= threshold for e in kept_edges]
    pairs = [(e.source, e.target) for e in kept_edges]
    return np.flatnonzero(edge_doubt.resting_on_flagged(num_scans, pairs, flagged, anchor)).tolist()


def _edge_information(info: np.ndarray, rot_sigma: float, trans_sigma: float) -> np.ndarray:
    """``(inv(info) + C)⁻¹`` with ``C`` the diagonal floor, computed without inverting a singular ``info``."""
    c_inv = np.diag([rot_sigma ** -2] * 3 + [trans_sigma ** -2] * 3)
    return c_inv - c_inv @ np.linalg.solve(info + c_inv, c_inv)


def _doubt_weights(edges, p_of: dict) -> list:
    """``[fitness × (1 − p_wrong), ...]`` of ``edges`` (``p_of``: by ``id``; edges not in it count as sure)."""
    return [e.fitness * (1.0 - p_of.get(id(e), 0.0)) for e in edges]


def _solve(num_scans, edges, anchor, noise, seed, weights=None):
    """Robust pose graph of ``edges``, its consensus ranking them by ``weights`` (default their fitness): (poses,
    NaN off the anchor's component of the kept edges; kept edges of that component; rejected edges)."""
    pairs = [(e.source, e.target) for e in edges]
    used = pose_graph.component(num_scans, pairs, anchor)
    info = [_edge_information(e.information, *noise) for e in edges]
    sol = pose_graph.optimize(num_scans, pairs, [e.transform for e in edges], info, anchor,
                              weights=[e.fitness for e in edges] if weights is None else weights, seed=seed)
    rejected = [e for e, ok in zip(edges, sol.inlier) if used[e.source] and not ok]
    kept = [e for e, ok in zip(edges, sol.inlier) if ok]
    nodes = pose_graph.component(num_scans, [(e.source, e.target) for e in kept], anchor)
    poses = np.where(nodes[:, None, None], sol.poses, np.nan)
    return poses, [e for e in kept if nodes[e.source]], rejected


def _largest_component(num_scans, edges):
    """The first scan of the largest connected component of ``edges``."""
    labels = pose_graph.components(num_scans, [(e.source, e.target) for e in edges])
    return int(np.argmax(labels == np.argmax(np.bincount(labels))))


def _merged(scans, poses, placed, voxel):
    points = np.concatenate([se3.apply(poses[s], scans[s].points) for s in placed])
    points, _ = sampling.voxel_downsample(points, None, voxel)
    return points, normals_lib.estimate_normals(points)


def _place_remaining(scans, poses, params, cfg, voxel, max_dist, accept, seed, tick):
    """Step 4: registers each unplaced scan onto the merged placed ones (``align``, ``init="global"``), in
    index order, merging again after each success (``tick(placed, scans)`` then). Returns (poses, placement
    edges, scans still pending, placed scans whose ``align`` answer was ``likely_wrong``)."""
    placed = [s for s in range(len(scans)) if np.isfinite(poses[s, 0, 0])]
    pending = [s for s in range(len(scans)) if s not in placed]
    edges, doubtful = [], []
    grew = True
    while pending and grew:
        grew = False
        model, model_normals = _merged(scans, poses, placed, voxel)
        for s in pending:
            a = alignment.align(scans[s].points, model, scans[s].normals, model_normals, params=params, cfg=cfg,
                                init="global", max_correspondence_distance=max_dist, seed=seed)
            residuals = scoring.plane_fit(scans[s].points, model, model_normals, a.transform,
                                          a.correspondences).residuals
            if accept(a.fitness, np.median(np.abs(residuals)) if len(residuals) else np.inf):
                poses[s] = a.transform
                doubtful += [s] if a.likely_wrong else []  # reported; the robust graph still decides on the edges
                edges += [edges_lib.measure(scans, s, o, np.linalg.inv(poses[o]) @ poses[s], max_dist, "global")
                          for o in placed]
                placed.append(s)
                pending.remove(s)
                tick(len(placed), len(scans))
                grew = True
                break  # the model grew: merge again before the next scan
    return poses, edges, pending, doubtful


def _overlapping_pairs(scans, poses, placed, max_dist, min_overlap, neighbours=None) -> list:
    """``[(i, j), ...]``, ``i < j``: the placed pairs predicted to overlap by ``min_overlap`` at ``poses`` (the
    pairs whose bounding spheres lie apart are not looked at); with ``neighbours``, of those only each scan's
    ``neighbours`` most overlapping ones (their union)."""
    means = {s: scans[s].points.mean(axis=0) for s in placed}  # each scan's centre in its own frame
    centres = {s: se3.apply(poses[s], means[s][None])[0] for s in placed}
    radii = {s: float(np.max(np.linalg.norm(scans[s].points - means[s], axis=1))) for s in placed}
    near = [(i, j) for i, j in itertools.combinations(sorted(placed), 2)
            if np.linalg.norm(centres[i] - centres[j]) <= radii[i] + radii[j] + max_dist]
    overlap = {(i, j): edges_lib.predicted_overlap(scans, i, j, np.linalg.inv(poses[j]) @ poses[i], max_dist)
               for i, j in near}
    pairs = [p for p in near if overlap[p] >= min_overlap]
    if neighbours is None:
        return pairs
    best = set()
    for s in placed:
        mine = sorted((p for p in pairs if s in p), key=lambda p: -overlap[p])
        best.update(mine[:neighbours])
    return sorted(best)


def _refine_round(engine, scans, poses, placed, max_dist, min_overlap, keep, round_, tick):
    """Step 5, one round: an ICP edge from the current poses for every placed pair predicted to overlap, run by
    ``engine`` (``tick(done, total)`` as they finish): (the edges ``keep`` accepts, the number of pairs)."""
    pairs = _overlapping_pairs(scans, poses, placed, max_dist, min_overlap)
    starts = [np.linalg.inv(poses[j]) @ poses[i] for i, j in pairs]
    return [e for e in engine.refine_edges(pairs, starts, round_, tick) if keep(e)], len(pairs)


def _refine_jointly(scans, poses, placed, max_dist, o, keep, tick):
    """Step 5 with ``refine="joint"``: the overlapping pairs' points refine all poses together
    (:mod:`rpmnet_jax.multiway.joint_refine`); then each pair measured: (poses, kept edges, the other edges)."""
    pairs = _overlapping_pairs(scans, poses, placed, max_dist, o.min_overlap, o.refine_neighbours)
    poses = joint_refine.refine_jointly(scans, poses, pairs, max_dist, min(placed), seed=o.seed, tick=tick).poses
    measured = [edges_lib.measure(scans, i, j, np.linalg.inv(poses[j]) @ poses[i], max_dist, "joint")
                for i, j in pairs]
    return poses, [e for e in measured if keep(e)], [e for e in measured if not keep(e)]


def align_scans(clouds, normals=None, *, viewpoints="auto",
                options: options_lib.ScanOptions = options_lib.ScanOptions(), params=None,
                checkpoint=None, cfg: config_lib.RPMNetConfig | None = None, progress=None, scheduler=None,
                cache=None) -> ScanAlignment:
    """Registers the scans ``clouds[i] (N_i, 3)`` (normals ``(N_i, 3)`` optional, per scan) into the frame of
    the first one; see the module docstring and :class:`~rpmnet_jax.multiway.options.ScanOptions`.
    ``viewpoints``: where each scan's sensor stood (:mod:`rpmnet_jax.multiway.sizes`): ``"auto"`` (a frame origin
    that its scan surrounds, as a LiDAR sweep's does), ``"origin"``, ``"none"`` or one ``(3,)`` (or ``None``) per
    scan in its own coordinates; estimated normals face it, and scans seen from inside get a scene's voxel.
    ``checkpoint``: as :func:`rpmnet_jax.align`'s (default the shipped model, or pass ``params``).
    ``progress``: called as ``progress(stage, done, total)`` as the long stages advance (a CLI draws bars).
    ``scheduler``: where the pair registrations run (:mod:`rpmnet_jax.multiway.pair_engine`): ``None`` this
    process, ``"local"`` or a worker count an embedded Dask ``LocalCluster``, ``"tcp://HOST:8786"`` a running
    Dask scheduler (or a ``distributed.Client``); the same poses on each. ``cache``: a folder (or
    :class:`~rpmnet_jax.multiway.pair_cache.PairCache`) keeping every finished pair result; a run again with
    the same scans, options and cache reuses them."""
    if not isinstance(options, options_lib.ScanOptions):
        raise ValueError(f"options must be a ScanOptions, got {type(options).__name__}")
    with threads.compiled_loops(), pair_engine.PairEngine(scheduler, cache) as engine:
        return _align_scans(engine, clouds, normals, viewpoints, options, params, checkpoint, cfg, progress)


def _align_scans(engine, clouds, normals, viewpoints, o, params, checkpoint, cfg, progress) -> ScanAlignment:

    def ticker(stage):
        """``tick(done, total)`` of ``stage``: passed on to ``progress``, if any."""
        return lambda done, total: progress(stage, done, total) if progress is not None else None

    clock = stopwatch.Stopwatch()
    with clock.stage("prepare"):
        shift = offsets.common_shift(clouds)  # every estimate is made near the origin, then moved back
        scans, voxel, seen_from, scene = _prepare_scans(clouds, normals, o.voxel_size, shift, viewpoints)
        plane_bar = o.max_plane_residual if o.max_plane_residual is not None else sizes.plane_residual(scene)
        num_scans = len(scans)
        max_dist = (float(o.max_correspondence_distance) if o.max_correspondence_distance is not None
                    else sizes.DISTANCE_VOXELS * voxel)
        noise = (np.radians(o.edge_sigma_deg), o.edge_sigma_fraction * max_dist)
        network_noise = tuple(NETWORK_NOISE_SCALE * x for x in noise)
        if params is None and checkpoint is not None:  # a caller's checkpoint is checked (and refused) up front
            params = loading.load_params(checkpoint)
        cfg = cfg or config_lib.RPMNetConfig()
        engine.bind(scans, params, cfg, pair_engine.Settings(
            max_dist, o.num_points, o.num_iters, o.batch_size, NETWORK_ICP_POINTS, o.refine_points, o.seed,
            sizes.RANSAC_VOXELS * voxel, plane_bar, all(v is None for v in seen_from)))

    def good(e, fitness):
        return e.fitness >= fitness and e.plane_residual <= plane_bar * max_dist

    counts, p_of = {}, {}
    with clock.stage("candidates"):
        pairs = _candidate_pairs(scans, o.all_pairs_up_to, o.neighbours, o.seed)
    edges, weak = [], pairs  # without classical edges, every candidate pair goes through the network
    if o.classical:
        with clock.stage("classical"):  # 2. every candidate pair: FPFH + RANSAC, a short ICP; the edge doubt
            found, p_of = _screened(engine.classical_edges(pairs, ticker("classical edges")), max_dist,
                                    lambda e: good(e, o.min_fitness), o.edge_doubt == "reject",
                                    _free_space_check(scans, seen_from, max_dist))
            counts["classical"] = len(pairs)
            edges = [e for answers in found for e in answers]  # a symmetric pair's answers: the graph chooses
        labels = pose_graph.components(num_scans, [(e.source, e.target) for e in edges])
        weak = [p for p, answers in zip(pairs, found) if not answers and labels[p[0]] != labels[p[1]]]
    if weak:
        with clock.stage("network"):  # the pairs left between components: the network from the identity
            edges += [e for e in engine.network_edges(weak, ticker("network edges")) if good(e, o.min_fitness)]
            counts["network"] = len(weak)

    rejected, resting = [], []  # 3. robust pose graph over them: the largest consistent component is placed
    poses = np.full((num_scans, 4, 4), np.nan)
    poses[0] = np.eye(4)
    if edges:
        with clock.stage("graph"):
            anchor = _largest_component(num_scans, edges)
            poses, edges, rejected = _solve(num_scans, edges, anchor, network_noise, o.seed,
                                            None if o.edge_doubt == "off" else _doubt_weights(edges, p_of))
            resting = _resting_on_doubt(num_scans, edges, p_of, anchor)

    global_edges, doubtful = [], []
    pending = [s for s in range(num_scans) if not np.isfinite(poses[s, 0, 0])]
    if pending:  # 4. the other scans: global registration onto the merged placed scans
        with clock.stage("global"):
            params = params if params is not None else loading.load_params(None)
            poses, global_edges, pending, doubtful = _place_remaining(
                scans, poses, params, cfg, voxel, max_dist, seed=o.seed, tick=ticker("placing the other scans"),
                accept=lambda fitness, residual: (fitness >= o.min_fitness
                                                  and residual <= plane_bar * max_dist))
            counts["global"] = len(global_edges)
            global_edges = [e for e in global_edges if good(e, o.min_overlap)]

    # 5. refinement rounds (or, without, one graph of the pair and placement edges, at the pair edges' noise)
    placed = [s for s in range(num_scans) if np.isfinite(poses[s, 0, 0])]
    final_edges, final_rejected = edges + global_edges, []
    for r in range(o.refine_rounds if o.refine == "icp" and len(placed) > 1 else 0):
        with clock.stage("refine"):
            round_edges, registered = _refine_round(engine, scans, poses, placed, max_dist, o.min_overlap,
                                                    lambda e: good(e, o.min_overlap), r,
                                                    ticker(f"refinement round {r + 1}"))
            counts["refine"] = counts.get("refine", 0) + registered
            if not round_edges:
                break
            poses, final_edges, final_rejected = _solve(num_scans, round_edges, min(placed), noise, o.seed)
        dropped = [s for s in placed if not np.isfinite(poses[s, 0, 0])]
        if dropped:
            warnings.warn(f"scans {dropped}: no edge consistent with the others after refinement; left out",
                          LeftOutWarning, stacklevel=3)
            placed = [s for s in placed if s not in dropped]
    if o.refine == "joint" and len(placed) > 1:
        with clock.stage("refine"):
            poses, final_edges, final_rejected = _refine_jointly(scans, poses, placed, max_dist, o,
                                                                 lambda e: good(e, o.min_overlap),
                                                                 ticker("joint refinement stages"))
            counts["refine"] = len(final_edges) + len(final_rejected)
    if o.refine == "none" and global_edges:
        with clock.stage("graph"):
            poses, final_edges, final_rejected = _solve(num_scans, final_edges, min(placed), network_noise, o.seed)

    if pending:
        warnings.warn(f"scans {pending} overlap none of the placed scans (no registration onto them reached "
                      f"fitness {o.min_fitness} with coinciding surfaces); left out", LeftOutWarning, stacklevel=3)
    left_out = tuple(s for s in range(num_scans) if not np.isfinite(poses[s, 0, 0]))
    first = min(s for s in range(num_scans) if s not in left_out)
    poses = offsets.unshift_transforms(np.linalg.inv(poses[first]) @ poses, shift)  # NaN rows stay NaN
    return ScanAlignment(poses, _unshifted(final_edges, shift), _unshifted(rejected + final_rejected, shift), left_out,
                         voxel, max_dist, clock.timings(), tuple(sorted(set(resting + doubtful) - set(left_out))),
                         counts)


def _unshifted(edges, shift) -> tuple:
    """``edges`` between the scans moved by ``-shift`` → the same edges between the caller's frames."""
    return tuple(e._replace(transform=offsets.unshift_transforms(e.transform, shift),
                            information=offsets.unshift_information(e.information, shift)) for e in edges)
