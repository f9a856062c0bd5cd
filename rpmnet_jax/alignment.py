"""Register your own point clouds: any units, any size, normals optional.

Each cloud is centred on its own centroid (or both on their common one, ``centering="common"``) and both
are scaled by one common factor into the unit sphere the model was trained on, downsampled, registered,
and the result is mapped back, so the returned 4×4 transform is rigid and in the caller's units. Separate
centring (the default) keeps the residual translation inside the range the model was trained on (0.5 of
the unit sphere per axis) even when the scans sit far apart in the caller's frame.
"""

from __future__ import annotations

import warnings
from typing import NamedTuple

import jax
import numpy as np

from rpmnet_jax import config as config_lib
from rpmnet_jax import normals as normals_lib
from rpmnet_jax import pretrained, registration


class Alignment(NamedTuple):
    transform: np.ndarray  # (4, 4): maps source points onto the reference, caller's units
    aligned: np.ndarray  # (N, 3): the full source cloud moved by ``transform``
    transforms: np.ndarray  # (I, 4, 4): per-iteration transforms, caller's units
    confidence: float  # mean inlier mass of the last match matrix, in [0, 1]
    num_points: tuple[int, int]  # points used for source and reference


def _clean(name: str, points, normals):
    points = np.asarray(points, np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"{name}: expected points of shape (N, 3), got {points.shape}")
    if normals is not None:
        normals = np.asarray(normals, np.float64)
        if normals.shape != points.shape:
            raise ValueError(f"{name}: normals {normals.shape} do not match points {points.shape}")
    finite = np.all(np.isfinite(points), axis=1)
    if normals is not None:
        finite &= np.all(np.isfinite(normals), axis=1)
    if not np.all(finite):
        dropped = int(np.sum(~finite))
        warnings.warn(f"{name}: dropped {dropped} points with NaN/inf values", stacklevel=3)
        points = points[finite]
        normals = None if normals is None else normals[finite]
    if len(points) < 3:
        raise ValueError(f"{name}: {len(points)} usable points; at least 3 are needed")
    sv = np.linalg.svd(points - points.mean(axis=0), compute_uv=False)
    if sv[0] <= 1e-12 * max(1.0, np.abs(points).max()) or sv[1] <= 1e-6 * sv[0]:
        raise ValueError(f"{name}: degenerate cloud (all points coincident or collinear)")
    if normals is not None:
        length = np.linalg.norm(normals, axis=1)
        if np.any(length < 1e-8):
            raise ValueError(f"{name}: {int(np.sum(length < 1e-8))} normals have zero length; "
                             "fix them or re-estimate normals")
        normals = normals / length[:, None]
    return points, normals


def _downsample(rng: np.random.Generator, n_total: int, n: int, method: str) -> np.ndarray:
    if n_total <= n:
        return np.arange(n_total)
    if method == "random":
        return np.sort(rng.choice(n_total, n, replace=False))
    raise ValueError(f"unknown sampling {method!r}")


