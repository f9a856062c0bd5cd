"""Step 4 of :func:`rpmnet_jax.align_scans`: the scans the pose graph left unplaced, each registered onto the merged
placed scans by :func:`rpmnet_jax.align` with ``init="global"`` (rotation hypotheses covering every orientation)."""

from __future__ import annotations

import numpy as np

from rpmnet_jax.geometry import normals as normals_lib, sampling
from rpmnet_jax.classical import scoring
from rpmnet_jax.pair_edges import edges as edges_lib
from rpmnet_jax.ops import se3
from rpmnet_jax.pairwise import alignment


def merged(scans, poses, placed, voxel: float) -> tuple:
    """``(points (M, 3), normals (M, 3))``: the ``placed`` scans at ``poses``, one cloud downsampled at ``voxel``."""
    points = np.concatenate([se3.apply(poses[s], scans[s].points) for s in placed])
    points, _ = sampling.voxel_downsample(points, None, voxel)
    return points, normals_lib.estimate_normals(points)


def place_remaining(scans, poses, params, cfg, voxel, max_dist, accept, seed, tick, visible=None):
    """Registers each unplaced scan (NaN in ``poses (S, 4, 4)``) onto the merged placed ones, in index order,
    merging again after each success (``tick(placed, scans)`` then); ``accept(fitness, median plane residual,
    balanced fitness)`` decides; with ``visible(edge) -> bool`` (the pair edges' free-space check) a placed scan
    whose edge to a scan placed before it fails it is named: a scan registered onto the merged scans can land on a
    street elsewhere that looks alike, inside what another station saw through. Returns (poses, the placed scans'
    edges to every scan placed before them, scans still pending, placed scans whose ``align`` answer was
    ``likely_wrong`` or failed ``visible``)."""
    placed = [s for s in range(len(scans)) if np.isfinite(poses[s, 0, 0])]
    pending = [s for s in range(len(scans)) if s not in placed]
    edges, doubtful = [], []
    grew = True
    while pending and grew:
        grew = False
        model, model_normals = merged(scans, poses, placed, voxel)
        for s in pending:
            a = alignment.align(scans[s].points, model, scans[s].normals, model_normals, params=params, cfg=cfg,
                                init="global", max_correspondence_distance=max_dist, seed=seed)
            residuals = scoring.plane_fit(scans[s].points, model, model_normals, a.transform,
                                          a.correspondences).residuals
            if accept(a.fitness, np.median(np.abs(residuals)) if len(residuals) else np.inf,
                      scoring.balanced_fitness(scans[s].normals, a.correspondences[:, 0])):
                found = [edges_lib.measure(scans, s, o, np.linalg.inv(poses[o]) @ a.transform, max_dist, "global")
                         for o in placed]
                seen_through = visible is not None and not all(visible(e) for e in found)
                poses[s] = a.transform
                # reported; the robust graph still decides on the edges
                doubtful += [s] if a.likely_wrong or seen_through else []
                edges += found
                placed.append(s)
                pending.remove(s)
                tick(len(placed), len(scans))
                grew = True
                break  # the model grew: merge again before the next scan
    return poses, edges, pending, doubtful
