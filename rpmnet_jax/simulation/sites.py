"""A simulated site scanned from many terrestrial-scanner stations, with their true poses: the campaign regime
(a town scanned street by street) where each scan overlaps only its few neighbours along the streets.

The town is a grid of blocks (buildings of several heights, set back from the street by a few metres) between
streets, on gently sloping ground; along the streets stand parked cars, trees (a trunk and a crown of overlapping
balls: vegetation-like clutter) and poles. Everything is an analytic solid (axis-aligned boxes, vertical
cylinders, balls, the ground plane), so a ray's first hit is exact. A station is a levelled 360° scanner on a
tripod on a street's centre line: rays on an azimuth × elevation grid, the first hit within ``MAX_RANGE``,
Gaussian noise along the ray; each station's points are in its own frame (sensor at the origin, a random heading),
as a scanner writes them. Stations are numbered from one corner of the town outwards, so the first ``S`` of a
town form one connected stretch of streets and a campaign of ``S`` stations grows the town with ``S``.

Pose: ``site point = R p + t`` for a point ``p`` of a station's frame. Units: metres.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np

BLOCK = 40.0  # a block's side (buildings inside it)
STREET = 12.0  # a street's width, kerb to kerb plus pavements
SPACING = 10.0  # between neighbouring stations along a street
SLOPE = (0.005, 0.003)  # the ground's rise per metre along x and y
SENSOR_HEIGHT = 1.6  # the tripod
STEP_DEG = 0.6  # the scanner's angular resolution (azimuth and elevation)
ELEVATION_DEG = (-50.0, 70.0)  # what it sees below and above the horizon
MAX_RANGE = 60.0  # returns beyond this are dropped
NOISE = 0.003  # metres, along the ray (a terrestrial scanner's range noise)
CROWN_BALLS = 8  # balls per tree crown


class Town(NamedTuple):
    boxes: np.ndarray  # (B, 6) solid axis-aligned boxes: min x, y, z, max x, y, z (buildings, cars)
    cylinders: np.ndarray  # (C, 5) solid vertical cylinders: centre x, y, radius, bottom z, top z (trunks, poles)
    balls: np.ndarray  # (P, 4) solid balls: centre x, y, z, radius (tree crowns)
    slots: np.ndarray  # (M, 2) station positions on the streets' centre lines, nearest the first corner first
    size: tuple  # (width, depth) of the town


class Station(NamedTuple):
    points: np.ndarray  # (N, 3) float64, the station's frame (sensor at the origin)
    pose: np.ndarray  # (4, 4) float64: station frame → site frame


def ground(xy) -> np.ndarray:
    """``(...,)`` the ground's height at ``xy (..., 2)``."""
    xy = np.asarray(xy, np.float64)
    return SLOPE[0] * xy[..., 0] + SLOPE[1] * xy[..., 1]


def blocks_for(num_stations: int) -> int:
    """The smallest ``n`` whose ``n × n``-block town has street slots for ``num_stations`` stations."""
    n = 1
    while len(_slots(n)) < num_stations:
        n += 1
    return n


def _slots(n: int) -> np.ndarray:
    """``(M, 2)`` station positions every ``SPACING`` along the centre lines of an ``n × n``-block town's
    streets (``n + 1`` each way), sorted by distance from the corner crossing, each position once."""
    pitch = BLOCK + STREET
    lines = STREET / 2 + pitch * np.arange(n + 1)  # the centre lines, both ways
    along = np.arange(STREET / 2, lines[-1] + 1e-9, SPACING)
    xy = np.concatenate([np.stack(np.meshgrid(lines, along, indexing="ij"), -1).reshape(-1, 2),
                         np.stack(np.meshgrid(along, lines, indexing="ij"), -1).reshape(-1, 2)])
    xy = np.unique(np.round(xy, 6), axis=0)
    return xy[np.lexsort((xy[:, 1], xy[:, 0], np.hypot(*(xy - STREET / 2).T)))]


def town(num_stations: int, seed: int = 0) -> Town:
    """A town just large enough for ``num_stations`` stations, reproducible from ``seed``."""
    rng = np.random.default_rng(seed)
    n = blocks_for(num_stations)
    pitch = BLOCK + STREET
    boxes, cylinders, balls = [], [], []
    for bx in range(n):
        for by in range(n):
            x0, y0 = STREET + pitch * bx, STREET + pitch * by
            boxes += _buildings(rng, x0, y0)
    lines = STREET / 2 + pitch * np.arange(n + 1)
    length = lines[-1] + STREET / 2
    for line in lines:  # street furniture along both sides of every street, both ways
        for along_x in (True, False):
            for side in (-1.0, 1.0):
                _street_side(rng, line, along_x, side, lines, boxes, cylinders, balls)
    slots = _slots(n)
    return Town(np.array(boxes), np.array(cylinders).reshape(-1, 5), np.array(balls).reshape(-1, 4), slots,
                (length, length))


