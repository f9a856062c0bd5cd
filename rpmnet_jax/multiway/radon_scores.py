"""Which scans of a levelled scene overlap: a place-recognition score invariant to a turn about the vertical and to
a slide, for scans that stand in their sensor's frame with z up (a terrestrial scanner on a tripod, a vehicle's
LiDAR): the Radon sinogram of each scan's footprint seen from above, as RING (Lu et al., "One RING to rule them all:
Radon sinogram for place recognition, orientation and translation estimation", IROS 2022).

Per scan: the cells of a grid of ``voxel`` in the horizontal plane, within ``RADIUS`` × the median robust scan
radius of the sensor, that hold a point more than one voxel above the ground under the sensor (walls, trunks,
cars; the ground itself would fill every cell alike); their projections on ``ANGLES`` directions over a half turn,
counted in bins of ``voxel`` (the sinogram, ``(ANGLES, bins)``); the magnitude of each row's Fourier transform over
its bins, less the constant term. A slide of the scan shifts each row, which leaves its magnitudes alone; a turn
about the vertical shifts the rows circularly (a row past the half turn comes back mirrored, with the same
magnitudes). For a pair the score is the best correlation of the two descriptors over those circular shifts
(:func:`similarities`, through the Fourier transform over the angles): in ``[0, 1]``, 1 for the same footprint.

Measured on 300 stations of the simulated site (:mod:`rpmnet_jax.simulation.sites`, seed 2; tuning data, the
constants below chosen there): of station pairs less than 12 m apart, 91% rank among either station's 6 best by
this score, 34% by the bag of words (:mod:`rpmnet_jax.multiway.candidate_pairs`); the nearest station among the
6 best: 96% against 46%. The bag of words sees local shape, which a town repeats street after street; the
footprint sees where things stand. All pairs' scores of 300 scans: about 2 s.
"""

from __future__ import annotations

import numpy as np

from rpmnet_jax.geometry import cloud

RADIUS = 0.65  # the footprint's reach, × the median robust scan radius (300 site stations: 0.5 → 74% of the
# near pairs among the 6 best, 0.65 → 91%, 0.8 → about the same; tuning data)
ANGLES = 90  # projection directions over a half turn (60: 72%, 90: 84%, 120: 84% with the vertical-normal
# footprint tried first; tuning data)
GROUND_NORMAL_Z = 0.9  # a point whose normal's z is at least this (in size) may be ground
GROUND_REACH = 0.2  # the ground under the sensor: such points within this share of the radius, horizontally
CHUNK = 64  # scans per block of the pairwise scores


def ground_height(points: np.ndarray, normals: np.ndarray, reach: float) -> float:
    """The ground's height under the sensor (at the origin of ``points (N, 3)``): the median z of the points with
    near-vertical ``normals (N, 3)`` within ``reach`` horizontally; the lowest tenth percentile of z without one."""
    near = (np.hypot(points[:, 0], points[:, 1]) < reach) & (np.abs(normals[:, 2]) >= GROUND_NORMAL_Z)
    return float(np.median(points[near, 2])) if near.any() else float(np.percentile(points[:, 2], 10))


def descriptor(points: np.ndarray, normals: np.ndarray, voxel: float, radius: float,
               angles: int = ANGLES) -> np.ndarray:
    """``(angles, bins - 1)`` unit-norm magnitudes of the footprint's sinogram (module docstring) of a scan
    ``points (N, 3)`` with ``normals (N, 3)`` in its sensor's frame, z up; ``radius`` the footprint's reach."""
    ground = ground_height(points, normals, GROUND_REACH / RADIUS * radius)
    keep = (np.hypot(points[:, 0], points[:, 1]) < radius) & (points[:, 2] > ground + voxel)
    cells = np.unique(np.floor(points[keep, :2] / voxel).astype(np.int64), axis=0)
    centres = (cells + 0.5) * voxel
    theta = np.arange(angles) * np.pi / angles
    bins = int(np.ceil(2.0 * radius / voxel))
    rows = np.clip(((centres @ np.stack([np.cos(theta), np.sin(theta)]) + radius) / voxel).astype(np.int64),
                   0, bins - 1)  # (M, angles)
    sinogram = np.zeros((angles, bins))
    np.add.at(sinogram, (np.broadcast_to(np.arange(angles), rows.shape), rows), 1.0)
    magnitude = np.abs(np.fft.rfft(sinogram, axis=1))[:, 1:]
    return magnitude / max(float(np.linalg.norm(magnitude)), 1e-12)


def similarities(descriptors: np.ndarray, chunk: int = CHUNK) -> np.ndarray:
    """``(S, S)`` the best correlation of ``descriptors (S, A, F)`` over circular shifts of their ``A`` rows."""
    spectra = np.fft.fft(descriptors, axis=1)  # (S, A, F)
    out = np.empty((len(descriptors),) * 2)
    for i in range(0, len(descriptors), chunk):
        cross = np.einsum("iaf,jaf->ija", spectra[i:i + chunk], np.conj(spectra))
        out[i:i + chunk] = np.fft.ifft(cross, axis=2).real.max(axis=2)
    return out


def overlap_scores(scans, sensors, voxel: float) -> np.ndarray:
    """``(S, S)`` symmetric scores in ``[0, 1]`` for ``scans`` (:class:`~rpmnet_jax.pair_edges.edges.Scan`, z up)
    seen from ``sensors`` (``(3,)`` each, in the scan's coordinates), on a grid of ``voxel``; higher where two
    footprints agree."""
    if len(scans) < 2:
        raise ValueError(f"need at least two scans, got {len(scans)}")
    if any(s is None for s in sensors):
        raise ValueError("every scan needs its sensor's position")
    radius = RADIUS * float(np.median([cloud.robust_radius(s.points - c) for s, c in zip(scans, sensors)]))
    scores = similarities(np.stack([descriptor(s.points - c, s.normals, voxel, radius)
                                    for s, c in zip(scans, sensors)]))
    return 0.5 * (scores + scores.T)
