"""Where :func:`rpmnet_jax.align`'s refinement starts, in the normalised frame: the network once from the
identity (:func:`local_start`) and the classical FPFH + RANSAC hypotheses (:func:`classical_starts`); the
network's global search over rotation hypotheses is :mod:`rpmnet_jax.pairwise.global_search`."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from rpmnet_jax.classical import feature_ransac
from rpmnet_jax.geometry import normals as normals_lib, sampling
from rpmnet_jax.pairwise import prepare


class Start(NamedTuple):
    """A start to refine (a network answer or a classical hypothesis), in the normalised frame."""

    init: str  # "local", "classical", "global" or "identity"
    network_transforms: np.ndarray  # (I, 3, 4): the network's iterates from this start (a classical one: itself)
    confidence: float  # network: mean inlier mass of its last match matrix; classical: share of inlier matches
    transform: np.ndarray  # (3, 4) or (4, 4): where the refinement starts


def identity_start() -> Start:
    """The clouds as they lie (``init="classical"`` or ``"global"`` when no hypothesis is found)."""
    return Start("identity", np.eye(4)[None, :3], 0.0, np.eye(4))


def local_start(params, pair: prepare.PreparedPair, cfg, num_iters: int) -> Start:
    """The network once from the identity (the paper's method) as a :class:`Start`."""
    from rpmnet_jax import registration  # JAX: imported when the network runs, not by the classical path
    reg = registration.jitted(cfg, int(num_iters))(params, pair.src6, pair.ref6)
    perm = np.asarray(reg.perm_matrices[-1, 0])
    net_ts = np.asarray(reg.transforms[:, 0], np.float64)
    return Start("local", net_ts, float(confidence(perm)), net_ts[-1])


CLASSICAL_KEEP = 0.3  # classical hypotheses with fewer inliers than this share of the best one's are not refined
# (for speed; chosen on 15 real pairs at any orientation, files not recorded, whose errors it kept: tuning data)
DENSE_FACTOR = 4  # clouds of at least this many times the network's samples (each) are dense: their hypotheses come
# from a voxel grid of the whole clouds (:func:`classical_starts`)
VOXEL = 0.03  # the grid's cube side in the normalised frame (the common radius is 1): ~3 mm on the Stanford bunny's
# scans, as Open3D's scan recipe; its FPFH radius 5 cubes (100 neighbours at most), RANSAC's distance 1.5 cubes
# (0.02, Open3D's 2 mm: as many of the bunny's 90 ordered pairs right, 46, and as many trusted, at 0.18-0.29 s
# for the classical stage of a 90-degree pair against 0.09-0.12 s). Chosen on the bunny's 90 ordered pairs (the six
# pairs of the bunny table among them; tuning data: numbers on that data are not held-out)
GRID_POINTS = 8_000  # at most this many grid points per cloud, a coarser grid beyond (a cluttered scene): the feature
# matching compares every pair of points (the bunny's scans, the real-scan benchmark's object, desk and LiDAR
# pairs and the room's stations: 2,000-3,000 each)


def classical_starts(pair: prepare.PreparedPair, count: int, seed: int) -> list:
    """Up to ``count`` FPFH + RANSAC hypotheses as :class:`Start` s; each hypothesis is its own single iterate, its
    confidence the share of feature correspondences it brings within the distance. On the network's samples
    (unit-sphere frame, Open3D's tutorial recipe), or, for dense clouds (:data:`DENSE_FACTOR`), on a voxel grid of
    the whole clouds (:data:`VOXEL`, Open3D's scan recipe): the six Stanford bunny pairs of the benchmark are all
    right from it, the two 90° ones settled without the network (0.23 s each against 2.5 s), where the
    1,024 samples gave a right answer to bun180 → bun090 at ``p_wrong`` 0.59 and a 45.7° wrong one to
    bun270 → bun180."""
    if dense(pair):
        ((src, src_n), (ref, ref_n)), voxel = _voxel_grids(pair)
        hyp = feature_ransac.from_clouds(src, src_n, ref, ref_n, max_distance=1.5 * voxel, radius=5 * voxel,
                                         max_nn=100, seed=seed, top_k=count)
    else:
        src, ref = np.asarray(pair.src6[0], np.float64), np.asarray(pair.ref6[0], np.float64)
        hyp = feature_ransac.from_clouds(src[:, :3], src[:, 3:], ref[:, :3], ref[:, 3:], seed=seed, top_k=count)
    share = hyp.inliers / max(hyp.num_correspondences, 1)
    keep = hyp.inliers >= CLASSICAL_KEEP * hyp.inliers.max(initial=0)  # a flip stays; stray samples do not
    return [Start("classical", t[None, :3], float(c), t) for t, c, k in zip(hyp.transforms, share, keep) if k]


def dense(pair: prepare.PreparedPair) -> bool:
    """Both clouds hold at least :data:`DENSE_FACTOR` × the network's samples of non-stray points: their classical
    hypotheses come from a voxel grid of the whole clouds (:func:`classical_starts`), and ``init="auto"`` keeps
    the classical answer (``GlobalOptions.network_on_dense``)."""
    least = min(np.count_nonzero(pair.src_core), np.count_nonzero(pair.ref_core))
    return least >= DENSE_FACTOR * len(pair.samples[0])


def _voxel_grids(pair: prepare.PreparedPair) -> tuple:
    """``([(points (V, 3), normals (V, 3)) of the source, of the reference], cube)``: the non-stray points of each
    cloud in the normalised frame, one per cube of :data:`VOXEL`, or of a coarser cube where a grid would hold more
    than :data:`GRID_POINTS` points (evenly spread, not a random subset of a fine grid; a surface's grid shrinks with
    the square of the cube: grown by that ratio's square root, 10% more each try), the same cube for both; normals
    estimated on the grids for both clouds alike (as Open3D's recipe). Not the caller's: a source with given normals
    beside a reference without (tests/register_test.py's pair) matched no true FPFH correspondence and ended on a
    180° flip of fitness 0.75, taken as strong."""
    clouds = [pair.to_unit(pair.src[pair.src_core], "src"), pair.to_unit(pair.ref[pair.ref_core], "ref")]
    voxel = VOXEL
    while True:
        grids = [sampling.voxel_downsample(c, None, voxel)[0] for c in clouds]
        most = max(len(g) for g in grids)
        if most <= GRID_POINTS:
            return [(g, normals_lib.estimate_normals(g)) for g in grids], voxel
        voxel *= 1.1 * np.sqrt(most / GRID_POINTS)


def confidence(perm):
    """Mean inlier mass of match matrices ``perm (..., J, K)`` → ``(...)``: the mean of the row and column
    sums (NumPy or JAX)."""
    return 0.5 * (perm.sum(axis=-1).mean(axis=-1) + perm.sum(axis=-2).mean(axis=-1))
