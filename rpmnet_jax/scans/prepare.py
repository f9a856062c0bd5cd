"""Preparing people's clouds for the network: cleaning, centring, scaling, downsampling, normals.

Each cloud is centred on its own centroid (or both on their common one, ``centering="common"``) and both
are scaled by one common factor into the unit sphere the model was trained on, downsampled, registered,
and the result is mapped back, so the returned 4×4 transform is rigid and in the caller's units. Separate
centring (the default) keeps the residual translation inside the range the model was trained on (0.5 of
the unit sphere per axis) even when the scans sit far apart in the caller's frame.
"""

from __future__ import annotations

import warnings
from typing import NamedTuple

import numpy as np

from rpmnet_jax.scans import normals as normals_lib
from rpmnet_jax.ops import se3


def clean_cloud(name: str, points, normals):
    """``points (N, 3)`` float64 without NaN/inf rows (warned), and unit ``normals`` (or ``None``); raises
    ``ValueError`` naming ``name`` for a wrong shape, fewer than 3 points, a degenerate cloud or zero normals."""
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


def voxel_downsample(points: np.ndarray, normals: np.ndarray | None, voxel_size: float
                     ) -> tuple[np.ndarray, np.ndarray | None]:
    """One point per occupied cube of side ``voxel_size``: the mean of its points ``(V, 3)`` and, when
    ``normals (N, 3)`` are given, their renormalised mean (the first normal of the cube where they cancel)."""
    if not voxel_size > 0:
        raise ValueError(f"voxel_size must be > 0, got {voxel_size}")
    points = np.asarray(points, np.float64)
    keys = np.floor((points - points.min(axis=0)) / voxel_size).astype(np.int64)
    _, first, inverse, counts = np.unique(keys, axis=0, return_index=True, return_inverse=True, return_counts=True)
    inverse = inverse.ravel()

    def summed(x):
        return np.stack([np.bincount(inverse, x[:, k], len(counts)) for k in range(3)], axis=1)

    out = summed(points) / counts[:, None]
    if normals is None:
        return out, None
    total = summed(np.asarray(normals, np.float64))
    length = np.linalg.norm(total, axis=1, keepdims=True)
    fallback = np.asarray(normals, np.float64)[first]
    fallback = fallback / np.maximum(np.linalg.norm(fallback, axis=1, keepdims=True), 1e-300)
    out_normals = np.where(length > 1e-6 * counts[:, None], total / np.maximum(length, 1e-300), fallback)
    return out, out_normals


def sample_indices(rng: np.random.Generator, n_total: int, n: int) -> np.ndarray:
    """Sorted indices ``(min(n, n_total),)`` of ``n`` rows drawn without replacement (all rows when
    ``n_total <= n``)."""
    return np.arange(n_total) if n_total <= n else np.sort(rng.choice(n_total, n, replace=False))


def _fps(points: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """Farthest-point sampling indices ``(n,)``."""
    chosen = np.empty(n, np.int64)
    chosen[0] = rng.integers(len(points))
    dist = np.full(len(points), np.inf)
    for i in range(1, n):
        dist = np.minimum(dist, np.sum((points - points[chosen[i - 1]]) ** 2, axis=1))
        chosen[i] = int(np.argmax(dist))
    return np.sort(chosen)


class PreparedPair(NamedTuple):
    """A pair normalised for the model, and how to map a unit-sphere answer back to the caller's units."""

    src6: np.ndarray  # (1, J, 6) float32: centred, scaled, downsampled source xyz + unit normals
    ref6: np.ndarray  # (1, K, 6) float32
    src: np.ndarray  # (N, 3) the cleaned full source, caller's units
    ref: np.ndarray  # (M, 3) the cleaned full reference, caller's units
    src_normals: np.ndarray | None  # (N, 3) unit normals of ``src`` when given (and not re-estimated)
    ref_normals: np.ndarray | None  # (M, 3)
    c_src: np.ndarray  # (3,) source centre
    c_ref: np.ndarray  # (3,) reference centre
    scale: float  # common scale: unit-sphere length = caller's length / scale

    def to_callers_units(self, t_unit) -> np.ndarray:
        """``(..., 3, 4)`` transforms between the normalised clouds → ``(..., 4, 4)`` in the caller's units."""
        t_unit = np.asarray(t_unit, np.float64)
        rot = t_unit[..., :3]
        # ref = c_ref + s * (R (src - c_src) / s + t) = R src + (s t + c_ref - R c_src)
        trans = self.scale * t_unit[..., 3] + self.c_ref - rot @ self.c_src
        return se3.to_homogeneous(np.concatenate([rot, trans[..., None]], axis=-1))

    def to_unit(self, points: np.ndarray, which: str) -> np.ndarray:
        """Caller's-units points ``(N, 3)`` of the ``"src"`` or ``"ref"`` cloud → the normalised frame."""
        return (points - (self.c_src if which == "src" else self.c_ref)) / self.scale


def prepare_pair(src_points, ref_points, src_normals=None, ref_normals=None, *, num_points: int = 1024,
                 sampling: str = "random", seed: int = 0, reestimate_normals: bool = False,
                 centering: str = "separate") -> PreparedPair:
    """Cleans, centres, scales into the unit sphere, downsamples and (where missing) estimates normals.

    ``src_points (N, 3)``, ``ref_points (M, 3)``; see :func:`rpmnet_jax.align` for the options.
    """
    if num_points < 3:
        raise ValueError(f"num_points must be >= 3, got {num_points}")
    if sampling not in ("random", "fps"):
        raise ValueError(f"sampling must be 'random' or 'fps', got {sampling!r}")
    if centering not in ("separate", "common"):
        raise ValueError(f"centering must be 'separate' or 'common', got {centering!r}")
    src, src_n = clean_cloud("source", src_points, None if reestimate_normals else src_normals)
    ref, ref_n = clean_cloud("reference", ref_points, None if reestimate_normals else ref_normals)
    if centering == "separate":
        c_src, c_ref = src.mean(axis=0), ref.mean(axis=0)
    else:
        c_src = c_ref = np.concatenate([src, ref]).mean(axis=0)
    scale = float(max(np.max(np.linalg.norm(src - c_src, axis=1)), np.max(np.linalg.norm(ref - c_ref, axis=1))))
    src_u, ref_u = (src - c_src) / scale, (ref - c_ref) / scale
    rng = np.random.default_rng(seed)
    pick = (lambda x: _fps(x, min(num_points, len(x)), rng)) if sampling == "fps" else (
        lambda x: sample_indices(rng, len(x), num_points))
    i_src, i_ref = pick(src_u), pick(ref_u)
    src_s, ref_s = src_u[i_src], ref_u[i_ref]
    n_src = src_n[i_src] if src_n is not None else normals_lib.estimate_normals(src_s)
    n_ref = ref_n[i_ref] if ref_n is not None else normals_lib.estimate_normals(ref_s)
    src6 = np.concatenate([src_s, n_src], 1)[None].astype(np.float32)
    ref6 = np.concatenate([ref_s, n_ref], 1)[None].astype(np.float32)
    return PreparedPair(src6, ref6, src, ref, src_n, ref_n, c_src, c_ref, scale)
