"""The starts of :func:`rpmnet_jax.align`'s refinement, in the normalised frame: the network from the identity
(:func:`local_start`), the classical FPFH + RANSAC hypotheses (:func:`classical_starts`), the network's global
screen over rotation hypotheses (:func:`screen_hypotheses`); and the denser samples of both clouds that
refinement and selection use (:func:`dense_clouds`, :func:`selection_score`)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree

from rpmnet_jax import registration
from rpmnet_jax.ops import se3
from rpmnet_jax.scans import feature_ransac, global_search, options as options_lib, prepare, refine as refine_lib
from rpmnet_jax.scans import scoring
from rpmnet_jax.scans import normals as normals_lib


class Start(NamedTuple):
    """A start to refine (a network answer or a classical hypothesis), in the normalised frame."""

    init: str  # "local", "classical" or "global"
    network_transforms: np.ndarray  # (I, 3, 4): the network's iterates from this start (a classical one: itself)
    confidence: float  # mean inlier mass of the network's last match matrix
    transform: np.ndarray  # (3, 4) or (4, 4): where the refinement starts


class DenseClouds(NamedTuple):
    """Denser samples of both clouds in the normalised frame, for refinement and scoring of candidates."""

    src: np.ndarray  # (n, 3)
    ref: np.ndarray  # (m, 3)
    ref_normals: np.ndarray  # (m, 3)
    ref_tree: cKDTree
    src_normals: np.ndarray  # (n, 3): for the ICP's symmetric planes (lines only: signs need not agree)


REFERENCE_FACTOR = 20  # the ICP's reference: up to this many times its source points (all of most scans)
# (a random 2/3 of a reference widens its nearest-neighbour gaps: the Stanford bunny's bun180 onto bun090, 54%
# overlap, ended 1.3-2.4 deg off from its answer with 5,000 source points on 20,000 of the reference's 30,379,
# 0.21-0.26 deg on all of them)


def dense_clouds(pair: prepare.PreparedPair, refine_points: int, seed: int,
                 full_ref_tree: cKDTree | None = None) -> DenseClouds:
    """Random samples of the non-stray points: ``refine_points`` of the source, ``REFERENCE_FACTOR`` × as
    many of the reference (unoriented normals estimated where missing, from the neighbours in the full cloud:
    point-to-plane ICP needs only their lines; ``full_ref_tree``: a k-d tree of ``pair.ref`` to reuse)."""
    rng = np.random.default_rng(seed + 1)
    core_src, core_ref = np.flatnonzero(pair.src_core), np.flatnonzero(pair.ref_core)
    i_src = core_src[prepare.sample_indices(rng, len(core_src), refine_points)]
    i_ref = core_ref[prepare.sample_indices(rng, len(core_ref), REFERENCE_FACTOR * refine_points)]
    src = pair.to_unit(pair.src[i_src], "src")
    ref = pair.to_unit(pair.ref[i_ref], "ref")
    normals = (pair.ref_normals[i_ref] if pair.ref_normals is not None
               else normals_lib.normals_at(pair.ref, i_ref, tree=full_ref_tree))
    src_normals = (pair.src_normals[i_src] if pair.src_normals is not None
                   else normals_lib.normals_at(pair.src, i_src))
    return DenseClouds(src, ref, normals, cKDTree(ref), src_normals)


SELECT_FRACTION = 0.4  # refined candidates are compared by their fitness at this fraction of the threshold


def selection_score(dense: DenseClouds, t44: np.ndarray, max_distance: float) -> tuple:
    """``(fitness at 0.4 × max_distance, fitness at max_distance, -RMSE)``, larger is better.

    The tight threshold tells a right answer from a symmetric flip: on partial, noisy shapes the flip
    often overlaps *more* at ``max_distance`` but lies on the surface less closely (measured on real
    ModelNet40 pairs at any rotation: all 6 of 30 pairs where the plain fitness chose a 160–180° flip
    are decided for the truth at 0.3–0.6 × the threshold).
    """
    s = scoring.evaluate_registration(dense.src, dense.ref, t44, max_distance, ref_tree=dense.ref_tree)
    tight = np.count_nonzero(s.distances <= SELECT_FRACTION * max_distance) / len(dense.src)
    return tight, s.fitness, -s.inlier_rmse


def local_start(params, pair: prepare.PreparedPair, cfg, num_iters: int) -> Start:
    """The network once from the identity (the paper's method) as a :class:`Start`."""
    reg = registration.jitted(cfg, int(num_iters))(params, pair.src6, pair.ref6)
    perm = np.asarray(reg.perm_matrices[-1, 0])
    net_ts = np.asarray(reg.transforms[:, 0], np.float64)
    return Start("local", net_ts, float(confidence(perm)), net_ts[-1])


def screen_hypotheses(params, pair: prepare.PreparedPair, dense: DenseClouds, cfg,
                       opts: options_lib.GlobalOptions, max_dist_unit: float, seed: int) -> list:
    """Runs every rotation hypothesis through ``opts.iters`` network iterations on ``opts.points`` of each
    cloud (one batched call), polishes each answer with a short ICP on ``opts.polish_points`` source points,
    and returns the ``opts.top_k`` :class:`Start` s by :func:`selection_score` (polished), best first. (A
    network answer a few degrees off scores a low fitness at a tight threshold; the short ICP makes the
    scores of right answers comparable.)"""
    starts = global_search.initial_transforms(opts.hypotheses)
    rng = np.random.default_rng(seed)
    src = pair.src6[:, prepare.sample_indices(rng, pair.src6.shape[1], opts.points)]
    ref = pair.ref6[:, prepare.sample_indices(rng, pair.ref6.shape[1], opts.points)]
    fn = registration.jitted(cfg, int(opts.iters), _transforms_and_confidence, from_starts=True)
    transforms, confidences = fn(params, src, ref, starts)
    nets = np.swapaxes(np.asarray(transforms, np.float64), 0, 1)  # (H, I, 3, 4)
    confidences = np.asarray(confidences, np.float64)
    few = dense.src[prepare.sample_indices(rng, len(dense.src), opts.polish_points)]
    polished, scores = [], []
    for t in nets[:, -1]:
        r = refine_lib.point_to_plane_icp(few, dense.ref, dense.ref_normals, se3.to_homogeneous(t), max_dist_unit,
                                          scales=(4.0, 2.0), max_iterations=8, ref_tree=dense.ref_tree)
        polished.append(r.transform[:3])
        scores.append(selection_score(dense._replace(src=few), r.transform, max_dist_unit))
    order = sorted(range(len(nets)), key=lambda h: scores[h], reverse=True)[:opts.top_k]
    return [Start("global", nets[h], float(confidences[h]), polished[h]) for h in order]


CLASSICAL_KEEP = 0.3  # classical hypotheses with fewer inliers than this share of the best one's are not refined


def classical_starts(pair: prepare.PreparedPair, count: int, seed: int) -> list:
    """Up to ``count`` FPFH + RANSAC hypotheses on the network's samples (unit-sphere frame, Open3D's recipe)
    as :class:`Start` s; each hypothesis is its own single iterate, its confidence the share of feature
    correspondences it brings within the distance."""
    src, ref = np.asarray(pair.src6[0], np.float64), np.asarray(pair.ref6[0], np.float64)
    hyp = feature_ransac.from_clouds(src[:, :3], src[:, 3:], ref[:, :3], ref[:, 3:], seed=seed, top_k=count)
    share = hyp.inliers / max(hyp.num_correspondences, 1)
    keep = hyp.inliers >= CLASSICAL_KEEP * hyp.inliers.max(initial=0)  # a flip stays; stray samples do not
    return [Start("classical", t[None, :3], float(c), t) for t, c, k in zip(hyp.transforms, share, keep) if k]


def _transforms_and_confidence(reg: registration.Registration):
    """The network's transforms ``(I, H, 3, 4)`` and confidences ``(H,)`` of a batched run (what the screen
    keeps: the per-iteration match matrices of every hypothesis are never materialised)."""
    return reg.transforms, confidence(reg.perm_matrices[-1])


def confidence(perm):
    """Mean inlier mass of match matrices ``perm (..., J, K)`` → ``(...)``: the mean of the row and column
    sums (NumPy or JAX)."""
    return 0.5 * (perm.sum(axis=-1).mean(axis=-1) + perm.sum(axis=-2).mean(axis=-1))
