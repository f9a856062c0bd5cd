"""Step 1 of :func:`rpmnet_jax.align_scans`: the scans ready for pairing, and the pairs to register.

Each scan cleaned, moved by the set's common shift (float64: the shift loses nothing), voxel-downsampled at the
set's voxel (:mod:`rpmnet_jax.multiway.sizes`), with normals (the caller's averaged per voxel, else estimated and
facing the scan's sensor where one is known, else away from its centroid) and the FPFH of its keypoints
(:func:`rpmnet_jax.pair_edges.edges.make_scan`).
"""

from __future__ import annotations

import itertools
from typing import NamedTuple

import numpy as np

from rpmnet_jax import memory
from rpmnet_jax.geometry import cloud, kdtree, normals as normals_lib, packed_normals, sampling, sensors, threads
from rpmnet_jax.multiway import candidate_pairs, radon_scores, sizes
from rpmnet_jax.pair_edges import edges as edges_lib

MIN_VOXEL_POINTS = 16  # a scan with fewer points after voxel downsampling is too coarse to register
GIVE_BACK_EVERY = 50  # scans prepared between two returns of the heap's free pages (rpmnet_jax.memory): site seed
# 14's 1,000 finer scans ended their preparation with 224 MB freed but resident, the run's peak
SCAN_DTYPE = np.float32  # a refinement's scans (points in their sensor's frame moved by the common shift; their unit
# normals packed in two int16: geometry.packed_normals), in their k-d tree's order: 16 bytes a point, not 48 + 8 (its
# tree's row map): a site's finer scans are most of its memory (seed 14's 1,000: points 552 MB, normals 552 -> 184 MB,
# trees 152 MB). Rounding moves a point by at most 2^-24 of its coordinate (6 microns at 100 m); every estimate
# from them is in float64. The registration's scans keep their points in float64 in their own order (in float32 and
# the tree's order, their keypoints and ICP rows drawn otherwise, seed 7's look-alike streets folded again:
# tests/sites_test.py); their normals, FPFH features and their tree's copy of the points are rounded to this once
# made (the normals and features from the float64 points): 1.12 -> ~0.65 MB a site station


class Prepared(NamedTuple):
    scans: list  # edges.Scan of each scan, moved by -shift
    voxel: float  # caller's units
    sensors: list  # each scan's sensor (3,) in the moved frame, or None
    scene: bool  # scans seen from inside a scene (sizes.voxel)


def prepare_scans(clouds, normals, voxel_size, shift=np.zeros(3), viewpoints="auto", engine=None,
                  tick=None, features: bool = True) -> Prepared:
    """The scans ``clouds[i] (N_i, 3)`` (``normals``: ``None`` or one ``(N_i, 3)`` or ``None`` per scan) moved by
    ``-shift (3,)``, at ``voxel_size`` (``None``: :func:`~rpmnet_jax.multiway.sizes.voxel`'s default), their
    sensors from ``viewpoints`` (:func:`~rpmnet_jax.geometry.sensors.positions`); each scan made ready by
    :func:`prepare_scan`, by ``engine`` when given (:meth:`~rpmnet_jax.pair_edges.pair_engine.PairEngine.prepare`:
    a task a scan on a cluster), ``tick(done, total)`` as they finish; ``features=False``: without FPFH (scans for
    the refinement only)."""
    if len(clouds) < 2:
        raise ValueError(f"need at least two scans, got {len(clouds)}")
    normals = [None] * len(clouds) if normals is None else list(normals)
    if len(normals) != len(clouds):
        raise ValueError(f"got {len(normals)} normal arrays for {len(clouds)} scans")
    cleaned = [cloud.clean_cloud(f"scan {i}", c, n)[:2] for i, (c, n) in enumerate(zip(clouds, normals))]
    seen_from = [None if v is None else v - shift for v in sensors.positions([p for p, _ in cleaned], viewpoints)]
    voxel, scene = sizes.voxel((p - shift for p, _ in cleaned), seen_from, voxel_size)  # one moved copy at a time
    jobs = [(p, n, sensor, voxel, i, features, shift) for i, ((p, n), sensor) in enumerate(zip(cleaned, seen_from))]

    def ticked(done: int, total: int) -> None:
        if done % GIVE_BACK_EVERY == 0:
            memory.give_back()  # each scan's work leaves freed pieces of other sizes than the scans kept
        if tick is not None:
            tick(done, total)

    scans = engine.prepare(prepare_scan, jobs, ticked) if engine is not None else [prepare_scan(*job) for job in jobs]
    coarse = [(i, s) for i, s in enumerate(scans) if not isinstance(s, edges_lib.Scan)]
    if coarse:  # here, not in the task: one line naming the first such scan, wherever the tasks ran
        raise ValueError(f"scan {coarse[0][0]}: {coarse[0][1]} points after voxel downsampling at {voxel:.4g}; "
                         "a smaller voxel size is needed")
    return Prepared(scans, voxel, seen_from, scene)


