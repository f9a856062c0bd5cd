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

The descriptor forgets where along each direction things stand, and a town's streets repeat: two footprints may
agree without overlapping. :meth:`Footprints.aligned` checks a pair's footprints themselves: one turned by the
turn the descriptors agree at (or half a turn more), slid by the peak of the cross-correlation of the two cells'
images, and the share of cells that coincide (as RING goes on from the sinogram to a pose); about 0.05 s for one
scan against 736 (step 3c of :func:`rpmnet_jax.align_scans` asks it for the ends of the groups left unplaced).

Measured on 300 stations of the simulated site (:mod:`rpmnet_jax.simulation.sites`, seed 2; tuning data, the
constants below chosen there): of station pairs less than 12 m apart, 91% rank among either station's 6 best by
this score, 34% by the bag of words (:mod:`rpmnet_jax.multiway.candidate_pairs`); the nearest station among the
6 best: 96% against 46%. The bag of words sees local shape, which a town repeats street after street; the
footprint sees where things stand. All pairs' scores of 300 scans: about 2 s.
"""

from __future__ import annotations

import numpy as np

from rpmnet_jax.geometry import cloud, packed_normals

RADIUS = 0.65  # the footprint's reach, × the median robust scan radius (300 site stations: 0.5 → 74% of the
# near pairs among the 6 best, 0.65 → 91%, 0.8 → about the same; tuning data)
ANGLES = 90  # projection directions over a half turn (60: 72%, 90: 84%, 120: 84% with the vertical-normal
# footprint tried first; tuning data)
GROUND_NORMAL_Z = 0.9  # a point whose normal's z is at least this (in size) may be ground
GROUND_REACH = 0.2  # the ground under the sensor: such points within this share of the radius, horizontally
CHUNK = 64  # scans per block of the pairwise scores
RERANKED = 48  # Footprints.ranked: each scan's best partners by the sinograms ordered again by aligned footprints.
# Site seed 8's 1,000 stations, each with its 6 best: share of pairs < 12 m among them 0.84 by the sinograms, 0.96
# re-ranked from the 48 best (0.97 from 96, twice the time), the nearest station 0.88 -> 0.97 (0.98); tuning data
ALIGN_CELLS = 40  # Footprints.aligned: cells per footprint radius (1 m at a site's 41 m). Site seed 8's 49 street
# ends with a placed neighbour, its rank among 736 placed stations in the 6 best: 20 cells 25, 40 cells 43, 60 cells
# 43 (3x the time); images dilated by a cell 3; a padded (linear) correlation the same as the circular; tuning data


def ground_height(points: np.ndarray, normals: np.ndarray, reach: float) -> float:
    """The ground's height under the sensor (at the origin of ``points (N, 3)``): the median z of the points with
    near-vertical ``normals (N, 3)`` within ``reach`` horizontally; the lowest tenth percentile of z without one."""
    near = (np.hypot(points[:, 0], points[:, 1]) < reach) & (np.abs(normals[:, 2]) >= GROUND_NORMAL_Z)
    return float(np.median(points[near, 2])) if near.any() else float(np.percentile(points[:, 2], 10))


def footprint(points: np.ndarray, normals: np.ndarray, voxel: float, radius: float) -> np.ndarray:
    """``(M, 2)`` centres of the footprint's cells of a scan ``points (N, 3)`` with ``normals (N, 3)`` in its
    sensor's frame, z up (module docstring): the cells of ``voxel`` within ``radius`` holding a point more than one
    voxel above the ground under the sensor."""
    ground = ground_height(points, normals, GROUND_REACH / RADIUS * radius)
    keep = (np.hypot(points[:, 0], points[:, 1]) < radius) & (points[:, 2] > ground + voxel)
    return (np.unique(np.floor(points[keep, :2] / voxel).astype(np.int64), axis=0) + 0.5) * voxel


def descriptor(points: np.ndarray, normals: np.ndarray, voxel: float, radius: float,
               angles: int = ANGLES) -> np.ndarray:
    """``(angles, bins - 1)`` unit-norm magnitudes of the footprint's sinogram (module docstring) of a scan
    ``points (N, 3)`` with ``normals (N, 3)`` in its sensor's frame, z up; ``radius`` the footprint's reach."""
    centres = footprint(points, normals, voxel, radius)
    theta = np.arange(angles) * np.pi / angles
    bins = int(np.ceil(2.0 * radius / voxel))
    rows = np.clip(((centres @ np.stack([np.cos(theta), np.sin(theta)]) + radius) / voxel).astype(np.int64),
                   0, bins - 1)  # (M, angles)
    sinogram = np.zeros((angles, bins))
    np.add.at(sinogram, (np.broadcast_to(np.arange(angles), rows.shape), rows), 1.0)
    magnitude = np.abs(np.fft.rfft(sinogram, axis=1))[:, 1:]
    return magnitude / max(float(np.linalg.norm(magnitude)), 1e-12)


def similarities(descriptors: np.ndarray, chunk: int = CHUNK) -> tuple:
    """``(S, S)`` the best correlation of ``descriptors (S, A, F)`` over circular shifts of their ``A`` rows, and
    ``(S, S)`` int16 the shift that gives it: ``[i, j]`` turns scan ``j`` onto scan ``i`` by that many ``pi / A``
    (or half a turn more)."""
    spectra = np.fft.fft(descriptors, axis=1)  # (S, A, F)
    out = np.empty((len(descriptors),) * 2)
    turns = np.empty((len(descriptors),) * 2, np.int16)
    for i in range(0, len(descriptors), chunk):
        cross = np.fft.ifft(np.einsum("iaf,jaf->ija", spectra[i:i + chunk], np.conj(spectra)), axis=2).real
        out[i:i + chunk] = cross.max(axis=2)
        turns[i:i + chunk] = cross.argmax(axis=2)
    return out, turns


def overlap_scores(scans, sensors, voxel: float) -> np.ndarray:
    """``(S, S)`` symmetric scores in ``[0, 1]`` for ``scans`` (:class:`~rpmnet_jax.pair_edges.edges.Scan`, z up)
    seen from ``sensors`` (``(3,)`` each, in the scan's coordinates), on a grid of ``voxel``; higher where two
    footprints agree."""
    return Footprints(scans, sensors, voxel).scores


class Footprints:
    """The footprints of ``scans`` (:class:`~rpmnet_jax.pair_edges.edges.Scan`, z up) seen from ``sensors``
    (``(3,)`` each, in the scan's coordinates): :attr:`scores` ``(S, S)`` from their sinograms on a grid of
    ``voxel`` (symmetric, in ``[0, 1]``, higher where two footprints agree) and :meth:`aligned` from their cells on
    a grid of ``radius / ALIGN_CELLS``; :attr:`turns` ``(S, S)`` int16, :func:`similarities`' best shifts."""

    def __init__(self, scans, sensors, voxel: float):
        if len(scans) < 2:
            raise ValueError(f"need at least two scans, got {len(scans)}")
        if any(s is None for s in sensors):
            raise ValueError("every scan needs its sensor's position")
        self.radius = RADIUS * float(np.median([cloud.robust_radius(s.points - c) for s, c in zip(scans, sensors)]))
        self.cell = self.radius / ALIGN_CELLS
        scores, self.turns = similarities(np.stack([descriptor(s.points - c, packed_normals.unit(s.normals), voxel,
                                                               self.radius) for s, c in zip(scans, sensors)]))
        self.scores = 0.5 * (scores + scores.T)
        self.cells = [footprint(s.points - c, packed_normals.unit(s.normals), self.cell, self.radius)
                      for s, c in zip(scans, sensors)]
        self._spectra = {}  # scan -> the rfft2 of its cells' image, complex64

    def ranked(self, best: int = RERANKED) -> np.ndarray:
        """``(S, S)`` symmetric scores that rank each scan's ``best`` partners by :attr:`scores` first, among them
        by :meth:`aligned` (``1 +`` the larger of the pair's two ways, in ``[1, 2]``), then the rest by
        :attr:`scores` (in ``[0, 1]``)."""
        others = self.scores - np.diag(np.full(len(self.scores), np.inf))  # a scan is not its own partner
        top = np.argsort(-others, axis=1, kind="stable")[:, :min(best, len(others) - 1)]
        aligned = np.full(others.shape, -np.inf)
        for i, cols in enumerate(top):
            aligned[i, cols] = self.aligned(i, cols)
        aligned = np.maximum(aligned, aligned.T)  # the diagonal stays -inf: the scores keep it
        return np.where(np.isfinite(aligned), 1.0 + aligned, self.scores)

    def aligned(self, row: int, cols) -> np.ndarray:
        """``(len(cols),)`` how well scan ``row``'s footprint covers each of ``cols``' once turned and slid onto it:
        the turn of the descriptors' best correlation (:attr:`turns`, or half a turn more: the sinogram spans half
        a turn), the slide the cross-correlation of their cells' images finds (circular, on the grid of
        :attr:`cell`); the cells that coincide ÷ the geometric mean of the two counts, in ``[0, 1]``. Sees where
        things stand, not only their spread along each direction: a town's look-alike footprints agree in
        :attr:`scores` but not here (site seed 8's street ends: a placed neighbour first among 736 placed
        stations for 38 of 49, by :attr:`scores` 0th–678th; tuning data)."""
        cols = np.asarray(cols, np.int64)
        angles = ANGLES
        size = 2 * ALIGN_CELLS
        best = np.zeros(len(cols))
        turned = {}
        for half in (0, angles):
            steps = (self.turns[cols, row].astype(np.int64) + half) % (2 * angles)
            for step in np.unique(steps):
                turned[step] = np.conj(np.fft.rfft2(self._image(self.cells[row], step * np.pi / angles)))
            for start in range(0, len(cols), CHUNK):
                part = slice(start, start + CHUNK)
                products = np.stack([self._spectrum(int(c)) * turned[s] for c, s in zip(cols[part], steps[part])])
                peaks = np.fft.irfft2(products, s=(size, size)).reshape(len(products), -1).max(axis=1)
                best[part] = np.maximum(best[part], peaks)
        counts = np.array([len(self.cells[c]) for c in cols], np.float64) * len(self.cells[row])
        return best / np.sqrt(np.maximum(counts, 1.0))

    def _image(self, cells: np.ndarray, turn: float) -> np.ndarray:
        """``(2·ALIGN_CELLS, 2·ALIGN_CELLS)`` 1 where ``cells (M, 2)``, turned by ``turn`` radians, fall."""
        c, s = np.cos(turn), np.sin(turn)
        at = np.floor((cells @ np.array([[c, s], [-s, c]]) + self.radius) / self.cell).astype(np.int64)
        at = at[((at >= 0) & (at < 2 * ALIGN_CELLS)).all(axis=1)]
        image = np.zeros((2 * ALIGN_CELLS,) * 2, np.float32)
        image[at[:, 0], at[:, 1]] = 1.0
        return image

    def _spectrum(self, scan: int) -> np.ndarray:
        if scan not in self._spectra:
            self._spectra[scan] = np.fft.rfft2(self._image(self.cells[scan], 0.0)).astype(np.complex64)
        return self._spectra[scan]
