"""Many scans into one frame: pairwise registration, a robust pose graph on SE(3), a final refinement.

Options: :class:`~rpmnet_jax.multiway.options.ScanOptions`. :func:`align_scans` runs the steps below as stages of
one run state (:class:`_Run`); each step's work lives in its own module.

0. every scan moved by one common shift near the origin (:mod:`rpmnet_jax.geometry.offsets`: whole units, float64),
   so that scans in a national grid are registered as near the origin; the answers are moved back;
1. prepare (:mod:`rpmnet_jax.multiway.preparation`): each scan cleaned, voxel-downsampled (``voxel_size``, default a share of the median robust scan
   radius: 2% for objects, 1% for scans seen from inside a scene; every other size a multiple of the voxel,
   :mod:`rpmnet_jax.multiway.sizes`), normals averaged per voxel when given, else estimated (PCA) on the
   downsampled scan and facing its sensor where one is known (else away from its centroid);
2. pair edges (:mod:`rpmnet_jax.multiway.edge_graph`): the candidate pairs are every pair up to ``all_pairs_up_to`` scans, else each scan with its
   ``neighbours`` best partners by a cheap overlap estimate (a bag of FPFH words per scan; for a levelled scene's
   scans, z up with known sensors, the footprints' Radon sinograms, :mod:`rpmnet_jax.multiway.radon_scores`,
   which find the neighbours of a town's stations where the bag of words does not, each scan's best of them
   ordered again by how well the footprints align: :meth:`~rpmnet_jax.multiway.radon_scores.Footprints.ranked`)
   plus a spanning tree
   of those scores (:mod:`rpmnet_jax.multiway.candidate_pairs`: O(S·k) pairs whatever the file order), and where
   those leave separate groups of scans, up to ``BRIDGING_ROUNDS`` rounds of each outside scan's next
   ``neighbours`` partners in other groups. Each is
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
   classical edges connect every scan and the network does not run. In a levelled scene's campaign (footprint
   scores) an edge below ``edge_graph.WEAK_LINK`` × the median balanced fitness of the pair edges is weak;
3. robust pose graph (:mod:`rpmnet_jax.pose_graphs.pose_graph`: a consensus spanning tree whose edges are ranked by
   fitness × (1 − ``p_wrong``) (``edge_doubt="weigh"``, the default; a symmetric shape's flip often overlaps
   more than the right answer, and its ``p_wrong`` is what tells them apart), GTSAM's
   Levenberg–Marquardt with a Cauchy kernel, edges beyond the χ² bound rejected) over those edges; wrong
   edges (a flipped pair) are rejected. A campaign's kept weak edges that alone join scans are rejected too (a
   town's look-alike street matches the ground and little else). The largest component of the kept edges is
   placed; its scans whose every
   path to the anchor crosses a kept classical edge with ``p_wrong`` ≥ the model's ``threshold`` (0.5: more likely
   wrong than right) are reported in ``likely_wrong``. With known sensors the answer is then checked where no
   edge looked (:mod:`rpmnet_jax.multiway.conflicts`): placed scans it puts near one another that stand in each
   other's free space (at ``conflicts.MAX_SHARE``, the bar of poses composed through the graph: a group carries
   its drift) point at suspect edges (every one of a tie); the suspects that are bridges (no cycle confirms
   them: a wrong edge that carried a group of scans onto a look-alike street) are cut, without solving the graph
   again, up to ``MAX_CUTS`` rounds, and the scans they carried go to step 4. In a levelled scene's campaign the
   groups left unplaced are then joined across the cuts (step 3c): up to ``BRIDGING_ROUNDS`` rounds, each
   registering each group's ends (:func:`~rpmnet_jax.multiway.placement.group_ends`: a street's group meets the
   placed streets there) with their next ``neighbours`` placed partners by how well their footprints align
   (:meth:`~rpmnet_jax.multiway.radon_scores.Footprints.aligned`), then placing each
   group where two pair edges from different members to different placed scans agree
   (:func:`~rpmnet_jax.multiway.placement.voted_frame`: one wrong edge puts a group on a look-alike street, two
   rarely agree there); the group is checked where it lands as in 3b (its own edges that conflicts point at are cut
   and the members they carried stay unplaced) and placed where at most ``VOTE_CONFLICTS`` of its members' near
   pairs still conflict;
4. global (:mod:`rpmnet_jax.multiway.placement`): the scans outside it, in groups (those the pair edges join among
   themselves, with their own robust pose graph's relative poses, largest first; then single scans), each
   registered onto the merged, placed scans by :func:`rpmnet_jax.align` with ``init="global"`` (rotation
   hypotheses covering every orientation, one batched call; in a levelled scene's campaign onto its
   ``PLACE_PARTNERS`` best-scored partners that are placed, not every placed scan), a group's members in turn
   until one places it;
   placed when its fitness is at least ``min_fitness``, else left out with a warning (it overlaps nothing); with
   known sensors a group of several is not placed where a member lies in a placed scan's free space, and a single
   scan placed there is reported in ``likely_wrong``, as is a placement ``align`` flags ``likely_wrong``
   (:mod:`rpmnet_jax.pairwise.doubt`; the robust graph, not the flag, decides which edges stay); in a levelled
   scene's campaign neither answer places a scan (it is left out);
5. refine (:mod:`rpmnet_jax.multiway.refinement`): every placed pair predicted to overlap by ``min_overlap`` at the current poses takes part:
   ``refine="joint"`` (default) moves all poses together on their points (multi-view point-to-plane,
   :mod:`rpmnet_jax.pose_graphs.joint_refine`), then measures each pair as an edge; ``refine="icp"`` gives each
   an ICP edge from the current poses on up to ``refine_points`` points, and the robust pose graph of those
   edges gives the poses (``refine_rounds`` times); then placed scans that the final poses put in one another's
   free space, joined by no edge from before the refinement, are reported in ``likely_wrong``.

Edge noise: an edge's covariance is the inverse of its point-to-plane information plus a floor of
``edge_sigma_deg`` (rotation) and ``edge_sigma_fraction × max_correspondence_distance`` (translation) per
axis: correlated pairs of neighbouring points and the registration's own bias make the raw information
overconfident, and the floor is what the χ² bound that rejects edges is measured against.
"""

