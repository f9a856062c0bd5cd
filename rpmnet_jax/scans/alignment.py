"""Register your own point clouds: any units, any size, any orientation, normals optional.

The pipeline around the paper's network (which itself is :func:`rpmnet_jax.register`, untouched):

1. prepare: clean, centre each cloud, scale both into the unit sphere, sample ``num_points`` per cloud for the
   network (:mod:`rpmnet_jax.scans.prepare`);
2. start: ``init="local"`` runs the network once from the identity; ``init="global"`` runs it from the
   rotation hypotheses of :mod:`rpmnet_jax.scans.global_search` in one batched call, polishes each answer
   with a short ICP and keeps the ``top_k`` best; ``init="auto"`` (default) is local, and global only when
   the refined local answer's fitness is below ``auto_fitness``;
3. refine: ``refine="icp"`` (default) runs robust point-to-plane ICP (:mod:`rpmnet_jax.scans.refine`) from
   each start on denser samples of the caller's clouds (``refine_points`` source and ``4 × refine_points``
   reference points, random); the answer with the best :func:`_selection_score` wins; ``refine="none"``
   returns the network's answer as it is (the paper's method);
4. score: fitness, inlier RMSE and correspondences of the answer on the full clouds, as Open3D's
   ``evaluate_registration`` (:mod:`rpmnet_jax.scans.scoring`).

``max_correspondence_distance`` (caller's units) is the inlier threshold of the score and the finest ICP
gate; by default 5% of the clouds' common radius (the largest distance of a point from its cloud's centre):
0.05 on the unit-sphere shapes the network was trained on (measured on 40 real ModelNet40 partial pairs, the
refined error is 0.86° / 0.57° / 0.53° / 0.69° mean at 0.03 / 0.05 / 0.08 / 0.12).
"""

from __future__ import annotations

import functools
import time
from typing import NamedTuple

import jax
import numpy as np
from scipy.spatial import cKDTree

from rpmnet_jax import config as config_lib
from rpmnet_jax import registration
from rpmnet_jax.ops import se3
from rpmnet_jax.scans import global_search, refine as refine_lib, scoring
from rpmnet_jax.scans import normals as normals_lib
from rpmnet_jax.scans.prepare import PreparedPair, prepare_pair
from rpmnet_jax.weights import loading

INITS = ("auto", "local", "global")
REFINES = ("icp", "none")
DEFAULT_RELATIVE_DISTANCE = 0.05


class Alignment(NamedTuple):
    transform: np.ndarray  # (4, 4): maps source points onto the reference, caller's units
    aligned: np.ndarray  # (N, 3): the full source cloud moved by ``transform``
    transforms: np.ndarray  # (I, 4, 4): the network's per-iteration transforms (of the chosen start)
    confidence: float  # mean inlier mass of the network's last match matrix, in [0, 1]
    num_points: tuple[int, int]  # points the network saw, source and reference
    fitness: float  # fraction of source points with a reference point within max_correspondence_distance
    inlier_rmse: float  # RMS distance of those pairs, caller's units
    correspondences: np.ndarray  # (n, 2): (source index, reference index) of the inlier pairs
    converged: bool  # the refinement met its tolerance (True for refine="none")
    num_iterations: int  # refinement iterations (0 for refine="none")
    max_correspondence_distance: float  # the threshold used, caller's units
    init: str  # the start that won: "local" or "global"
    timings: dict  # seconds per stage: prepare, network, global, refine, score, total


def _sample(rng: np.random.Generator, n_total: int, n: int) -> np.ndarray:
    return np.arange(n_total) if n_total <= n else np.sort(rng.choice(n_total, n, replace=False))


class _DenseClouds(NamedTuple):
    """Denser samples of both clouds in the normalised frame, for refinement and scoring of candidates."""

    src: np.ndarray  # (n, 3)
    ref: np.ndarray  # (m, 3)
    ref_normals: np.ndarray  # (m, 3)
    ref_tree: cKDTree


def _dense_clouds(pair: PreparedPair, refine_points: int, seed: int) -> _DenseClouds:
    rng = np.random.default_rng(seed + 1)
    i_src = _sample(rng, len(pair.src), refine_points)
    i_ref = _sample(rng, len(pair.ref), 4 * refine_points)
    src = pair.to_unit(pair.src[i_src], "src")
    ref = pair.to_unit(pair.ref[i_ref], "ref")
    normals = pair.ref_normals[i_ref] if pair.ref_normals is not None else normals_lib.estimate_normals(ref)
    return _DenseClouds(src, ref, normals, cKDTree(ref))


SELECT_FRACTION = 0.4  # refined candidates are compared by their fitness at this fraction of the threshold