def _buildings(rng, x0, y0):
    """1–4 buildings in the block at ``(x0, y0)``: the block cut in two or four, each part set back 0–3 m,
    6–25 m tall; now and then a part left open (a yard)."""
    cuts_x = [0.0, rng.uniform(0.35, 0.65) * BLOCK, BLOCK] if rng.random() < 0.6 else [0.0, BLOCK]
    cuts_y = [0.0, rng.uniform(0.35, 0.65) * BLOCK, BLOCK] if rng.random() < 0.6 else [0.0, BLOCK]
    out = []
    for (ax, bx) in zip(cuts_x[:-1], cuts_x[1:]):
        for (ay, by) in zip(cuts_y[:-1], cuts_y[1:]):
            if rng.random() < 0.15:
                continue
            back = rng.uniform(0.0, 3.0, 4)
            lo = (x0 + ax + back[0], y0 + ay + back[1])
            hi = (x0 + bx - back[2], y0 + by - back[3])
            base = float(ground([lo, hi]).min()) - 0.5  # sunk into the slope
            out.append((lo[0], lo[1], base, hi[0], hi[1], base + 0.5 + rng.uniform(6.0, 25.0)))
    return out


def _street_side(rng, line, along_x, side, lines, boxes, cylinders, balls):
    """Cars at the kerb (3.5 m off the centre line), trees and poles on the pavement (5 m off) along one side
    of the street whose centre line is ``line`` (``along_x``: the street runs along x), none in a crossing
    (within ``STREET / 2 + 2.5`` of the crossing streets' centre lines ``lines``)."""
    def put(u, offset):  # along the street, across it → site xy
        return (u, line + side * offset) if along_x else (line + side * offset, u)

    def clear(u0, u1):
        return np.all((lines < u0 - STREET / 2 - 2.5) | (lines > u1 + STREET / 2 + 2.5))

    length = lines[-1] + STREET / 2
    u = rng.uniform(0.0, 8.0)
    while u < length - 5.0:
        if rng.random() < 0.5 and clear(u, u + 4.5):
            cx, cy = put(u + 2.25, 3.5)
            hx, hy = (2.25, 0.9) if along_x else (0.9, 2.25)
            z = float(ground((cx, cy)))
            boxes.append((cx - hx, cy - hy, z - 0.1, cx + hx, cy + hy, z + rng.uniform(1.4, 1.9)))
        u += rng.uniform(5.0, 14.0)
    u = rng.uniform(0.0, 10.0)
    while u < length:
        if not clear(u, u):
            u += rng.uniform(8.0, 16.0)
            continue
        x, y = put(u, 5.0)
        z = float(ground((x, y)))
        if rng.random() < 0.7:  # a tree: trunk, then a crown of overlapping balls
            top = z + rng.uniform(2.5, 4.0)
            cylinders.append((x, y, rng.uniform(0.15, 0.3), z - 0.1, top))
            radius = rng.uniform(1.5, 3.0)
            for _ in range(CROWN_BALLS):  # within 1.15 radii across and above top + 0.1 radius: never
                # down to a station's sensor on the street (≤ 2 m off the centre line, 1.6 m up)
                offset = np.clip(rng.normal(size=3), -1.0, 1.0) * radius * 0.45
                balls.append((x + offset[0], y + offset[1], top + radius * 0.8 + abs(offset[2]),
                              radius * rng.uniform(0.4, 0.7)))
        else:  # a pole
            cylinders.append((x, y, 0.08, z - 0.1, z + rng.uniform(5.0, 8.0)))
        u += rng.uniform(8.0, 16.0)