from __future__ import annotations

import dataclasses
import functools
import warnings
from typing import NamedTuple

import numpy as np

from rpmnet_jax import config as config_lib, memory, stopwatch
from rpmnet_jax.classical import scoring
from rpmnet_jax.geometry import cloud, offsets, threads
from rpmnet_jax.multiway import candidate_pairs, conflicts, edge_graph, options as options_lib, placement, preparation
from rpmnet_jax.pair_edges import pair_engine
from rpmnet_jax.pose_graphs import pose_graph
from rpmnet_jax.multiway import refinement, sizes
from rpmnet_jax.weights import loading

NETWORK_ICP_POINTS = 1500  # the short ICP of a pair edge (icp.NETWORK_EDGE), source points per candidate pair
BRIDGING_ROUNDS = 3  # rounds of classical edges between the groups the candidate pairs left apart, each scan outside
# the largest group with its next `neighbours` best-scored partners in other groups (candidate_pairs.bridging_pairs).
# A town's stations look alike to the bag of words: 30 stations of site seed 0 had 34 of their 46 true neighbour
# pairs (< 15 m) among the candidates; the classical edges of all 435 pairs gave 72 passing answers, all right
# (tuning data: site seed 0)
AGREE_DEG = 1.0  # step 3c: two pair edges place a group alike when their frames differ by at most this (and the
# correspondence distance at the group's centre)
VOTE_CONFLICTS = 0.05  # step 3c: a voted group is placed when at most this share of its members' near pairs still
# conflict after its cuts (site seed 3, tuning data: a group of 299 stations placed right left 1 of 590, one voted
# onto a look-alike street 113 of 119)
MAX_CUTS = 20  # step 3b: rounds of cuts at most (each one check of the conflicts)
PLACE_PARTNERS = 12  # step 4 in a campaign: a scan registered onto its placed partners among this many best-scored
# (the footprints' 6 best hold a site station's nearest one for 96%, radon_scores)
PLACE_TRIES = 3  # ... from at most this many members of a group a round (not compared)
NETWORK_NOISE_SCALE = 3.0  # the pair edges' short ICP is coarser: their noise floor is this many times larger


class LeftOutWarning(UserWarning):
    """Scans were left out of the answer (they overlap no other scan, or no edge of theirs is consistent)."""


