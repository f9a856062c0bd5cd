"""Robust point-to-plane ICP: makes a good initial transform precise on the caller's dense clouds.

Each iteration pairs moved source points with reference points (k-d tree) closer than a gate, weights each
pair by Tukey's biweight of its plane residual at the scale of the gate (as Open3D's ``TukeyLoss``: pairs
off the surface — partial overlap, outliers — count little or not at all) and solves the linearised weighted
point-to-plane problem (6×6). The gates come in stages, coarse to fine (``scales``):

- a coarse stage (``scale > 1``) pulls an answer a few degrees off in: each source point with its nearest
  reference point, on the reference's tangent plane, within a gate that follows the clouds (3 median
  nearest-neighbour distances, between ``max_distance`` and ``scale × max_distance``);
- a fine stage (``scale <= 1``) is precise: each source point with its ``neighbours`` nearest reference
  points (averaging the reference's noise) within ``scale × max_distance`` (down to a quarter of it by the
  same median rule for clouds far denser and cleaner than the gate, as range scans); when the source has
  normals, on the symmetric plane (normal: the mean of both normal lines, as in symmetric ICP, Rusinkiewicz
  2019) and weighted also by ``cos²`` of the angle between the normal lines (a pair across a crease has no
  common plane; such pairs made the update flip back and forth as they crossed the gate).

A stage ends when the update is below ``tolerance`` (rotation in radians, translation relative to the cloud
radius) or after ``max_iterations``. Each stage is one compiled loop: moving the source, querying the k-d tree
(:mod:`rpmnet_jax.geometry.kdtree`), gating and solving, with no Python between iterations.

Why (measured against Open3D's Tukey point-to-plane ICP, 0.05 / k 0.05 / 60 iterations, from the same
starts on the real ModelNet40 subset and real_meshes_train test files, ``experiments.refine_ab``): Tukey
weights of the point *distance* (the previous design) weigh the tangential offset between samples of two
noisy clouds, not the plane residual, and discard most pairs at the finest gate; the symmetric plane cancels
the first-order error of a tangent plane taken at a neighbouring sample; a fixed wide gate slid thin and
shell-like shapes along themselves; several neighbours or symmetric planes in the coarse stage stalled
boxy shapes 5–8° off; on the Stanford bunny's scans the full gate biased pairs by up to 0.1°.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np

from rpmnet_jax.geometry import cloud, kdtree, packed_normals


class Refinement(NamedTuple):
    transform: np.ndarray  # (4, 4): maps source onto reference
    converged: bool  # every stage ended on the tolerance, not on max_iterations
    num_iterations: int  # over all stages


MAX_ITERATIONS = 20  # per stage, by default
MIN_PAIRS = 6  # a stage with fewer pairs within its gate cannot fix the 6 degrees of freedom: it ends there
DAMPING = 1e-9  # added to the normal equations' diagonal, relative to their trace (a sliding direction stays put)


class Schedule(NamedTuple):
    """The gates of an ICP run's stages (multiples of ``max_distance``, coarse to fine) and the iterations per
    stage. Every schedule of the library is named here."""

    scales: tuple
    max_iterations: int


PAIR = Schedule((4.0, 1.0), MAX_ITERATIONS)  # align's candidates (RefineOptions may change it); its scales, the 3
# neighbours and GATE_MEDIANS chosen on the partial test pairs of both test files (experiments.refine_ab; tuning data:
# numbers on that data are not held-out)
SCREEN = Schedule((4.0, 2.0), 8)  # the global search's polish: just enough to make hypotheses comparable
EDGE = Schedule((4.0, 2.0, 1.0), 30)  # a pair of scans from a start that may lie a few degrees off
NETWORK_EDGE = Schedule((4.0, 2.0, 1.0), 10)  # align_scans: the short ICP after the network, every candidate pair
REFINE_EDGE = Schedule((1.0, 0.5), 30)  # align_scans' refinement rounds, from close poses (the 1x gate alone
# biased bunny edges by up to 1.3 deg: chosen on the 10 bunny scans, tuning data, numbers on them are not held-out)
GATE_MEDIANS = 3.0  # every gate: this many median nearest-neighbour distances, within the stage's bounds
FINE_FLOOR = 0.25  # a fine stage's gate goes down to this share of its scale (dense, clean range scans): chosen on
# the six bunny pairs (tuning data: numbers on that data are not held-out)
SMALL_ANGLE = float(np.finfo(np.float64).eps) ** 0.5  # |ω|² below which Rodrigues' coefficients are series


@numba.njit(cache=True)
def tukey_weights(residuals, scale: float):
    """Tukey's biweight ``(1 - (r / scale)²)²`` of ``residuals`` (an array ``(P,)`` or one number), 0 beyond
    ``scale`` (compiled: the ICP's loop calls it per pair)."""
    u = np.minimum(np.abs(residuals) / scale, 1.0)
    return (1.0 - u * u) ** 2


@numba.njit(cache=True)
def _median(values, m):
    """``np.median(values[:m])`` (``m >= 1``), reordering ``values[:m]``: the middle one, or the mean of the middle
    two, by Hoare's selection (:func:`rpmnet_jax.geometry.kdtree.select`). Numba's ``np.median`` takes 1.4 s to
    compile, this under 0.5 s."""
    rows = np.empty(m, np.int64)
    half = m // 2
    kdtree.select(values, rows, m, half + 1)  # values[half]: the (half + 1)-th smallest; the half below it
    high = values[half]
    if m % 2:
        return high
    low = values[0]
    for i in range(1, half):
        low = max(low, values[i])
    return (low + high) / 2


@numba.njit(cache=True)
def _solve6(a, b):
    """``x (6,)`` with ``a (6, 6) x = b (6,)``, ``a`` symmetric positive definite (the damped normal equations):
    Cholesky, ``a`` and ``b`` overwritten; zeros (no step) when ``a`` is not (a NaN from a degenerate pair).
    ``np.linalg.solve`` takes 4 s to compile in Numba (LAPACK's copies and their shape-error messages), this 0.6 s."""
    for j in range(6):
        d = a[j, j]
        for k in range(j):
            d -= a[j, k] * a[j, k]
        if not d > 0.0:
            return np.zeros(6)
        d = math.sqrt(d)
        a[j, j] = d
        for i in range(j + 1, 6):
            v = a[i, j]
            for k in range(j):
                v -= a[i, k] * a[j, k]
            a[i, j] = v / d
    for i in range(6):  # L y = b
        v = b[i]
        for k in range(i):
            v -= a[i, k] * b[k]
        b[i] = v / a[i, i]
    for i in range(5, -1, -1):  # Lᵀ x = y
        v = b[i]
        for k in range(i + 1, 6):
            v -= a[k, i] * b[k]
        b[i] = v / a[i, i]
    return b


@numba.njit(cache=True)
def _gate(dist, max_distance, scale):
    """A stage's gate from the distances ``dist (Q, K)`` of each moved source point's nearest reference points
    within the stage's ceiling ``scale × max_distance`` (``inf`` beyond): ``GATE_MEDIANS`` median nearest
    distances (``dist[:, 0]``), between ``max_distance`` and the ceiling in a coarse stage (``scale > 1``: wide
    while the clouds lie apart, the finest gate once they lie on each other), between ``FINE_FLOOR`` × the ceiling
    and the ceiling in a fine one (narrower only for clouds much denser and less noisy than ``max_distance``
    assumes), there over the source points with a partner within the ceiling only: the part that does not
    overlap (half of a pair of range scans 90° apart) says nothing of the noise. The ceiling when none has one."""
    ceiling = scale * max_distance
    coarse = scale > 1.0
    floor = max_distance if coarse else FINE_FLOOR * ceiling
    nearest = np.empty(len(dist))
    m = 0
    for i in range(len(dist)):
        if coarse or np.isfinite(dist[i, 0]):
            nearest[m] = dist[i, 0]
            m += 1
    if m == 0:
        return ceiling
    return min(max(GATE_MEDIANS * _median(nearest, m), floor), ceiling)


@numba.njit(cache=True)
def _step(moved, ref, normals, src_normals, transform, dist, idx, gate, symmetric):
    """One linearised, Tukey-weighted point-to-plane solve over the pairs ``dist, idx (Q, K)`` within ``gate``
    (on the symmetric planes, weighted by ``cos²`` of the normal lines' angle, when ``symmetric``): ``(the
    step (4, 4), |ω|, |v|, pairs)``; the identity and no pairs below ``MIN_PAIRS``."""
    a = np.zeros((6, 6))
    b = np.zeros(6)
    jac = np.empty(6)
    pairs = 0
    for i in range(len(dist)):
        for k in range(dist.shape[1]):
            if not dist[i, k] <= gate:
                continue
            pairs += 1
            j = idx[i, k]
            px, py, pz = moved[i, 0], moved[i, 1], moved[i, 2]
            nx, ny, nz = normals[j, 0], normals[j, 1], normals[j, 2]
            agreement = 1.0
            if symmetric:  # the symmetric plane: both normal lines, signs made to agree
                mx = transform[0, 0] * src_normals[i, 0] + transform[0, 1] * src_normals[i, 1] + transform[0, 2] * src_normals[i, 2]
                my = transform[1, 0] * src_normals[i, 0] + transform[1, 1] * src_normals[i, 1] + transform[1, 2] * src_normals[i, 2]
                mz = transform[2, 0] * src_normals[i, 0] + transform[2, 1] * src_normals[i, 1] + transform[2, 2] * src_normals[i, 2]
                cos = mx * nx + my * ny + mz * nz
                sign = -1.0 if cos < 0 else 1.0
                nx, ny, nz = nx + sign * mx, ny + sign * my, nz + sign * mz
                norm = math.sqrt(nx * nx + ny * ny + nz * nz)
                nx, ny, nz = nx / norm, ny / norm, nz / norm
                agreement = cos * cos
            r = (px - ref[j, 0]) * nx + (py - ref[j, 1]) * ny + (pz - ref[j, 2]) * nz
            w = tukey_weights(r, gate) * agreement
            jac[0], jac[1], jac[2] = py * nz - pz * ny, pz * nx - px * nz, px * ny - py * nx  # d r / d (ω, v)
            jac[3], jac[4], jac[5] = nx, ny, nz
            for c in range(6):
                wc = w * jac[c]
                b[c] -= wc * r
                for d in range(c, 6):
                    a[c, d] += wc * jac[d]
    step = np.eye(4)
    if pairs < MIN_PAIRS:
        return step, 0.0, 0.0, pairs
    trace = 0.0
    for c in range(6):
        trace += a[c, c]
        for d in range(c):
            a[c, d] = a[d, c]
    for c in range(6):
        a[c, c] += DAMPING * max(trace, 1e-12)
    x = _solve6(a, b)
    wx, wy, wz = x[0], x[1], x[2]
    t = wx * wx + wy * wy + wz * wz
    if t < SMALL_ANGLE:  # Rodrigues' coefficients by their Taylor series (as ops.se3.exp)
        ca, cb = 1 - t / 6 + t * t / 120, 0.5 - t / 24 + t * t / 720
    else:
        theta = math.sqrt(t)
        half = math.sin(0.5 * theta)
        ca, cb = math.sin(theta) / theta, 2 * half * half / t
    k = np.array([[0.0, -wz, wy], [wz, 0.0, -wx], [-wy, wx, 0.0]])
    for r in range(3):
        for c in range(3):
            k2 = k[r, 0] * k[0, c] + k[r, 1] * k[1, c] + k[r, 2] * k[2, c]
            step[r, c] += ca * k[r, c] + cb * k2
        step[r, 3] = x[3 + r]
    return step, math.sqrt(t), math.sqrt(x[3] * x[3] + x[4] * x[4] + x[5] * x[5]), pairs


@numba.njit(cache=True)
def _stage(src, ref, nodes, normals, src_normals, transform, max_distance, scale, neighbours, symmetric,
           max_iterations, rot_tolerance, shift_tolerance, chunks):
    """One stage of :func:`point_to_plane_icp`, compiled whole: each iteration moves ``src (N, 3)``, pairs each
    point with its ``neighbours`` nearest points of ``ref (M, 3)`` (its k-d tree ``nodes``,
    :func:`rpmnet_jax.geometry.kdtree.query_into` in ``chunks``) within the stage's ceiling, gates them
    (:func:`_gate`) and takes the step (:func:`_step`). Returns ``(transform, iterations, ended on the
    tolerance)``; a step with fewer than ``MIN_PAIRS`` pairs ends the stage (not converged, transform kept)."""
    ceiling = scale * max_distance
    n = len(src)
    moved = np.empty((n, 3))
    dist = np.empty((n, neighbours))
    idx = np.empty((n, neighbours), np.int64)
    for iteration in range(1, max_iterations + 1):
        for i in range(n):
            for a in range(3):
                moved[i, a] = (transform[a, 0] * src[i, 0] + transform[a, 1] * src[i, 1]
                               + transform[a, 2] * src[i, 2] + transform[a, 3])
        kdtree.query_into(nodes, moved, neighbours, ceiling * ceiling, dist, idx, chunks)
        gate = _gate(dist, max_distance, scale)
        step, rot, shift, pairs = _step(moved, ref, normals, src_normals, transform, dist, idx, gate, symmetric)
        if pairs < MIN_PAIRS:
            return transform, iteration, False
        transform = step @ transform
        if rot < rot_tolerance and shift < shift_tolerance:
            return transform, iteration, True
    return transform, max_iterations, False


def point_to_plane_icp(src, ref, ref_normals, init, max_distance: float, *, src_normals=None,
                       scales=PAIR.scales, max_iterations: int = PAIR.max_iterations, tolerance: float = 1e-4,
                       neighbours: int = 3, ref_tree: kdtree.KdTree | None = None) -> Refinement:
    """Refines ``init (4, 4)`` moving ``src (N, 3)`` onto ``ref (M, 3)`` with unit ``ref_normals (M, 3)`` (or
    packed: :mod:`~rpmnet_jax.geometry.packed_normals`, unpacked here).

    ``src_normals (N, 3)``: unit normals of the source (either sign), for the symmetric planes of the fine
    stages; ``None``: the reference's tangent planes throughout. ``max_distance``: the finest gate (same
    units as the clouds); ``scales``: the stages' gates (their bounds, for coarse ones) as multiples of it;
    ``max_iterations``: per stage; ``neighbours``: reference points paired with each source point in a fine
    stage.
    """
    src = np.ascontiguousarray(src, np.float64)
    normals = packed_normals.unit(np.asarray(ref_normals))  # float32 kept (a scan set's compact scans: not copied
    # for each pair); a refinement's packed ones unpacked, once a pair
    normals = np.ascontiguousarray(normals, normals.dtype if normals.dtype == np.float32 else np.float64)
    src_n = None if src_normals is None else np.ascontiguousarray(packed_normals.unit(np.asarray(src_normals)),
                                                                  np.float64)
    if not max_distance > 0:
        raise ValueError(f"max_distance must be > 0, got {max_distance}")
    if max_iterations < 1:
        raise ValueError(f"max_iterations must be >= 1, got {max_iterations}")
    if neighbours < 1:
        raise ValueError(f"neighbours must be >= 1, got {neighbours}")
    if src_n is not None and src_n.shape != src.shape:
        raise ValueError(f"src_normals {src_n.shape} do not match src {src.shape}")
    tree = ref_tree if ref_tree is not None else kdtree.KdTree(np.asarray(ref, np.float64))
    radius = max(cloud.radius(src), 1e-12)
    transform = np.array(init, np.float64)
    total, converged = 0, True
    for scale in scales:
        fine = scale <= 1.0
        transform, iterations, stage_done = _stage(
            src, tree.data, tree.nodes, normals, src_n if src_n is not None else np.zeros((0, 3)), transform,
            max_distance, scale, neighbours if fine else 1, src_n is not None and fine, max_iterations,
            tolerance, tolerance * radius, kdtree.chunks_for(len(src)))
        total += iterations
        converged &= stage_done
    return Refinement(transform, bool(converged), total)