def _selection_score(dense: _DenseClouds, t44: np.ndarray, max_distance: float) -> tuple:
    """``(fitness at 0.4 × max_distance, fitness at max_distance, -RMSE)``, larger is better.

    The tight threshold tells a right answer from a symmetric flip: on partial, noisy shapes the flip
    often overlaps *more* at ``max_distance`` but lies on the surface less closely (measured on real
    ModelNet40 pairs at any rotation: all 6 of 30 pairs where the plain fitness chose a 160–180° flip
    are decided for the truth at 0.3–0.6 × the threshold).
    """
    s = scoring.evaluate_registration(dense.src, dense.ref, t44, max_distance, ref_tree=dense.ref_tree)
    tight = np.count_nonzero(s.distances <= SELECT_FRACTION * max_distance) / len(dense.src)
    return tight, s.fitness, -s.inlier_rmse


def _check_options(init, refine, num_iters, top_k, refine_points, global_points, global_iters,
                   max_correspondence_distance, auto_fitness):
    if init not in INITS:
        raise ValueError(f"init must be one of {INITS}, got {init!r}")
    if refine not in REFINES:
        raise ValueError(f"refine must be one of {REFINES}, got {refine!r}")
    if num_iters < 1:
        raise ValueError(f"num_iters must be >= 1, got {num_iters}")
    if top_k < 1:
        raise ValueError(f"top_k must be >= 1, got {top_k}")
    if refine_points < 3 or global_points < 3:
        raise ValueError(f"refine_points and global_points must be >= 3, got {refine_points}, {global_points}")
    if global_iters < 1:
        raise ValueError(f"global_iters must be >= 1, got {global_iters}")
    if max_correspondence_distance is not None and not max_correspondence_distance > 0:
        raise ValueError(f"max_correspondence_distance must be > 0, got {max_correspondence_distance}")
    if not 0.0 <= auto_fitness <= 1.0:
        raise ValueError(f"auto_fitness must be in [0, 1], got {auto_fitness}")


def align(src_points, ref_points, src_normals=None, ref_normals=None, *, checkpoint=None, params=None,
          num_points: int = 1024, num_iters: int = 5, sampling: str = "random", seed: int = 0,
          reestimate_normals: bool = False, centering: str = "separate", init: str = "auto",
          refine: str = "icp", max_correspondence_distance: float | None = None, hypotheses: str = "octahedral",
          top_k: int = 3, global_points: int = 256, global_iters: int = 2, refine_points: int = 5000,
          auto_fitness: float = 0.6,
          cfg: config_lib.RPMNetConfig | None = None) -> Alignment:
    """Rigidly aligns ``src_points (N, 3)`` onto ``ref_points (M, 3)``; see the module docstring.

    Normals (``(N, 3)``, any length > 0) are estimated when missing or when ``reestimate_normals``.
    ``checkpoint``: orbax dir, ``.npz`` or official ``.pth``; default the shipped model (or pass ``params``).
    ``sampling``: ``random`` or ``fps`` down to ``num_points`` per cloud for the network. ``centering``:
    ``separate`` (each cloud on its centroid) or ``common`` (both on their joint centroid). ``hypotheses``:
    ``icosahedral`` (60) or ``octahedral`` (24) starts for the global search, screened with ``global_iters``
    network iterations on ``global_points`` per cloud and a short ICP; the ``top_k`` best are refined.
    Deterministic for a ``seed``.
    """
    _check_options(init, refine, num_iters, top_k, refine_points, global_points, global_iters,
                   max_correspondence_distance, auto_fitness)
    t_start = time.perf_counter()
    timings = {"prepare": 0.0, "network": 0.0, "global": 0.0, "refine": 0.0, "score": 0.0}
    pair = prepare_pair(src_points, ref_points, src_normals, ref_normals, num_points=num_points,
                        sampling=sampling, seed=seed, reestimate_normals=reestimate_normals, centering=centering)
    params = params if params is not None else loading.load_params(checkpoint)
    cfg = cfg or config_lib.RPMNetConfig()
    max_dist = (max_correspondence_distance if max_correspondence_distance is not None
                else DEFAULT_RELATIVE_DISTANCE * pair.scale)
    max_dist_unit = max_dist / pair.scale
    dense = _dense_clouds(pair, refine_points, seed) if (refine == "icp" or init != "local") else None
    timings["prepare"] = time.perf_counter() - t_start

    # candidates: (name, network transforms (I, 3, 4), confidence, start (3, 4))
    candidates = []
    if init in ("local", "auto"):
        t0 = time.perf_counter()
        reg = registration.jitted(cfg, int(num_iters))(params, pair.src6, pair.ref6)
        perm = np.asarray(reg.perm_matrices[-1, 0])
        net_ts = np.asarray(reg.transforms[:, 0], np.float64)
        candidates.append(("local", net_ts, float(confidence(perm)), net_ts[-1]))
        timings["network"] = time.perf_counter() - t0

    def refined(cands):
        out = []
        t0 = time.perf_counter()
        for name, ts, conf, start in cands:
            start = se3.to_homogeneous(start)
            if refine == "icp":
                r = refine_lib.point_to_plane_icp(dense.src, dense.ref, dense.ref_normals, start, max_dist_unit,
                                                  ref_tree=dense.ref_tree)
                final, converged, iters = r.transform, r.converged, r.num_iterations
            else:
                final, converged, iters = start, True, 0
            score = _selection_score(dense, final, max_dist_unit) if dense is not None else (1.0, 1.0, 0.0)
            out.append((score, name, ts, conf, final, converged, iters))
        timings["refine"] += time.perf_counter() - t0
        return out

    results = refined(candidates)
    if init == "global" or (init == "auto" and results[0][0][1] < auto_fitness):
        t0 = time.perf_counter()
        screened = _screen_hypotheses(params, pair, dense, cfg, hypotheses, global_points, global_iters,
                                      max_dist_unit, top_k)
        timings["global"] = time.perf_counter() - t0
        results += refined([("global", ts, conf, start if refine == "icp" else ts[-1])
                            for ts, conf, start in screened])

    best = max(results, key=lambda r: r[0])  # the first of equals: local before global
    _, name, net_ts, conf, final_unit, converged, iters = best
    transform = pair.to_callers_units(final_unit[:3])
    t0 = time.perf_counter()
    score = scoring.evaluate_registration(pair.src, pair.ref, transform, max_dist)
    timings["score"] = time.perf_counter() - t0
    timings["total"] = time.perf_counter() - t_start
    aligned = pair.src @ transform[:3, :3].T + transform[:3, 3]
    return Alignment(transform, aligned, pair.to_callers_units(net_ts), conf,
                     (pair.src6.shape[1], pair.ref6.shape[1]), score.fitness, score.inlier_rmse,
                     score.correspondences, converged, iters, float(max_dist), name, timings)


