"""Simulated terrestrial-scanner stations inside a room, with their true poses: the scene users register indoors.

A room is an axis-aligned box of free space (walls, floor and ceiling are its faces) with a door recess cut into
one wall, and solid boxes inside it (columns from floor to ceiling, furniture). A station is a levelled 360°
scanner on a tripod: rays on an azimuth × elevation grid from the sensor, the nearest hit of each, Gaussian noise
along the ray; each station's points are in its own frame (the sensor at the origin, a random heading), as a
scanner writes them. A rectangular room is nearly symmetric under a half turn: only the furniture, the columns and
the door tell the two ways apart, as in real rooms.

Pose: ``room point = R p + t`` for a point ``p`` of the station's frame.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

SIZE = (10.0, 7.0, 3.0)  # the room's free space, metres
DOOR = ((4.0, 5.0), 0.3, 2.1)  # the recess in the far wall (y = SIZE[1]): its x span, depth and height
COLUMNS = (((2.0, 2.4), (2.0, 2.4)), ((7.6, 8.0), (4.6, 5.0)))  # floor-to-ceiling columns: x and y spans
FURNITURE = (((0.3, 2.1), (5.6, 6.6), 0.75), ((6.5, 8.5), (0.4, 1.2), 0.9), ((4.3, 4.9), (3.0, 3.6), 0.45),
             ((8.9, 9.6), (2.5, 4.5), 1.8))  # boxes on the floor: x and y spans, height (a table, a desk, a crate,
# a cupboard)
SENSOR_HEIGHT = 1.5  # the tripod
STEP_DEG = 0.6  # angular resolution of the scanner (azimuth and elevation)
ELEVATION_DEG = (-60.0, 90.0)  # what the scanner sees below and above the horizon
NOISE = 0.003  # metres, along the ray


class Station(NamedTuple):
    points: np.ndarray  # (N, 3) float64, the station's frame (sensor at the origin)
    pose: np.ndarray  # (4, 4) float64: station frame → room frame


def boxes() -> np.ndarray:
    """``(B, 2, 3)`` the solid boxes inside the room (min and max corners): the columns, then the furniture."""
    out = [((x[0], y[0], 0.0), (x[1], y[1], SIZE[2])) for x, y in COLUMNS]
    out += [((x[0], y[0], 0.0), (x[1], y[1], h)) for x, y, h in FURNITURE]
    return np.array(out, np.float64)


def _exit(origins, dirs, lo, hi):
    """``(R,)`` the distance along each ray (from inside the box ``lo, hi (3,)``) to where it leaves the box."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(dirs > 0, (hi - origins) / dirs, np.where(dirs < 0, (lo - origins) / dirs, np.inf))
    return t.min(axis=1)


def _entry(origins, dirs, lo, hi):
    """``(R,)`` the distance along each ray to where it enters the solid box ``lo, hi (3,)`` (inf: a miss)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        a, b = (lo - origins) / dirs, (hi - origins) / dirs
    near = np.nanmax(np.minimum(a, b), axis=1)
    far = np.nanmin(np.maximum(a, b), axis=1)
    return np.where((far >= near) & (near > 0), near, np.inf)


def cast(sensor: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """``(R,)`` distance from ``sensor (3,)`` (room frame, inside the free space) to the first surface along each
    unit ray ``dirs (R, 3)``."""
    origins = np.broadcast_to(np.asarray(sensor, np.float64), dirs.shape)
    room_hi = np.array(SIZE)
    t = _exit(origins, dirs, np.zeros(3), room_hi)
    hit = origins + t[:, None] * dirs
    (x0, x1), depth, height = DOOR
    through = (np.abs(hit[:, 1] - SIZE[1]) < 1e-9) & (hit[:, 0] > x0) & (hit[:, 0] < x1) & (hit[:, 2] < height)
    if np.any(through):  # into the recess: on to its back or side walls
        t[through] = _exit(origins[through], dirs[through], np.array([x0, 0.0, 0.0]),
                           np.array([x1, SIZE[1] + depth, height]))
    for lo, hi in boxes():
        t = np.minimum(t, _entry(origins, dirs, lo, hi))
    return t


def station(sensor_xy, heading_deg: float, seed: int, step_deg: float = STEP_DEG) -> Station:
    """One scanner station at ``sensor_xy (2,)`` (room frame, on the tripod's height), turned by ``heading_deg``
    about the vertical: its points in its own frame and its pose."""
    rng = np.random.default_rng(seed)
    az = np.radians(np.arange(0.0, 360.0, step_deg))
    el = np.radians(np.arange(ELEVATION_DEG[0], ELEVATION_DEG[1], step_deg))
    az, el = np.meshgrid(az, el, indexing="ij")
    dirs = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], -1).reshape(-1, 3)
    sensor = np.array([sensor_xy[0], sensor_xy[1], SENSOR_HEIGHT])
    t = cast(sensor, dirs)
    keep = np.isfinite(t)
    dirs, t = dirs[keep], t[keep] + rng.normal(scale=NOISE, size=int(keep.sum()))
    h = np.radians(heading_deg)
    rot = np.array([[np.cos(h), -np.sin(h), 0.0], [np.sin(h), np.cos(h), 0.0], [0.0, 0.0, 1.0]])
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = rot, sensor
    return Station((t[:, None] * dirs) @ rot, pose)  # the room ray R d seen in the station's frame: d = Rᵀ (R d)


STATIONS = ((1.5, 1.5), (5.0, 1.8), (8.5, 2.0), (1.5, 4.5), (5.5, 5.2), (8.4, 6.2))  # free floor, all in the room


def stations(seed: int = 0, step_deg: float = STEP_DEG) -> list:
    """The six stations of :data:`STATIONS`, each with a random heading (``seed``)."""
    headings = np.random.default_rng(seed).uniform(0.0, 360.0, len(STATIONS))
    return [station(xy, float(h), seed * 100 + k, step_deg) for k, (xy, h) in enumerate(zip(STATIONS, headings))]
