"""Where :func:`rpmnet_jax.align`'s refinement starts, in the normalised frame: the network once from the
identity (:func:`local_start`) and the classical FPFH + RANSAC hypotheses (:func:`classical_starts`); the
network's global search over rotation hypotheses is :mod:`rpmnet_jax.pairwise.global_search`."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from rpmnet_jax.geometry import feature_ransac
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


def classical_starts(pair: prepare.PreparedPair, count: int, seed: int) -> list:
    """Up to ``count`` FPFH + RANSAC hypotheses on the network's samples (unit-sphere frame, Open3D's recipe)
    as :class:`Start` s; each hypothesis is its own single iterate, its confidence the share of feature
    correspondences it brings within the distance."""
    src, ref = np.asarray(pair.src6[0], np.float64), np.asarray(pair.ref6[0], np.float64)
    hyp = feature_ransac.from_clouds(src[:, :3], src[:, 3:], ref[:, :3], ref[:, 3:], seed=seed, top_k=count)
    share = hyp.inliers / max(hyp.num_correspondences, 1)
    keep = hyp.inliers >= CLASSICAL_KEEP * hyp.inliers.max(initial=0)  # a flip stays; stray samples do not
    return [Start("classical", t[None, :3], float(c), t) for t, c, k in zip(hyp.transforms, share, keep) if k]


def confidence(perm):
    """Mean inlier mass of match matrices ``perm (..., J, K)`` → ``(...)``: the mean of the row and column
    sums (NumPy or JAX)."""
    return 0.5 * (perm.sum(axis=-1).mean(axis=-1) + perm.sum(axis=-2).mean(axis=-1))
