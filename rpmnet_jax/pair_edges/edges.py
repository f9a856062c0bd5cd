"""Pairwise edges between scans for :func:`rpmnet_jax.align_scans`: the network over many pairs in batched
calls, ICP from a start, and the measured quality of each answer.

An edge ``(i, j)`` maps the source scan ``i`` onto the target scan ``j`` (caller's units); its information
matrix is on the tangent of the right perturbation (:func:`rpmnet_jax.classical.scoring.plane_fit`).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from rpmnet_jax.ops import se3
from rpmnet_jax.classical import feature_ransac, fpfh, icp, scoring
from rpmnet_jax.geometry import kdtree, packed_normals, sampling
from rpmnet_jax.pairwise import prepare

FEATURE_POINTS = 4000  # FPFH keypoints per scan at most: one per cube of KEYPOINT_VOXELS voxels, a seeded random
# subset of those beyond this many
KEYPOINT_VOXELS = 2.0  # the keypoints' cube, in voxels: evenly spread, so two scans' keypoints lie near each other
# (1,024 random keypoints of a 21,000-voxel LiDAR sweep rarely do). With the FPFH of each keypoint from its
# neighbours in the whole scan (not among the keypoints), the 45 pairs of kitti_04's 10 tune sweeps (0.3 m voxel)
# have a right classical answer for 24 -> 40 and 10 -> 1 wrong ones accepted (cubes of 3 voxels, 2,000 at most: 38,
# 0); happy_stand's and tum_fr1_desk's tune pairs stay all right. Chosen on those tune parts (tuning data: numbers
# on them are not held-out)
FEATURE_NEIGHBOURS = 128  # FPFH's max_nn (Open3D's tutorial recipe)


class Scan(NamedTuple):
    """A scan ready for pairing: voxel-downsampled points, unit normals, their k-d tree and, for the classical
    edges, FPFH features of some of its points."""

    points: np.ndarray  # (V, 3) caller's units
    normals: np.ndarray  # (V, 3) unit, or (V, 2) packed (a refinement's scan: geometry.packed_normals)
    tree: kdtree.KdTree
    keypoints: np.ndarray | None = None  # (M,) rows of ``points`` that carry features
    features: np.ndarray | None = None  # (M, 33) their FPFH


class Edge(NamedTuple):
    source: int
    target: int
    transform: np.ndarray  # (4, 4): maps the source scan's points into the target scan's frame
    fitness: float  # fraction of the (downsampled) source within max_correspondence_distance of the target
    inlier_rmse: float  # RMS distance of those pairs, caller's units
    information: np.ndarray  # (6, 6) on ξ = (ω, v) of transform · Exp(ξ)
    plane_residual: float  # median |point-to-plane distance| of those pairs: small where the surfaces coincide
    stage: str  # "classical" (FPFH + RANSAC + ICP), "network" (batched network + ICP), "global" (placed against
    # the merged model), "refine" (ICP)
    p_wrong: float = 0.0  # a classical edge's probability of a rotation > 5° off (multiway.edge_doubt); 0: not rated
    balanced_fitness: float = 0.0  # fitness with every normal direction of the source weighing the same
    # (classical.scoring.balanced_fitness): what a scene's ground cannot carry


def make_scan(points: np.ndarray, normals: np.ndarray, feature_radius: float | None = None, voxel: float = 0.0,
              seed=0, tree: kdtree.KdTree | None = None) -> Scan:
    """A :class:`Scan` of voxel-downsampled ``points, normals (V, 3)``; with ``feature_radius``, the FPFH (that
    radius, over the whole scan) of its keypoints: one per cube of ``KEYPOINT_VOXELS × voxel`` (every point at
    ``voxel`` 0), at most ``FEATURE_POINTS`` drawn with ``seed`` (an int or a sequence of ints). ``tree``: a k-d
    tree of ``points`` already built (else built here)."""
    points, normals = np.asarray(points, np.float64), np.asarray(normals, np.float64)
    scan = Scan(points, normals, tree if tree is not None else kdtree.KdTree(points))
    if feature_radius is None:
        return scan
    keypoints = np.arange(len(points))
    if voxel > 0:
        keypoints = np.sort(np.unique(sampling.cube_ids(points, KEYPOINT_VOXELS * voxel), return_index=True)[1])
    keypoints = keypoints[sampling.sample_indices(np.random.default_rng(seed), len(keypoints), FEATURE_POINTS)]
    features = fpfh.fpfh(points, normals, feature_radius, FEATURE_NEIGHBOURS, scan.tree)[keypoints]
    return scan._replace(keypoints=keypoints, features=features)


def measure(scans, i: int, j: int, transform: np.ndarray, max_distance: float, stage: str,
            plane_distance: float | None = None, num_points: int | None = None) -> Edge:
    """The edge ``i → j`` at ``transform``, scored on all of scan ``i`` (or, with ``num_points``, on every k-th
    point, at least ``num_points``: its information scaled back to all of them): fitness (plain and balanced) and
    RMSE within ``max_distance``, point-to-plane residual and information from the pairs within ``plane_distance``
    (default ``max_distance``)."""
    src, ref = scans[i], scans[j]
    step = 1 if num_points is None else max(1, len(src.points) // num_points)
    points, normals = src.points[::step], src.normals[::step]
    score = scoring.evaluate_registration(points, ref.points, transform, max_distance, ref_tree=ref.tree)
    close = score.correspondences[score.distances <= (plane_distance or max_distance)]
    fit = scoring.plane_fit(points, ref.points, ref.normals, transform, close)
    residual = float(np.median(np.abs(fit.residuals))) if len(fit.residuals) else float("inf")
    return Edge(int(i), int(j), np.asarray(transform, np.float64), score.fitness, score.inlier_rmse,
                fit.information * (len(src.points) / len(points)), residual, stage,
                balanced_fitness=scoring.balanced_fitness(normals, score.correspondences[:, 0]))


def icp_edge(scans, i: int, j: int, start: np.ndarray, max_distance: float, rng: np.random.Generator, *,
             num_points: int, schedule: icp.Schedule = icp.EDGE, stage: str = "refine") -> Edge:
    """Point-to-plane ICP of up to ``num_points`` random points of scan ``i`` onto scan ``j`` from
    ``start (4, 4)`` (``schedule``: gates × ``max_distance``, iterations), measured on all of scan ``i`` (the
    plane fit within the finest gate)."""
    src, ref = scans[i], scans[j]
    pick = sampling.sample_indices(rng, len(src.points), num_points)
    r = icp.point_to_plane_icp(src.points[pick], ref.points, ref.normals, start, max_distance,
                               scales=schedule.scales, max_iterations=schedule.max_iterations, ref_tree=ref.tree)
    return measure(scans, i, j, r.transform, max_distance, stage, min(1.0, min(schedule.scales)) * max_distance)


DISTINCT_DEG = 10.0  # a pair's answers whose rotations lie closer than this are one answer (the fitter one kept)


def classical_edges(scans, i: int, j: int, max_distance: float, ransac_distance: float, rng: np.random.Generator, *,
                    num_points: int, max_plane_residual: float, hypotheses: int = 2, identity: bool = True) -> list:
    """The distinct answers ``[Edge, ...]`` of ``i → j`` from FPFH + RANSAC on the scans' keypoints (mutual
    feature matches, up to ``hypotheses`` distinct transforms within ``ransac_distance``), each refined as a
    network edge's short ICP (``icp.NETWORK_EDGE``, ``num_points``), best first: those whose median
    point-to-plane distance is at most ``max_plane_residual × max_distance`` before the others, then by
    fitness; a symmetric pair keeps its flip beside the truth, for the pose graph to choose by consistency."""
    a, b = scans[i], scans[j]
    corr = feature_ransac.mutual_correspondences(a.features, b.features)
    hyp = feature_ransac.ransac_hypotheses(a.points[a.keypoints], b.points[b.keypoints], corr, ransac_distance,
                                           top_k=hypotheses, seed=int(rng.integers(2 ** 31)))
    # the scans as they lie too (``identity``): scans that come in roughly one frame
    starts = [np.eye(4)] * identity + list(hyp.transforms)
    found = sorted((icp_edge(scans, i, j, t, max_distance, rng, num_points=num_points, schedule=icp.NETWORK_EDGE,
                             stage="classical") for t in starts),
                   key=lambda e: (e.plane_residual <= max_plane_residual * max_distance, e.fitness), reverse=True)
    if not found:
        return []
    keep = se3.distinct_rotations(np.stack([e.transform[:3, :3] for e in found]), DISTINCT_DEG)
    return [found[k] for k in keep]


def batches(items: list, batch_size: int) -> list:
    """``[(chunk, padded), ...]``: ``items`` in order, in chunks of one size (a power of two up to ``batch_size``:
    one batch shape, one compile), each ``padded`` to that size with its last item."""
    size = min(batch_size, 1 << max(0, len(items) - 1).bit_length())
    chunks = [list(items[k:k + size]) for k in range(0, len(items), size)]
    return [(chunk, chunk + chunk[-1:] * (size - len(chunk))) for chunk in chunks]


def network_starts(params, scans, pairs, *, cfg, num_points: int, num_iters: int, batch_size: int, seed: int
                   ) -> np.ndarray:
    """``(P, 4, 4)`` network answers (caller's units) for ``pairs (P, 2)``, each started from the identity
    after :func:`rpmnet_jax.pairwise.prepare.prepare_pair` (as :func:`rpmnet_jax.align` prepares a pair); pairs
    of equal sample sizes share batched calls of ``batch_size`` (the last one padded), one compile per size."""
    from rpmnet_jax import registration  # JAX is imported when the network runs, not for the classical edges

    prepared = [prepare.prepare_pair(scans[i].points, scans[j].points, packed_normals.unit(scans[i].normals),
                                     packed_normals.unit(scans[j].normals),
                                     num_points=num_points, seed=seed) for i, j in pairs]
    out = np.zeros((len(pairs), 4, 4))
    fn = registration.jitted(cfg, int(num_iters), "transforms")
    groups = {}
    for p, pair in enumerate(prepared):
        groups.setdefault((len(pair.samples[0]), len(pair.samples[1])), []).append(p)
    for members in groups.values():
        for chunk, padded in batches(members, batch_size):
            src = np.concatenate([prepared[p].src6 for p in padded])
            ref = np.concatenate([prepared[p].ref6 for p in padded])
            transforms = np.asarray(fn(params, src, ref)[-1], np.float64)  # (size, 3, 4), normalised frames
            for k, p in enumerate(chunk):
                out[p] = prepared[p].to_callers_units(transforms[k])
    return out


def predicted_overlap(scans, i: int, j: int, transform: np.ndarray, max_distance: float,
                      num_points: int = 300) -> float:
    """Share of an evenly strided sample of scan ``i`` within ``max_distance`` of scan ``j`` under
    ``transform``, or of scan ``j`` near scan ``i``, whichever is larger (one scan may cover a small part of
    the other)."""

    def share(a, b, t):
        pts = scans[a].points[:: max(1, len(scans[a].points) // num_points)]
        dist, _ = scans[b].tree.query(se3.apply(t, pts), distance_upper_bound=max_distance)
        return float(np.mean(np.isfinite(dist)))

    return max(share(i, j, transform), share(j, i, np.linalg.inv(transform)))
