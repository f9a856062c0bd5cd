"""The network's global search: started from rotation hypotheses that cover SO(3), in one batched call.

The network registers reliably only inside a basin around the identity (it was trained on rotations of up to
45° per Euler axis; ``python -m experiments.basin`` measures it). A finite rotation group whose covering
radius lies inside that basin puts every rotation within reach of at least one hypothesis: the
icosahedral group (60 rotations) leaves no rotation farther than 44.3° from one of them, the octahedral
group (24) no farther than 62.7°. Every hypothesis runs through :func:`rpmnet_jax.registration.register_from`
(reference features and source neighbourhoods computed once); each answer is polished by a short ICP and
ranked by :func:`rpmnet_jax.pairwise.candidates.selection_score` (:func:`screen_hypotheses`).
"""

from __future__ import annotations

import functools

import numpy as np

from rpmnet_jax.classical import icp
from rpmnet_jax.geometry import sampling
from rpmnet_jax.ops import se3
from rpmnet_jax.pairwise import candidates, options as options_lib, prepare, starts



HYPOTHESES_A_CALL = 6  # rotation starts a network call: 24 (or 60) at once held ~490 MB of activations at 256 points
# (a site's placement: the run's peak); both groups' sizes divide by it, so one compiled shape


@functools.lru_cache(maxsize=None)
def rotation_hypotheses(kind: str = "icosahedral") -> np.ndarray:
    """``(H, 3, 3)`` rotations of a finite group (the identity first): 60 icosahedral or 24 octahedral."""
    from scipy.spatial.transform import Rotation

    if kind not in options_lib.HYPOTHESIS_SETS:
        raise ValueError(f"hypotheses must be one of {sorted(options_lib.HYPOTHESIS_SETS)}, got {kind!r}")
    mats = Rotation.create_group(options_lib.HYPOTHESIS_SETS[kind]).as_matrix()
    first = int(np.argmin(np.linalg.norm(mats - np.eye(3), axis=(1, 2))))
    order = [first] + [i for i in range(len(mats)) if i != first]
    out = mats[order]
    out.setflags(write=False)
    return out


def initial_transforms(kind: str = "icosahedral") -> np.ndarray:
    """``(H, 3, 4)`` float32 starts ``[R_h | 0]`` for :func:`rpmnet_jax.registration.register_from`.

    The clouds are centred on their own centroids before registration, so rotating about the origin keeps
    the source where the network expects it.
    """
    rots = rotation_hypotheses(kind)
    return np.concatenate([rots, np.zeros((len(rots), 3, 1))], axis=2).astype(np.float32)


def screen_hypotheses(params, pair: prepare.PreparedPair, dense: prepare.DenseClouds, cfg,
                      opts: options_lib.GlobalOptions, max_dist_unit: float, seed: int) -> list:
    """Runs every rotation hypothesis through ``opts.iters`` network iterations on ``opts.points`` of each
    cloud (one batched call), polishes each answer with a short ICP on ``opts.polish_points`` source points,
    and returns the ``opts.top_k`` :class:`~rpmnet_jax.pairwise.starts.Start` s by selection score (polished),
    best first. (A network answer a few degrees off scores a low fitness at a tight threshold; the short ICP
    makes the scores of right answers comparable.)"""
    from rpmnet_jax import registration  # JAX: imported when the network runs, not by the classical path

    rng = np.random.default_rng(seed)
    src = pair.src6[:, sampling.sample_indices(rng, pair.src6.shape[1], opts.points)]
    ref = pair.ref6[:, sampling.sample_indices(rng, pair.ref6.shape[1], opts.points)]
    fn = registration.jitted(cfg, int(opts.iters), _transforms_and_confidence, from_starts=True)
    inits = initial_transforms(opts.hypotheses)
    parts = [fn(params, src, ref, inits[k:k + HYPOTHESES_A_CALL]) for k in range(0, len(inits), HYPOTHESES_A_CALL)]
    nets = np.swapaxes(np.concatenate([np.asarray(t, np.float64) for t, _ in parts], axis=1), 0, 1)  # (H, I, 3, 4)
    confidences = np.concatenate([np.asarray(c, np.float64) for _, c in parts])
    few = dense._replace(src=dense.src[sampling.sample_indices(rng, len(dense.src), opts.polish_points)])
    polished, scores = [], []
    for t in nets[:, -1]:
        r = icp.point_to_plane_icp(few.src, few.ref, few.ref_normals, se3.to_homogeneous(t), max_dist_unit,
                                   scales=icp.SCREEN.scales, max_iterations=icp.SCREEN.max_iterations,
                                   ref_tree=few.ref_tree)
        polished.append(r.transform[:3])
        scores.append(candidates.selection_score(few, r.transform, max_dist_unit))
    order = sorted(range(len(nets)), key=lambda h: scores[h], reverse=True)[:opts.top_k]
    return [starts.Start("global", nets[h], float(confidences[h]), polished[h]) for h in order]


def _transforms_and_confidence(reg):
    """The network's transforms ``(I, H, 3, 4)`` and confidences ``(H,)`` of a batched run (what the screen
    keeps: the per-iteration match matrices of every hypothesis are never materialised)."""
    return reg.transforms, starts.confidence(reg.perm_matrices[-1])