@threads.compiled_loops()  # on a worker too: BLAS leaves the cores to the compiled loops
def prepare_scan(points, normals, sensor, voxel: float, index: int, features: bool = True, shift=None):
    """Scan ``index`` (cleaned ``points (N, 3)``, moved by ``-shift (3,)`` when given; ``normals (N, 3)`` or
    ``None``; its ``sensor (3,)`` or ``None``, in the moved frame) voxel-downsampled at ``voxel``, with normals
    (averaged per voxel, else estimated: facing the sensor, else away from the centroid) and, with ``features``,
    the FPFH of its keypoints (drawn with seed ``index``): an :class:`~rpmnet_jax.pair_edges.edges.Scan`, or the
    number of points left when fewer than ``MIN_VOXEL_POINTS``. Without ``features`` (a refinement's scan) the points
    are in the k-d tree's order (:meth:`~rpmnet_jax.geometry.kdtree.KdTree.reordered`: held once, no row map), in
    ``SCAN_DTYPE``, the normals packed (:func:`~rpmnet_jax.geometry.packed_normals.pack`); with them the points stay
    as they are (float64), the normals, features and the tree's copy of the points
    (:meth:`~rpmnet_jax.geometry.kdtree.KdTree.rounded`) in ``SCAN_DTYPE``."""
    p, n = sampling.voxel_downsample(points if shift is None else points - shift, normals, voxel)
    if len(p) < MIN_VOXEL_POINTS:
        return len(p)
    tree = kdtree.KdTree(p)  # one tree for the normals and the scan
    if n is None:
        n = normals_lib.estimate_normals(p, tree=tree) if sensor is None else normals_lib.facing(p, sensor, tree=tree)
    if not features:  # a refinement's scan
        tree, order = tree.reordered(SCAN_DTYPE)
        return edges_lib.Scan(tree.data, packed_normals.pack(n[order]), tree)
    scan = edges_lib.make_scan(p, n, sizes.FEATURE_VOXELS * voxel, voxel, seed=index, tree=tree)
    return scan._replace(normals=scan.normals.astype(SCAN_DTYPE), tree=scan.tree.rounded(SCAN_DTYPE),
                         features=scan.features.astype(SCAN_DTYPE))  # after the normals and features are made


def pairs_to_register(scans, all_pairs_up_to: int, neighbours: int, seed: int, levelled=None) -> tuple:
    """``([(i, j), ...], scores, footprints)``, ``i < j``: every pair up to ``all_pairs_up_to`` scans (``scores`` and
    ``footprints`` ``None``), else each scan with its ``neighbours`` best partners by the overlap ``scores (S, S)``
    and a spanning tree of those scores (:mod:`rpmnet_jax.multiway.candidate_pairs`), whatever the order of the
    scans. The scores: with ``levelled`` ``(sensors, voxel)`` (a levelled scene's scans, :func:`levelled`) the
    footprints' sinograms, each scan's best ordered again by how well the footprints align (``footprints``,
    :meth:`~rpmnet_jax.multiway.radon_scores.Footprints.ranked`), else the bag of words (``footprints`` ``None``)."""
    if len(scans) <= all_pairs_up_to:
        return list(itertools.combinations(range(len(scans)), 2)), None, None
    footprints = radon_scores.Footprints(scans, *levelled) if levelled is not None else None
    scores = candidate_pairs.overlap_scores(scans, seed=seed) if footprints is None else footprints.ranked()
    return candidate_pairs.select_pairs(scores, neighbours), scores, footprints


def levelled(prepared: Prepared):
    """``(sensors, voxel)`` when ``prepared`` holds a levelled scene's scans (seen from inside, every sensor known,
    and most scans spread least along a direction within 25° of z: wider than tall, z up), else None."""
    if not prepared.scene or any(v is None for v in prepared.sensors):
        return None
    up = [abs(np.linalg.eigh(np.cov(s.points.T))[1][2, 0]) >= radon_scores.GROUND_NORMAL_Z for s in prepared.scans]
    return (prepared.sensors, prepared.voxel) if np.mean(up) > 0.5 else None