def _screen_hypotheses(params, pair: PreparedPair, dense: _DenseClouds, cfg, hypotheses: str, num_points: int,
                       num_iters: int, max_dist_unit: float, top_k: int, polish_points: int = 1000) -> list:
    """Runs every rotation hypothesis through ``num_iters`` network iterations on ``num_points`` of each
    cloud (one batched call), polishes each answer with a short ICP on ``polish_points`` source points, and
    returns the ``top_k`` by :func:`_selection_score` as ``[(network transforms (I, 3, 4), confidence,
    polished (3, 4))]``, best first. (A network answer a few degrees off scores a low fitness at a tight
    threshold; the short ICP makes the scores of right answers comparable.)"""
    starts = global_search.initial_transforms(hypotheses)
    rng = np.random.default_rng(0)
    src = pair.src6[:, _sample(rng, pair.src6.shape[1], num_points)]
    ref = pair.ref6[:, _sample(rng, pair.ref6.shape[1], num_points)]
    transforms, confidences = _screen_fn(cfg, int(num_iters))(params, src, ref, starts)
    nets = np.swapaxes(np.asarray(transforms, np.float64), 0, 1)  # (H, I, 3, 4)
    confidences = np.asarray(confidences, np.float64)
    few = dense.src[_sample(rng, len(dense.src), polish_points)]
    polished, scores = [], []
    for t in nets[:, -1]:
        r = refine_lib.point_to_plane_icp(few, dense.ref, dense.ref_normals, se3.to_homogeneous(t), max_dist_unit,
                                          scales=(4.0, 2.0), max_iterations=8, ref_tree=dense.ref_tree)
        polished.append(r.transform[:3])
        scores.append(_selection_score(dense._replace(src=few), r.transform, max_dist_unit))
    order = sorted(range(len(nets)), key=lambda h: scores[h], reverse=True)[:top_k]
    return [(nets[h], float(confidences[h]), polished[h]) for h in order]


@functools.lru_cache(maxsize=None)
def _screen_fn(cfg, num_iters: int):
    """Jitted hypotheses run returning only the transforms ``(I, H, 3, 4)`` and the confidences ``(H,)`` (the
    per-iteration match matrices of every hypothesis are never materialised)."""

    def run(params, src, ref, starts):
        reg = registration.register_from(params, src, ref, starts, cfg, num_iters)
        return reg.transforms, confidence(reg.perm_matrices[-1])
    return jax.jit(run)


def confidence(perm):
    """Mean inlier mass of match matrices ``perm (..., J, K)`` → ``(...)``: the mean of the row and column
    sums (NumPy or JAX)."""
    return 0.5 * (perm.sum(axis=-1).mean(axis=-1) + perm.sum(axis=-2).mean(axis=-1))
