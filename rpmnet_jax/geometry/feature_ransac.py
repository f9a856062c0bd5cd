"""Classical global hypotheses: FPFH correspondences and RANSAC over 3-point samples, verified in one batched,
jitted call (Open3D's ``registration_ransac_based_on_feature_matching``, with its mutual filter, edge-length
and distance checkers, made batch-parallel instead of sequential).

Rotation-invariant features make these hypotheses independent of the starting orientation, which the
network (trained on rotations of up to 45° per axis) is not; :func:`rpmnet_jax.align` refines them
beside the network's answers and lets its selection score decide.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from rpmnet_jax.ops import procrustes, se3
from rpmnet_jax.geometry import fpfh


class Hypotheses(NamedTuple):
    """Distinct RANSAC answers, best first."""

    transforms: np.ndarray  # (H, 4, 4): map source onto reference
    inliers: np.ndarray  # (H,) correspondences within the distance, of ``num_correspondences``
    num_correspondences: int


def nearest_rows(queries: np.ndarray, rows: np.ndarray, chunk: int = 2048) -> np.ndarray:
    """``(Q,)`` index of each query's nearest row (Euclidean) among ``rows (R, D)``, by brute force as
    ``|r|² - 2 q·r`` in ``chunk``-row blocks: 5x faster than a k-d tree in FPFH's 33 dimensions (1,024 points)."""
    queries, rows = np.asarray(queries, np.float64), np.asarray(rows, np.float64)
    sq = np.einsum("rd,rd->r", rows, rows)
    return np.concatenate([np.argmin(sq[None] - 2.0 * (queries[i:i + chunk] @ rows.T), axis=1)
                           for i in range(0, len(queries), chunk)])


def mutual_correspondences(src_features: np.ndarray, ref_features: np.ndarray) -> np.ndarray:
    """``(C, 2)`` (source, reference) index pairs that are each other's nearest neighbour in feature space;
    all source → reference nearest pairs when fewer than 3 are mutual (as Open3D's mutual filter)."""
    to_ref = nearest_rows(src_features, ref_features)
    to_src = nearest_rows(ref_features, src_features)
    src_idx = np.arange(len(src_features))
    mutual = to_src[to_ref] == src_idx
    keep = mutual if mutual.sum() >= 3 else np.ones_like(mutual)
    return np.stack([src_idx[keep], to_ref[keep]], axis=1)


MIN_INLIERS = 3  # a hypothesis must bring at least its own sample's correspondences within the distance


def _bucket(n: int) -> int:
    """Padded size for ``n`` correspondences (few distinct compiled shapes)."""
    return max(64, 1 << int(np.ceil(np.log2(max(n, 1)))))


def _moved_sq_distances(t, src_c, ref_c):
    """``|R_m s_c + t_m - r_c|² (M, C)`` for transforms ``t (M, 3, 4)`` and pairs ``src_c, ref_c (C, 3)``, as one
    ``(M, 15) @ (15, C)`` product (|s|² + |r|² + |t|² + 2 (Rᵀt)·s - 2 t·r - 2 vec(R)·vec(r sᵀ)) instead of
    materialising the ``(M, C, 3)`` moved points: 5x faster on the CPU (4,096 samples, 512 pairs)."""
    rot, trans = t[:, :, :3], t[:, :, 3]
    per_t = jnp.concatenate([rot.reshape(-1, 9), jnp.einsum("mji,mj->mi", rot, trans), trans], axis=1)  # (M, 15)
    per_c = jnp.concatenate([-2.0 * (ref_c[:, :, None] * src_c[:, None, :]).reshape(-1, 9), 2.0 * src_c,
                             -2.0 * ref_c], axis=1)  # (C, 15)
    # full float32 products: the terms cancel to ~0.0056 near the threshold, TF32 (a GPU's default) loses it
    return (jnp.matmul(per_t, per_c.T, precision=jax.lax.Precision.HIGHEST) + jnp.sum(trans**2, -1)[:, None]
            + (jnp.sum(src_c**2, -1) + jnp.sum(ref_c**2, -1))[None])


@jax.jit
def _score_samples(src_c, ref_c, valid, samples, max_distance):
    """Transforms ``(M, 3, 4)`` of 3-point samples ``(M, 3)`` of correspondences ``src_c, ref_c (C, 3)``
    (``valid (C,)`` marks the unpadded ones) and their inlier counts ``(M,)``, -1 where the sample's own points
    do not land within ``max_distance`` (Open3D's distance checker)."""
    a, b = src_c[samples], ref_c[samples]  # (M, 3, 3)
    t = procrustes.weighted_procrustes(a, b, jnp.ones(a.shape[:2], a.dtype))
    moved = se3.apply(t, a)
    dist_ok = jnp.all(jnp.linalg.norm(moved - b, axis=-1) <= max_distance, axis=-1)
    close = _moved_sq_distances(t, src_c, ref_c) <= max_distance**2  # (M, C)
    inliers = jnp.sum(close & valid[None], axis=-1)
    return t, jnp.where(dist_ok, inliers, -1)