@numba.njit(cache=True)
def _first_hits(origin, dirs, boxes, cylinders, balls, slope, max_range):
    """``(R,)`` distance from ``origin (3,)`` along each unit ray ``dirs (R, 3)`` to the first surface (inf: none
    within ``max_range``): the ground ``z = slope · xy``, ``boxes``, ``cylinders`` and ``balls`` as in
    :class:`Town`."""
    out = np.full(dirs.shape[0], np.inf)
    ox, oy, oz = origin[0], origin[1], origin[2]
    for r in range(dirs.shape[0]):
        dx, dy, dz = dirs[r, 0], dirs[r, 1], dirs[r, 2]
        best = max_range
        rise = dz - slope[0] * dx - slope[1] * dy  # the ray's height over the ground changes at this rate
        if rise < 0.0:
            t = (slope[0] * ox + slope[1] * oy - oz) / rise
            if 0.0 < t < best:
                best = t
        for b in range(boxes.shape[0]):  # slabs
            near, far = 0.0, best
            for k in range(3):
                o, d = origin[k], dirs[r, k]
                lo, hi = boxes[b, k], boxes[b, k + 3]
                if abs(d) < 1e-15:
                    if o < lo or o > hi:
                        near, far = 1.0, 0.0
                        break
                    continue
                t0, t1 = (lo - o) / d, (hi - o) / d
                if t0 > t1:
                    t0, t1 = t1, t0
                near, far = max(near, t0), min(far, t1)
                if near > far:
                    break
            if near <= far and near > 0.0:
                best = near
        for c in range(cylinders.shape[0]):
            cx, cy, rad, z0, z1 = cylinders[c, 0], cylinders[c, 1], cylinders[c, 2], cylinders[c, 3], cylinders[c, 4]
            a = dx * dx + dy * dy
            if a > 1e-15:  # the side
                px, py = ox - cx, oy - cy
                bq = px * dx + py * dy
                disc = bq * bq - a * (px * px + py * py - rad * rad)
                if disc >= 0.0:
                    t = (-bq - math.sqrt(disc)) / a
                    if 0.0 < t < best and z0 <= oz + t * dz <= z1:
                        best = t
            if abs(dz) > 1e-15:  # the top
                t = (z1 - oz) / dz
                if 0.0 < t < best and (ox + t * dx - cx) ** 2 + (oy + t * dy - cy) ** 2 <= rad * rad:
                    best = t
        for p in range(balls.shape[0]):
            px, py, pz = ox - balls[p, 0], oy - balls[p, 1], oz - balls[p, 2]
            bq = px * dx + py * dy + pz * dz
            disc = bq * bq - (px * px + py * py + pz * pz - balls[p, 3] ** 2)
            if disc >= 0.0:
                t = -bq - math.sqrt(disc)
                if 0.0 < t < best:
                    best = t
        if best < max_range:
            out[r] = best
    return out


def _near(site: Town, sensor, reach):
    """The boxes, cylinders and balls of ``site`` whose footprint comes within ``reach`` of ``sensor``'s xy."""
    x, y = sensor[0], sensor[1]
    b = site.boxes
    gap = np.hypot(np.maximum(np.maximum(b[:, 0] - x, x - b[:, 3]), 0.0),
                   np.maximum(np.maximum(b[:, 1] - y, y - b[:, 4]), 0.0))
    c, p = site.cylinders, site.balls
    return (np.ascontiguousarray(b[gap <= reach]),
            np.ascontiguousarray(c[np.hypot(c[:, 0] - x, c[:, 1] - y) - c[:, 2] <= reach]),
            np.ascontiguousarray(p[np.hypot(p[:, 0] - x, p[:, 1] - y) - p[:, 3] <= reach]))


def scan_directions(step_deg: float = STEP_DEG) -> np.ndarray:
    """``(R, 3)`` unit rays of one station in its own frame: azimuth × elevation grid, ``step_deg`` apart."""
    az = np.radians(np.arange(0.0, 360.0, step_deg))
    el = np.radians(np.arange(ELEVATION_DEG[0], ELEVATION_DEG[1] + 1e-9, step_deg))
    az, el = np.meshgrid(az, el, indexing="ij")
    return np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], -1).reshape(-1, 3)


def station(site: Town, xy, heading_deg: float, seed: int, step_deg: float = STEP_DEG) -> Station:
    """One levelled station at ``xy (2,)`` (site frame, on the tripod above the ground), turned by
    ``heading_deg`` about the vertical: its points in its own frame and its pose."""
    rng = np.random.default_rng(seed)
    sensor = np.array([xy[0], xy[1], float(ground(xy)) + SENSOR_HEIGHT])
    h = np.radians(heading_deg)
    rot = np.array([[np.cos(h), -np.sin(h), 0.0], [np.sin(h), np.cos(h), 0.0], [0.0, 0.0, 1.0]])
    own = scan_directions(step_deg)
    t = _first_hits(sensor, own @ rot.T, *_near(site, sensor, MAX_RANGE), np.array(SLOPE), MAX_RANGE)
    keep = np.isfinite(t)
    t = t[keep] + rng.normal(scale=NOISE, size=int(keep.sum()))
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = rot, sensor
    return Station(t[:, None] * own[keep], pose)


def stations(num_stations: int, seed: int = 0, step_deg: float = STEP_DEG, progress=None) -> tuple:
    """``(town, [Station, ...])``: the first ``num_stations`` slots of :func:`town` (``seed``), each 0–1 m off
    the centre line across the street, with a random heading. ``progress(done, total)`` after each station."""
    if num_stations < 1:
        raise ValueError(f"num_stations must be >= 1 (got {num_stations})")
    site = town(num_stations, seed)
    rng = np.random.default_rng([seed, 1])
    out = []
    for k, xy in enumerate(site.slots[:num_stations]):
        jitter = rng.uniform(-1.0, 1.0, 2)
        out.append(station(site, xy + jitter, float(rng.uniform(0.0, 360.0)), seed * 1_000_003 + k, step_deg))
        if progress is not None:
            progress(k + 1, num_stations)
    return site, out
