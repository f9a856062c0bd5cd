"""Step 5 of :func:`rpmnet_jax.align_scans`: the placed scans refined on the pairs predicted to overlap, jointly
(:mod:`rpmnet_jax.pose_graphs.joint_refine`) or by rounds of pairwise ICP edges."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from rpmnet_jax.geometry import threads
from rpmnet_jax.pair_edges import edges as edges_lib
from rpmnet_jax.pose_graphs import joint_refine
from rpmnet_jax.ops import se3

FINER_GATES = (joint_refine.GATES[-1], joint_refine.GATES[-1] / 2)  # the second pass's, × its correspondence distance:
# its wider gates only undo the first pass, and a wider gate's optimum lies further from the truth. The town's 1,000
# stations of seed 8 (tuning), the finer pass started from the truth: 0.5 -> 15 within 0.2 deg and 1 cm (median
# 19 mm), 0.25 -> 965 (4.2 mm), 0.125 -> 994 (3.4 mm): the wider gate takes in rows off the surface. From the first
# pass's poses 0.125 alone is slow to reach what 0.25 then 0.125 reach (below)
FINER_POINTS = (4 * joint_refine.POINTS, 8 * joint_refine.POINTS)  # the second pass's points per directed pair, a
# count per gate (those 858 stations placed from seed 8's 1,000 at the gate 0.25, 8 steps: 1,000 -> 4,000 rows took
# 123 -> 44 beyond 1 cm RMS). With FINER_NORMAL_COSINE, seed 14's 1,000 (tuning data since: not held-out), its finer
# pass replayed from the first pass's poses: 4,000 rows at both gates 988 within 0.2 deg and 1 cm (12 steps), 8,000
# or 12,000 at the last 996 (11 steps; 12,000 as long as 4,000 at both); from the truth at the last gate 4,000 rows
# 980, 12,000 999: the optimum itself drifts where few rows hold the along-street sliding, and more rows hold it
FINER_NORMAL_COSINE = 0.985  # the second pass leaves out a row whose normal and its neighbour's are more than ~10 deg
# apart: at a voxel that straddles a box's edge (a wall's corner, a car's end) point and normal mix two faces and lie
# off both, by up to a quarter voxel, and a scan that sees one face only disagrees there. Seed 14's 1,000 (tuning
# data), the finer pass started from the truth, 4,000 rows, the last gate: 957 within without, 975 at 0.94 (20 deg),
# 980 at 0.985; from the first pass's poses at both gates 953 -> 988 within, 16 -> 12 steps (186 -> 159 s). Normal-
# space sampling (as many rows of each normal's direction) went the other way: 751 (the rare normals are those off
# the surface). Chosen there
FINER_TOLERANCE = 1.5e-5  # the second pass's stop: no pose moved more than this (radians; x the set's radius: 5.5 mm
# on the town), in at most FINER_ITERATIONS steps a gate, each extrapolated up to FINER_EXTRAPOLATION times: the set
# bends slowly (a branch of stations near the anchor held ~1.5 cm off at 3e-5)
FINER_ITERATIONS = 15
FINER_EXTRAPOLATION = 20.0
# Seed 8's 1,000 (tuning), its finer pass replayed from the first pass's poses (float32 scans): gate 0.25, stop 3e-5,
# 10 steps, cap 10 (before): 969 within, worst 2.4 cm, 64 s; 0.25 then 0.125 at 1.5e-5, 15 steps, cap 20: 994, worst
# 1.2 cm, 13 steps, 121 s; 0.125 alone so: 992, 79 s; 0.125 at 1e-5, 20 steps, cap 10: 990, 160 s. Chosen there
MEASURED_POINTS = 10_000  # the refinement's edges are scored on every k-th point of the source scan, at least this
# many (fitness to ~0.5%, the binomial error of 10,000 draws): the finer pass's scans of the town hold ~47,000 points,
# and scoring all of them took 8.5 ms a pair, as long as the joint refinement's steps together. Not chosen on data: an
# object's scan (fewer points) is scored on all of them as before
PASSES = {False: {"gates": joint_refine.GATES, "num_points": joint_refine.POINTS, "tolerance": joint_refine.TOLERANCE},
          True: {"gates": FINER_GATES, "num_points": FINER_POINTS, "tolerance": FINER_TOLERANCE,
                 "max_iterations": FINER_ITERATIONS, "max_extrapolation": FINER_EXTRAPOLATION,
                 "normal_cosine": FINER_NORMAL_COSINE}}  # by ``finer``


def overlapping_pairs(scans, poses, placed, max_dist, min_overlap, neighbours=None) -> list:
    """``[(i, j), ...]``, ``i < j``: the placed pairs predicted to overlap by ``min_overlap`` at ``poses`` (the
    pairs whose bounding spheres lie apart are neither looked at nor enumerated: :func:`near_pairs`); with
    ``neighbours``, of those only each scan's ``neighbours`` most overlapping ones (their union)."""
    placed = sorted(placed)
    means = {s: scans[s].points.mean(axis=0, dtype=np.float64) for s in placed}  # each scan's centre in its own frame
    centres = np.array([se3.apply(poses[s], means[s][None])[0] for s in placed]).reshape(-1, 3)
    radii = np.array([float(np.max(np.linalg.norm(scans[s].points - means[s], axis=1))) for s in placed])
    near = [(placed[a], placed[b]) for a, b in near_pairs(centres, radii, max_dist)]
    overlap = {(i, j): edges_lib.predicted_overlap(scans, i, j, np.linalg.inv(poses[j]) @ poses[i], max_dist)
               for i, j in near}
    pairs = [p for p in near if overlap[p] >= min_overlap]
    if neighbours is None:
        return pairs
    of_scan = {s: [] for s in placed}
    for p in pairs:
        of_scan[p[0]].append(p)
        of_scan[p[1]].append(p)
    best = set()
    for s in placed:
        best.update(sorted(of_scan[s], key=lambda p: -overlap[p])[:neighbours])
    return sorted(best)