def _edge_lengths_agree(a: np.ndarray, b: np.ndarray, edge_ratio: float) -> np.ndarray:
    """Open3D's edge-length checker on 3-point samples ``a, b (M, 3, 3)``: ``(M,)`` whether every edge of one
    triangle is at least ``edge_ratio`` of the other's."""
    edges = lambda p: np.linalg.norm(p - np.roll(p, 1, axis=1), axis=-1)  # (M, 3)
    ea, eb = edges(a), edges(b)
    return np.all((ea >= edge_ratio * eb) & (eb >= edge_ratio * ea), axis=-1)


def ransac_hypotheses(src: np.ndarray, ref: np.ndarray, correspondences: np.ndarray, max_distance: float, *,
                      samples: int = 8192, edge_ratio: float = 0.9, top_k: int = 4, min_angle_deg: float = 45.0,
                      seed: int = 0, chunk: int = 2048) -> Hypotheses:
    """The ``top_k`` best RANSAC transforms of ``src, ref (·, 3)`` from ``correspondences (C, 2)``, each at
    least ``min_angle_deg`` from the better ones (a symmetric shape's flip survives beside the truth).

    ``samples`` random 3-point samples are drawn (``seed``); a sample whose edge lengths disagree by more than
    ``edge_ratio`` is rejected before it is solved (NumPy), one whose points do not land within
    ``max_distance`` after (in the batched, jitted solve of ``chunk`` samples); the rest are ranked by how
    many correspondences they bring within ``max_distance``.
    """
    c = len(correspondences)
    if c < 3:
        return Hypotheses(np.zeros((0, 4, 4)), np.zeros((0,), np.int64), c)
    size = _bucket(c)
    src_c = np.zeros((size, 3), np.float32)
    ref_c = np.zeros((size, 3), np.float32)
    src_c[:c] = src[correspondences[:, 0]]
    ref_c[:c] = ref[correspondences[:, 1]]
    valid = np.arange(size) < c
    rng = np.random.default_rng(seed)
    draws = rng.integers(0, c, (samples, 3))  # (M, 3); samples that repeat a correspondence are dropped
    repeated = (draws[:, 0] == draws[:, 1]) | (draws[:, 1] == draws[:, 2]) | (draws[:, 0] == draws[:, 2])
    passing = np.flatnonzero(~repeated & _edge_lengths_agree(src[correspondences[draws, 0]],
                                                             ref[correspondences[draws, 1]], edge_ratio))
    transforms = np.zeros((samples, 3, 4))
    scores = np.full(samples, -1, np.int64)
    for start in range(0, len(passing), chunk):  # only the samples the cheap checker passes are solved
        part = passing[start:start + chunk]
        padded = np.concatenate([part, np.repeat(part[:1], chunk - len(part))])  # one compiled shape
        t, s = _score_samples(src_c, ref_c, valid, draws[padded].astype(np.int32), np.float32(max_distance))
        transforms[part] = np.asarray(t, np.float64)[:len(part)]
        scores[part] = np.asarray(s)[:len(part)]
    order = np.argsort(-scores, kind="stable")
    ranked = order[scores[order] >= MIN_INLIERS]
    picked = ranked[se3.distinct_rotations(transforms[ranked, :, :3], min_angle_deg, top_k)]
    out = se3.to_homogeneous(transforms[picked]) if len(picked) else np.zeros((0, 4, 4))
    return Hypotheses(out, scores[picked].astype(np.int64), c)


def from_clouds(src, src_normals, ref, ref_normals, max_distance: float = 0.075, radius: float = 0.3,
                max_nn: int = 128, seed: int = 0, **kwargs) -> Hypotheses:
    """:func:`ransac_hypotheses` from FPFH correspondences of ``src, ref (·, 3)`` with normals; defaults are
    Open3D's tutorial recipe on unit-sphere clouds (FPFH radius 0.3, 128 neighbours; distance 0.075)."""
    corr = mutual_correspondences(fpfh.fpfh(src, src_normals, radius, max_nn),
                                  fpfh.fpfh(ref, ref_normals, radius, max_nn))
    return ransac_hypotheses(src, ref, corr, max_distance, seed=seed, **kwargs)