def _fps(points: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """Farthest-point sampling indices ``(n,)``."""
    chosen = np.empty(n, np.int64)
    chosen[0] = rng.integers(len(points))
    dist = np.full(len(points), np.inf)
    for i in range(1, n):
        dist = np.minimum(dist, np.sum((points - points[chosen[i - 1]]) ** 2, axis=1))
        chosen[i] = int(np.argmax(dist))
    return np.sort(chosen)


def _to_4x4(t34: np.ndarray) -> np.ndarray:
    out = np.zeros(t34.shape[:-2] + (4, 4))
    out[..., :3, :] = t34
    out[..., 3, 3] = 1.0
    return out


_JITTED = {}


def _register_fn(cfg, num_iters):
    key = (cfg, num_iters)
    if key not in _JITTED:
        _JITTED[key] = jax.jit(lambda p, s, r: registration.register(p, s, r, cfg, num_iters=num_iters))
    return _JITTED[key]


class PreparedPair(NamedTuple):
    """A pair normalised for the model, and how to map a unit-sphere answer back to the caller's units."""

    src6: np.ndarray  # (1, J, 6) float32: centred, scaled, downsampled source xyz + unit normals
    ref6: np.ndarray  # (1, K, 6) float32
    src: np.ndarray  # (N, 3) the cleaned full source, caller's units
    c_src: np.ndarray  # (3,) source centre
    c_ref: np.ndarray  # (3,) reference centre
    scale: float  # common scale: unit-sphere length = caller's length / scale

    def to_callers_units(self, t_unit) -> np.ndarray:
        """``(..., 3, 4)`` transforms between the normalised clouds → ``(..., 4, 4)`` in the caller's units."""
        t_unit = np.asarray(t_unit, np.float64)
        rot = t_unit[..., :3]
        # ref = c_ref + s * (R (src - c_src) / s + t) = R src + (s t + c_ref - R c_src)
        trans = self.scale * t_unit[..., 3] + self.c_ref - rot @ self.c_src
        return _to_4x4(np.concatenate([rot, trans[..., None]], axis=-1))


def prepare_pair(src_points, ref_points, src_normals=None, ref_normals=None, *, num_points: int = 1024,
                 sampling: str = "random", seed: int = 0, reestimate_normals: bool = False,
                 centering: str = "separate") -> PreparedPair:
    """Cleans, centres, scales into the unit sphere, downsamples and (where missing) estimates normals.

    ``src_points (N, 3)``, ``ref_points (M, 3)``; see :func:`align` for the options.
    """
    if num_points < 3:
        raise ValueError(f"num_points must be >= 3, got {num_points}")
    if sampling not in ("random", "fps"):
        raise ValueError(f"sampling must be 'random' or 'fps', got {sampling!r}")
    if centering not in ("separate", "common"):
        raise ValueError(f"centering must be 'separate' or 'common', got {centering!r}")
    src, src_n = _clean("source", src_points, None if reestimate_normals else src_normals)
    ref, ref_n = _clean("reference", ref_points, None if reestimate_normals else ref_normals)
    if centering == "separate":
        c_src, c_ref = src.mean(axis=0), ref.mean(axis=0)
    else:
        c_src = c_ref = np.concatenate([src, ref]).mean(axis=0)
    scale = float(max(np.max(np.linalg.norm(src - c_src, axis=1)), np.max(np.linalg.norm(ref - c_ref, axis=1))))
    src_u, ref_u = (src - c_src) / scale, (ref - c_ref) / scale
    rng = np.random.default_rng(seed)
    pick = (lambda x: _fps(x, min(num_points, len(x)), rng)) if sampling == "fps" else (
        lambda x: _downsample(rng, len(x), num_points, "random"))
    i_src, i_ref = pick(src_u), pick(ref_u)
    src_s, ref_s = src_u[i_src], ref_u[i_ref]
    n_src = src_n[i_src] if src_n is not None else normals_lib.estimate_normals(src_s)
    n_ref = ref_n[i_ref] if ref_n is not None else normals_lib.estimate_normals(ref_s)
    src6 = np.concatenate([src_s, n_src], 1)[None].astype(np.float32)
    ref6 = np.concatenate([ref_s, n_ref], 1)[None].astype(np.float32)
    return PreparedPair(src6, ref6, src, c_src, c_ref, scale)


def align(src_points, ref_points, src_normals=None, ref_normals=None, *, checkpoint=None, params=None,
          num_points: int = 1024, num_iters: int = 5, sampling: str = "random", seed: int = 0,
          reestimate_normals: bool = False, centering: str = "separate",
          cfg: config_lib.RPMNetConfig | None = None) -> Alignment:
    """Rigidly aligns ``src_points (N, 3)`` onto ``ref_points (M, 3)``.

    Normals (``(N, 3)``, any length > 0) are estimated when missing or when ``reestimate_normals``.
    ``checkpoint``: orbax dir, ``.npz`` or official ``.pth``; default the shipped model (or pass
    ``params``). ``sampling``: ``random`` or ``fps`` down to ``num_points`` per cloud. ``centering``:
    ``separate`` (each cloud on its centroid) or ``common`` (both on their joint centroid).
    """
    if num_iters < 1:
        raise ValueError(f"num_iters must be >= 1, got {num_iters}")
    pair = prepare_pair(src_points, ref_points, src_normals, ref_normals, num_points=num_points,
                        sampling=sampling, seed=seed, reestimate_normals=reestimate_normals, centering=centering)
    params = params if params is not None else pretrained.load_params(checkpoint)
    cfg = cfg or config_lib.RPMNetConfig()
    reg = _register_fn(cfg, int(num_iters))(params, pair.src6, pair.ref6)
    transforms = pair.to_callers_units(np.asarray(reg.transforms[:, 0]))  # (I, 4, 4)
    final = transforms[-1]
    aligned = pair.src @ final[:3, :3].T + final[:3, 3]
    perm = np.asarray(reg.perm_matrices[-1, 0])
    confidence = float(0.5 * (perm.sum(axis=1).mean() + perm.sum(axis=0).mean()))
    return Alignment(final, aligned, transforms, confidence, (pair.src6.shape[1], pair.ref6.shape[1]))