class ScanAlignment(NamedTuple):
    poses: np.ndarray  # (S, 4, 4): scan → the first placed scan's frame (scan 0 unless left out); NaN if left out
    edges: tuple  # Edge of the final pose graph (kept by the robust optimisation), each with its p_wrong
    rejected: tuple  # Edge the robust optimisation rejected: among the pair edges and the final ones
    left_out: tuple  # indices of scans that overlap none of the placed ones (poses NaN)
    voxel_size: float  # caller's units (the refinement's, with ScanOptions.refine_voxel_size)
    max_correspondence_distance: float  # caller's units (the same)
    timings: dict  # seconds per stage that ran: prepare, candidates, classical, network (each with its short ICP),
    # graph, global, refine; total
    likely_wrong: tuple = ()  # placed scans whose pose rests on a likely wrong pair edge (step 3) or whose placement
    # by ``align`` (step 4) was flagged ``likely_wrong``
    pairs: dict = {}  # pairs registered per stage: classical, network, global (placements), refine (pairs refined,
    # both passes with refine_voxel_size)


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
    ``scheduler``: where the work on scans and pairs runs (:mod:`rpmnet_jax.pair_edges.pair_engine`: the scans'
    preparation, the pair registrations, the joint refinement's shares): ``None`` this
    process, ``"local"`` or a worker count an embedded Dask ``LocalCluster``, ``"tcp://HOST:8786"`` a running
    Dask scheduler (or a ``distributed.Client``); the same poses on each. ``cache``: a folder (or
    :class:`~rpmnet_jax.pair_edges.pair_cache.PairCache`) keeping every finished pair result; a run again with
    the same scans, options and cache reuses them."""
    if not isinstance(options, options_lib.ScanOptions):
        raise ValueError(f"options must be a ScanOptions, got {type(options).__name__}")
    with threads.compiled_loops(), pair_engine.PairEngine(scheduler, cache) as engine:
        run = _prepare(engine, clouds, normals, viewpoints, options, params, checkpoint, cfg, progress)
        for stage in (_pair_edges, _pose_graph, _place_others, _finer_scans, _refine, _let_go_of_scans,
                      _name_conflicts):
            stage(run)
            run.visible.release_images()  # made again where a later stage checks a scan
            memory.give_back()  # what the stage freed (the network's buffers, the scans let go, the range images)
        return _answer(run)


@dataclasses.dataclass
class _Run:
    """One :func:`align_scans` run: what its stages share, filled in as they go (sizes in the moved frame)."""

    options: options_lib.ScanOptions
    engine: pair_engine.PairEngine
    clock: stopwatch.Stopwatch
    progress: object  # progress(stage, done, total) or None
    shift: np.ndarray  # (3,) the common shift: every estimate is made near the origin, then moved back
    prepared: preparation.Prepared
    max_dist: float  # the correspondence distance
    plane_bar: float  # an accepted edge's median point-to-plane distance, × max_dist
    balance_bar: float  # an accepted pair edge's (and placement's) balanced fitness: 0 but in a scene with ground
    params: object  # the network's parameters (None: loaded when the network first runs)
    cfg: config_lib.RPMNetConfig
    inputs: tuple = ()  # (clouds, normals, viewpoints) as the caller gave them: the refinement's finer scans
    poses: np.ndarray = None  # (S, 4, 4), NaN while a scan is unplaced
    edges: list = dataclasses.field(default_factory=list)  # the edges of the current graph
    pair_edges: list = dataclasses.field(default_factory=list)  # every pair edge, before the pose graph chose
    rejected: list = dataclasses.field(default_factory=list)  # rejected by the pair edges' robust graph
    refine_rejected: list = dataclasses.field(default_factory=list)  # rejected by the final graph or measure
    global_edges: list = dataclasses.field(default_factory=list)  # placement's edges kept
    screened: list = None  # the pair and placement edges kept before the refinement (None: not refined yet)
    pending: list = dataclasses.field(default_factory=list)  # scans placement could not place
    likely_wrong: set = dataclasses.field(default_factory=set)
    scores: np.ndarray = None  # (S, S) a levelled scene's campaign's footprint scores (else None)
    footprints: object = None  # radon_scores.Footprints of a levelled scene's campaign (else None)
    tried: set = dataclasses.field(default_factory=set)  # the pairs registered by the classical edges
    weak_bar: float = 0.0  # a campaign's weak links (edge_graph.WEAK_LINK): 0 where every edge may join scans
    counts: dict = dataclasses.field(default_factory=dict)  # pairs registered per stage
    # visible(edge) -> bool: the free-space check of an edge between scans with known sensors (edge_graph.FreeSpace),
    # on the registration's scans' points, its range images made once a run for the pair edges, the placement and
    # the conflicts (steps 3b, 3c and 5b, at conflicts.MAX_SHARE)
    visible: edge_graph.FreeSpace = None

    @property
    def scans(self) -> list:
        return self.prepared.scans

    @functools.cached_property
    def conflict_reach(self) -> float:
        """Step 3b's reach: ``conflicts.REACH`` × the median robust radius of the registration's scans."""
        return conflicts.REACH * float(np.median([cloud.robust_radius(s.points) for s in self.scans]))

    def ranking(self, edges) -> list:
        """How the robust graph ranks ``edges``: their doubt weights, or their fitness with ``edge_doubt="off"``."""
        return (edge_graph.doubt_weights(edges) if self.options.edge_doubt != "off"
                else [e.fitness for e in edges])

    def solve(self, edges) -> tuple:
        """The robust graph of pair ``edges`` anchored in their largest component, less its weak links
        (:func:`~rpmnet_jax.multiway.edge_graph.without_weak_links` at :attr:`weak_bar`): (poses, kept, rejected,
        the first placed scan)."""
        num_scans = len(self.poses)
        poses, kept, rejected = edge_graph.solve(num_scans, edges, edge_graph.largest_component(num_scans, edges),
                                                 self.noise(NETWORK_NOISE_SCALE), self.options.seed,
                                                 self.ranking(edges))
        if self.weak_bar > 0:
            poses, kept, links = edge_graph.without_weak_links(num_scans, poses, kept, self.weak_bar)
            rejected = rejected + links
        return poses, kept, rejected, int(np.flatnonzero(np.isfinite(poses[:, 0, 0]))[0])

    def noise(self, scale: float = 1.0) -> tuple:
        """The edge noise floor (rotation, translation sigmas), × ``scale``."""
        o = self.options
        return scale * np.radians(o.edge_sigma_deg), scale * (o.edge_sigma_fraction * self.max_dist)

    def good(self, edge, fitness: float, balanced: float = 0.0) -> bool:
        """The rule an edge passes: fitness ≥ ``fitness``, balanced fitness ≥ ``balanced`` and surfaces that
        coincide."""
        return (edge.fitness >= fitness and edge.balanced_fitness >= balanced
                and edge.plane_residual <= self.plane_bar * self.max_dist)

    def pair_edge(self, edge) -> bool:
        """The rule a pair edge passes (found by a search, which may be wrong): :meth:`good` at ``min_fitness`` and
        the balance bar."""
        return self.good(edge, self.options.min_fitness, self.balance_bar)

    def placed(self) -> list:
        return [s for s in range(len(self.poses)) if np.isfinite(self.poses[s, 0, 0])]

    def tick(self, stage: str):
        """``tick(done, total)`` of ``stage`` (:func:`_ticker`)."""
        return _ticker(self.progress, stage)


def _ticker(progress, stage: str):
    """``tick(done, total)`` of ``stage``: passed on to ``progress``, if any."""
    return lambda done, total: progress(stage, done, total) if progress is not None else None


def _prepare(engine, clouds, normals, viewpoints, o, params, checkpoint, cfg, progress) -> _Run:
    """Step 0–1: the common shift, the prepared scans and every size; the engine bound to them."""
    clock = stopwatch.Stopwatch()
    with clock.stage("prepare"):
        shift = offsets.common_shift(clouds)
        prepared = preparation.prepare_scans(clouds, normals, o.voxel_size, shift, viewpoints, engine,
                                             _ticker(progress, "preparing scans"))
        max_dist = (float(o.max_correspondence_distance) if o.max_correspondence_distance is not None
                    else sizes.DISTANCE_VOXELS * prepared.voxel)
        plane_bar = o.max_plane_residual if o.max_plane_residual is not None else sizes.plane_residual(prepared.scene)
        balance_bar = o.min_balanced_fitness if _grounded(prepared) else 0.0
        if params is None and checkpoint is not None:  # a caller's checkpoint is checked (and refused) up front
            params = loading.load_params(checkpoint)
        cfg = cfg or config_lib.RPMNetConfig()
        engine.bind(prepared.scans, params, cfg, pair_engine.Settings(
            max_dist, o.num_points, o.num_iters, o.batch_size, NETWORK_ICP_POINTS, o.refine_points, o.seed,
            sizes.RANSAC_VOXELS * prepared.voxel, plane_bar, all(v is None for v in prepared.sensors)))
    poses = np.full((len(prepared.scans), 4, 4), np.nan)
    poses[0] = np.eye(4)
    return _Run(o, engine, clock, progress, shift, prepared, max_dist, plane_bar, balance_bar, params, cfg,
                (clouds, normals, viewpoints), poses,
                visible=edge_graph.FreeSpace((s.points for s in prepared.scans), prepared.sensors, prepared.voxel))


def _grounded(prepared: preparation.Prepared) -> bool:
    """Whether the scans are a scene's with a ground: seen from inside, and the median scan holds at least
    ``sizes.DOMINANT_SHARE`` of its points in one normal direction (a box seen around holds as much in a face:
    objects never count)."""
    shares = [scoring.dominant_share(s.normals) for s in prepared.scans]
    return bool(prepared.scene and np.median(shares) >= sizes.DOMINANT_SHARE)


def _pair_edges(run: _Run) -> None:
    """Step 2: classical edges of every candidate pair (rated, screened), the network's on the pairs they leave
    between separate groups of scans (on every pair without ``classical``)."""
    o, clock, engine = run.options, run.clock, run.engine
    with clock.stage("candidates"):
        levelled = preparation.levelled(run.prepared)
        pairs, scores, run.footprints = preparation.pairs_to_register(run.scans, o.all_pairs_up_to, o.neighbours,
                                                                      o.seed, levelled)
        run.scores = scores if levelled is not None else None
    weak = pairs
    if o.classical:
        with clock.stage("classical"):

            found = _classical(run, pairs, "classical edges")
            if run.scores is not None:  # a levelled scene's campaign: weak links
                run.weak_bar = edge_graph.weak_bar([e for answers in found.values() for e in answers])
            for r in range(BRIDGING_ROUNDS if scores is not None else 0):  # the groups left apart: next partners
                kept = [(e.source, e.target) for answers in found.values() for e in answers]
                labels = pose_graph.components(len(run.poses), kept)
                more = candidate_pairs.bridging_pairs(scores, labels, found, o.neighbours)
                if not more:
                    break
                found.update(_classical(run, more, f"classical edges between groups, round {r + 1}"))
            run.tried = set(found)
            run.edges = [e for answers in found.values() for e in answers]  # a symmetric pair's answers: the graph
            # chooses
        labels = pose_graph.components(len(run.poses), [(e.source, e.target) for e in run.edges])
        weak = [p for p, answers in found.items() if not answers and labels[p[0]] != labels[p[1]]]
    if weak:
        run.visible.release_images()  # beside the network's runtime: made again for the few edges it finds
        memory.give_back()
        with clock.stage("network"):
            run.edges += [e for e in engine.network_edges(weak, run.tick("network edges"))
                          if run.pair_edge(e) and run.visible(e)]  # the classical edges' free-space check too
            run.counts["network"] = len(weak)


def _classical(run: _Run, pairs, stage: str) -> dict:
    """``{pair: [edge, ...]}``: the classical answers of ``pairs`` that pass (:func:`edge_graph.screened`)."""
    found = edge_graph.screened(run.engine.classical_edges(pairs, run.tick(stage)), run.max_dist, run.pair_edge,
                                run.options.edge_doubt == "reject", run.visible)
    run.counts["classical"] = run.counts.get("classical", 0) + len(pairs)
    return dict(zip(pairs, found))


def _pose_graph(run: _Run) -> None:
    """Step 3: the robust pose graph of the pair edges places the largest consistent component."""
    if not run.edges:
        return
    with run.clock.stage("graph"):
        num_scans = len(run.poses)
        run.pair_edges = list(run.edges)
        run.poses, run.edges, run.rejected, anchor = run.solve(run.edges)
        anchor = _cut_conflicts(run, anchor)
    if run.scores is not None and run.options.classical:
        _join_across_cuts(run)
    with run.clock.stage("graph"):
        run.likely_wrong.update(edge_graph.resting_on_doubt(num_scans, run.edges, anchor))


def _cut_conflicts(run: _Run, anchor: int) -> int:
    """Step 3b: the placed scans' conflicts cut (:func:`_without_conflicts`); the scans cut off go to step 4.
    Returns the anchor of what stays."""
    run.poses, run.edges, dropped = _without_conflicts(run, run.poses, run.edges)
    run.rejected += dropped
    return min(run.placed()) if dropped else anchor


def _without_conflicts(run: _Run, poses: np.ndarray, edges, among=None) -> tuple:
    """While scans with known sensors that ``poses (S, 4, 4)`` (NaN: unplaced) put within reach of each other fail
    the free-space check (:mod:`~rpmnet_jax.multiway.conflicts`) and suspect ``edges`` are bridges (no cycle
    confirms them), those bridges are cut (:func:`~rpmnet_jax.multiway.edge_graph.cut`: the graph is not solved
    again, the part with the most scans keeps its poses), at most ``MAX_CUTS`` rounds; with ``among`` (a set of
    scans), only the pairs with one of them checked. Returns (poses, edges, the edges cut)."""
    dropped = []
    for _ in range(MAX_CUTS):
        found = _conflicts(run, poses, edges, among)
        suspects = conflicts.suspects(len(run.poses), edges, run.ranking(edges), found) if found else []
        bridges = {k for k in suspects if _bridge(len(run.poses), edges, k)}
        if not bridges:
            break  # a cycle confirms each suspect: the conflicts are named after the refinement
        poses, edges, cut = edge_graph.cut(len(run.poses), poses, edges, [k in bridges for k in range(len(edges))])
        dropped += cut
    return poses, edges, dropped


def _join_across_cuts(run: _Run) -> None:
    """Step 3c, in a levelled scene's campaign: the groups of scans the graph left unplaced joined to the placed
    ones where two edges from different scans agree (:func:`_vote_groups`); up to ``BRIDGING_ROUNDS`` rounds, each
    first registering each group's ends (:func:`~rpmnet_jax.multiway.placement.group_ends`) with their next
    ``neighbours`` placed partners by how well their footprints align
    (:meth:`~rpmnet_jax.multiway.radon_scores.Footprints.aligned`)."""
    o = run.options
    for r in range(BRIDGING_ROUNDS):
        placed = np.isfinite(run.poses[:, 0, 0])
        if placed.all():
            return
        with run.clock.stage("classical"):
            pairs = _end_pairs(run, placed)
            found = _classical(run, pairs, f"classical edges across the cuts, round {r + 1}")
            run.tried.update(found)
            run.pair_edges += [e for answers in found.values() for e in answers]
        with run.clock.stage("graph"):
            grew = _vote_groups(run)
        if not pairs and not grew:
            return


def _end_pairs(run: _Run, placed: np.ndarray) -> list:
    """Pairs ``[(i, j), ...]``, ``i < j``, sorted, none tried: the ends of each unplaced group
    (:func:`_consistent_groups`) with their next ``neighbours`` best placed partners (``placed (S,)``) by
    :meth:`~rpmnet_jax.multiway.radon_scores.Footprints.aligned`."""
    cols, out = np.flatnonzero(placed), set()
    for group in _consistent_groups(run):
        for end in placement.group_ends(group, run.prepared.sensors, run.conflict_reach):
            row = np.full(len(run.poses), -np.inf)
            row[cols] = run.footprints.aligned(end, cols)
            candidate_pairs.add_partners(out, row, end, placed, run.tried, run.options.neighbours)
    return sorted(out)


def _vote_groups(run: _Run) -> bool:
    """Places each unplaced group (:func:`~rpmnet_jax.multiway.placement.unplaced_groups`) that the pair edges to
    placed scans agree on (:func:`~rpmnet_jax.multiway.placement.voted_frame`), again while any is placed. A group
    is checked where it lands: its edges that the conflicts with its members point at are cut
    (:func:`_without_conflicts`: a wrong edge inside the group carried some of it onto a look-alike street), the
    members they carried stay unplaced, and the rest is placed where at most ``VOTE_CONFLICTS`` of its members'
    near pairs still conflict (those left are named after the refinement), never where a cut would fall on a placed
    scan's edge or an agreeing one. Whether any was."""
    grew, changed = False, True
    while changed:
        changed = False
        for group in _consistent_groups(run):
            voted = placement.voted_frame(run.poses, group, run.pair_edges, AGREE_DEG, run.max_dist)
            if voted is None:
                continue
            members, own = set(group.members), {id(e) for e in group.edges}
            poses = run.poses.copy()
            poses[list(group.members)] = voted[0] @ group.poses
            poses, edges, cut = _without_conflicts(run, poses, run.edges + list(group.edges) + voted[1], members)
            near = _near_pairs(run, poses, edges, members)
            if (any(id(e) not in own for e in cut)
                    or len(_conflicts(run, poses, edges, members)) > VOTE_CONFLICTS * len(near)):
                continue  # the conflicts blame the placed scans' edges or the agreeing ones: no place found
            run.poses, run.edges = poses, edges
            run.rejected += cut
            cut_ids = {id(e) for e in cut}
            run.pair_edges = [e for e in run.pair_edges if id(e) not in cut_ids]
            changed = grew = True
            break  # the groups change with what was cut and placed
    return grew


def _consistent_groups(run: _Run) -> list:
    """The unplaced groups (:func:`~rpmnet_jax.multiway.placement.unplaced_groups`), each checked for conflicts in
    its own poses as the placed scans are (:func:`_without_conflicts`): the pair edges it cuts leave
    ``run.pair_edges`` for ``run.rejected`` and the groups are formed again."""
    o = run.options
    while True:
        groups = placement.unplaced_groups(len(run.poses), run.pair_edges, run.poses,
                                           run.noise(NETWORK_NOISE_SCALE), o.seed, o.edge_doubt != "off",
                                           run.weak_bar)
        cut = set()
        for group in groups:
            if len(group.members) > 2:
                poses = np.full_like(run.poses, np.nan)
                poses[list(group.members)] = group.poses
                cut.update(id(e) for e in _without_conflicts(run, poses, list(group.edges))[2])
        if not cut:
            return groups
        run.rejected += [e for e in run.pair_edges if id(e) in cut]
        run.pair_edges = [e for e in run.pair_edges if id(e) not in cut]


def _bridge(num_scans: int, edges, k: int) -> bool:
    """Whether ``edges[k]`` is a bridge of ``edges``: no other path joins its scans."""
    labels = pose_graph.components(num_scans, [(e.source, e.target) for i, e in enumerate(edges) if i != k])
    return bool(labels[edges[k].source] != labels[edges[k].target])


def _near_pairs(run: _Run, poses: np.ndarray, edges, among=None) -> list:
    """``[(i, j), ...]``: the scans with known sensors within :attr:`_Run.conflict_reach` of each other at ``poses``
    (NaN: unplaced), joined by none of ``edges``; with ``among``, only the pairs with one of those scans."""
    joined = {(min(e.source, e.target), max(e.source, e.target)) for e in edges}
    return [(i, j) for i, j in conflicts.near_placed(poses, run.prepared.sensors, run.conflict_reach)
            if (among is None or i in among or j in among) and (i, j) not in joined]


def _conflicts(run: _Run, poses: np.ndarray, edges, among=None) -> list:
    """The pairs of :func:`_near_pairs` whose implied pair fails the free-space check (at the bar of poses composed
    through the graph, ``conflicts.MAX_SHARE``)."""
    if all(v is None for v in run.prepared.sensors):
        return []
    return [(i, j) for i, j in _near_pairs(run, poses, edges, among)
            if not run.visible.clear(i, j, np.linalg.inv(poses[j]) @ poses[i], conflicts.MAX_SHARE)]


def _place_others(run: _Run) -> None:
    """Step 4: the scans still unplaced, in groups (those the pair edges join among themselves, largest first, then
    single scans: :func:`~rpmnet_jax.multiway.placement.unplaced_groups`), each registered onto the merged placed
    scans (in a campaign, those its pair edges join it to, else its best-scored placed partners); placed at
    ``min_fitness`` and the balance bar with coinciding surfaces and, for a group of several, with no member in the
    free space of a placed scan it overlaps by ``min_overlap``; a single scan that lies there is
    placed and named ``likely_wrong`` (scans with known sensors, the pair edges' check), but in a levelled scene's
    campaign no answer that fails the check or is ``likely_wrong`` places a scan (it is left out: on a town's 1,000
    stations such answers were wrong 137 times of 137); edges to each placed scan kept at ``min_overlap`` (one scan
    may overlap a few)."""
    o = run.options
    if not any(not np.isfinite(run.poses[s, 0, 0]) for s in range(len(run.poses))):
        return
    with run.clock.stage("global"):
        run.params = run.params if run.params is not None else loading.load_params(None)
        groups = placement.unplaced_groups(len(run.poses), run.pair_edges, run.poses, run.noise(NETWORK_NOISE_SCALE),
                                           o.seed, o.edge_doubt != "off", run.weak_bar)
        run.poses, found, run.pending, doubtful = placement.place_remaining(
            run.scans, run.poses, groups, run.params, run.cfg, run.prepared.voxel, run.max_dist, seed=o.seed,
            tick=run.tick("placing the other scans"),
            accept=lambda fitness, residual, balanced: (fitness >= o.min_fitness and balanced >= run.balance_bar
                                                        and residual <= run.plane_bar * run.max_dist),
            visible=lambda e: e.fitness < o.min_overlap or run.visible(e),
            partners=None if run.scores is None else candidate_pairs.best_partners(run.scores, PLACE_PARTNERS),
            max_tries=None if run.scores is None else PLACE_TRIES, place_doubtful=run.scores is None,
            joined=_joined(run.pair_edges))
        run.counts["global"] = sum(e.stage == "global" for e in found)
        run.global_edges = [e for e in found if e.stage != "global" or run.good(e, o.min_overlap)]
        run.edges += run.global_edges
        run.likely_wrong.update(doubtful)


def _joined(edges) -> dict:
    """``{scan: [scan, ...]}``: the scans ``edges`` join each to, in edge order, once each."""
    joined = {}
    for e in edges:
        for a, b in ((e.source, e.target), (e.target, e.source)):
            if b not in joined.setdefault(a, []):
                joined[a].append(b)
    return joined


def _finer_scans(run: _Run) -> None:
    """Before step 5, with ``refine_voxel_size`` and a refinement (not ``refine="none"``): the refinement first at
    the registration's voxel (:func:`_refine`), then the scans prepared again at that voxel (no features), the
    correspondence distance scaled with it, the engine bound to them; the refinement and the answer's edges use
    them. The coarse scans are let go first (the free-space check keeps
    their points): a site's stations never hold both sets of normals, trees and features."""
    o = run.options
    if o.refine_voxel_size is None or o.refine == "none" or len(run.placed()) < 2:
        return
    _refine(run, answer=False)  # at the registration's voxel first: the finer correspondence distance cannot reach a
    # pose the graph left a metre or more off (seed 2's 300 stations refined at 0.1 m alone: 3 slid 1.82 m, not named)
    with run.clock.stage("refine"):
        clouds, normals, viewpoints = run.inputs
        run.engine.release()
        run.visible.compact()  # images made again for the conflicts named at the end, once the finer scans are gone
        coarse_voxel, run.prepared = run.prepared.voxel, run.prepared._replace(scans=None)
        memory.give_back()  # the registration's scans, before the finer ones take their place
        fine = preparation.prepare_scans(clouds, normals, o.refine_voxel_size, run.shift, viewpoints, run.engine,
                                         run.tick("preparing scans for the refinement"), features=False)
        run.max_dist *= fine.voxel / coarse_voxel
        run.prepared = fine
        run.engine.bind(fine.scans, run.params, run.cfg, run.engine.settings._replace(
            max_distance=run.max_dist, ransac_distance=sizes.RANSAC_VOXELS * fine.voxel))


def _refine(run: _Run, answer: bool = True) -> None:
    """Step 5: ``refine="icp"`` rounds of ICP edges, each a robust graph; ``"joint"`` all poses together;
    ``"none"`` with placed scans, one graph of the pair and placement edges at the pair edges' noise. Not
    ``answer`` (the first of refine_voxel_size's two passes): ``"joint"`` measures no edges (the finer pass's are
    the answer's)."""
    o, placed = run.options, run.placed()
    finer = run.screened is not None  # the second pass (refine_voxel_size's finer scans), from refined poses
    run.screened = list(run.edges) if run.screened is None else run.screened  # the edges before any refinement
    keep = (lambda e: run.good(e, o.min_overlap))
    for r in range(o.refine_rounds if o.refine == "icp" and len(placed) > 1 else 0):
        with run.clock.stage("refine"):
            found, registered = refinement.icp_round(run.engine, run.scans, run.poses, placed, run.max_dist,
                                                     o.min_overlap, keep, r, run.tick(f"refinement round {r + 1}"))
            run.counts["refine"] = run.counts.get("refine", 0) + registered
            if not found:
                break
            run.poses, run.edges, run.refine_rejected = edge_graph.solve(len(run.poses), found, min(placed),
                                                                         run.noise(), o.seed)
        dropped = [s for s in placed if s not in run.placed()]
        if dropped:
            warnings.warn(f"scans {dropped}: no edge consistent with the others after refinement; left out",
                          LeftOutWarning, stacklevel=3)
            placed = run.placed()
    if o.refine == "joint" and len(placed) > 1:
        with run.clock.stage("refine"):
            run.poses, found, rejected, refined = refinement.jointly(
                run.engine, run.scans, run.poses, placed, run.max_dist, o, keep, run.tick("joint refinement stages"),
                finer, measured=answer)
            if answer:
                run.edges, run.refine_rejected = found, rejected
            run.counts["refine"] = run.counts.get("refine", 0) + refined
    if o.refine == "none" and run.global_edges:
        with run.clock.stage("graph"):
            run.poses, run.edges, run.refine_rejected = edge_graph.solve(
                len(run.poses), run.edges, min(placed), run.noise(NETWORK_NOISE_SCALE), o.seed)
            run.screened = list(run.edges)  # the edges this solve kept


def _let_go_of_scans(run: _Run) -> None:
    """After step 5: the prepared scans let go, here and on the cluster (the answer needs its poses and edges; the
    conflicts named next, the free-space check's points and reach)."""
    run.conflict_reach  # noqa: B018 (kept: measured on the scans)
    run.engine.release()
    run.prepared = run.prepared._replace(scans=None)


def _name_conflicts(run: _Run) -> None:
    """Step 5b: placed scans that the final poses put in one another's free space (:func:`_conflicts`) are named
    ``likely_wrong`` (timed with the graph); only the edges before the refinement exempt a pair (the refinement
    measures an edge wherever scans overlap at the poses, checked or not)."""
    if any(v is not None for v in run.prepared.sensors) and len(run.placed()) > 1:
        with run.clock.stage("graph"):
            edges = run.edges if run.screened is None else run.screened
            run.likely_wrong.update(s for pair in _conflicts(run, run.poses, edges) for s in pair)


def _answer(run: _Run) -> ScanAlignment:
    """The poses relative to the first placed scan and the edges, moved back by the shift; what was left out."""
    if run.pending:
        campaign = run.scores is not None
        onto = "the placed scans their pair edges join or their best-scored ones" if campaign else "them"
        where = " outside the placed scans' free space, not likely wrong" if campaign else ""
        warnings.warn(f"scans {run.pending} overlap none of the placed scans (no registration onto {onto} reached "
                      f"fitness {run.options.min_fitness} with coinciding surfaces{where}); left out",
                      LeftOutWarning, stacklevel=3)
    left_out = tuple(s for s in range(len(run.poses)) if s not in run.placed())
    first = min(run.placed())
    poses = offsets.unshift_transforms(np.linalg.inv(run.poses[first]) @ run.poses, run.shift)  # NaN stays NaN
    return ScanAlignment(poses, _unshifted(run.edges, run.shift), _unshifted(run.rejected + run.refine_rejected,
                                                                              run.shift),
                         left_out, run.prepared.voxel, run.max_dist, run.clock.timings(),
                         tuple(sorted(run.likely_wrong - set(left_out))), run.counts)


def _unshifted(edges, shift) -> tuple:
    """``edges`` between the scans moved by ``-shift`` → the same edges between the caller's frames."""
    return tuple(e._replace(transform=offsets.unshift_transforms(e.transform, shift),
                            information=offsets.unshift_information(e.information, shift)) for e in edges)