def near_pairs(centres: np.ndarray, radii: np.ndarray, max_dist: float) -> list:
    """``[(a, b), ...]``, ``a < b``, sorted: the rows of ``centres (P, 3)`` whose spheres of ``radii (P,)`` lie
    within ``max_dist`` of each other; the candidates from a k-d tree of the centres (within twice the largest
    radius), not from every pair."""
    if len(centres) < 2:
        return []
    reach = (2.0 * float(np.max(radii)) + max_dist) * (1.0 + 1e-9)  # a candidate on the bound stays one
    found = cKDTree(centres).query_pairs(reach, output_type="ndarray")
    return sorted((int(a), int(b)) for a, b in found
                  if np.linalg.norm(centres[a] - centres[b]) <= radii[a] + radii[b] + max_dist)


def icp_round(engine, scans, poses, placed, max_dist, min_overlap, keep, round_, tick) -> tuple:
    """``refine="icp"``, one round: an ICP edge from the current poses for every placed pair predicted to overlap,
    run by ``engine`` (``tick(done, total)`` as they finish): (the edges ``keep`` accepts, the number of pairs)."""
    pairs = overlapping_pairs(scans, poses, placed, max_dist, min_overlap)
    starts = [np.linalg.inv(poses[j]) @ poses[i] for i, j in pairs]
    return [e for e in engine.refine_edges(pairs, starts, round_, tick) if keep(e)], len(pairs)


def jointly(engine, scans, poses, placed, max_dist, options, keep, tick, finer: bool = False,
            measured: bool = True) -> tuple:
    """``refine="joint"``: the overlapping pairs' points refine all poses together, then each pair is measured, the
    work on the pairs done by ``engine`` (:meth:`~rpmnet_jax.pair_edges.pair_engine.PairEngine.map_pairs`: on a
    cluster, tasks): (poses, kept edges, the other edges, the number of pairs refined). ``finer``: the second pass
    (``refine_voxel_size``), from poses the first pass refined: its finest gate and half that (:data:`FINER_GATES`),
    on more points (:data:`FINER_POINTS`), the rows whose normals disagree left out (:data:`FINER_NORMAL_COSINE`),
    to a tighter stop (:data:`FINER_TOLERANCE`, :data:`FINER_ITERATIONS`, :data:`FINER_EXTRAPOLATION`). Not
    ``measured`` (a first pass whose edges a finer pass replaces): no edges, ``[]`` and ``[]``."""
    o = options
    pairs = overlapping_pairs(scans, poses, placed, max_dist, o.min_overlap, o.refine_neighbours)
    poses = joint_refine.refine_jointly(scans, poses, pairs, max_dist, min(placed), seed=o.seed, tick=tick,
                                        map_pairs=engine.map_pairs, **PASSES[finer]).poses
    if not measured:
        return poses, [], [], len(pairs)
    edges = [e for share in engine.map_pairs(measure_pairs, joint_refine.shares(pairs), poses, max_dist) for e in share]
    return poses, [e for e in edges if keep(e)], [e for e in edges if not keep(e)], len(pairs)


@threads.compiled_loops()  # on a worker too: BLAS on one thread, as in this process
def measure_pairs(scans, pairs, poses, max_dist) -> list:
    """The edges ``i → j`` of ``pairs [(i, j), ...]`` measured at ``poses`` (indexable by scan; ``scans`` too), each
    on at least :data:`MEASURED_POINTS` points of scan ``i`` (all of a smaller scan)."""
    return [edges_lib.measure(scans, i, j, np.linalg.inv(poses[j]) @ poses[i], max_dist, "joint",
                              num_points=MEASURED_POINTS) for i, j in pairs]
