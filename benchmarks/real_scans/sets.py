"""The real-scan sets of the benchmark: reading one (``data/<name>/``: one PLY per scan in its own frame,
``poses.conf`` with the true poses, ``meta.json`` with the source, licence, kind and the tune/report split),
the georeferenced variant of a set, and the pairs.

Conventions: a scan's pose ``P (4, 4)`` maps its own frame into the set's common frame
(:mod:`rpmnet_jax.io.poses`), so the motion taking scan ``a`` onto scan ``b`` is ``P_b⁻¹ P_a``.
"""

from __future__ import annotations

import dataclasses
import json
import os

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
DATA = os.path.join(HERE, "data")

# The georeferenced set (kind d): a real set moved into a national grid (UTM-like easting, northing, height in
# metres): every scan's own frame is shifted by GRID_ORIGIN, so the relative motions are the local set's and only
# the coordinates change (~4.1e6 m from the origin, where float32 keeps 0.25 m): a method that is right near the
# origin and wrong here loses precision or linearises about the origin.
GRID_ORIGIN = np.array([512_000.0, 4_100_000.0, 120.0])
GEOREFERENCED_FROM = "outdoor_lidar"  # the kind whose set is moved into the grid
# The voxel each kind gets, as the tools' documentation sets it for such data; every tool gets the same one.
VOXEL = {
    "object": 0.002,  # 1 % of a 20 cm statuette: the ratio of Open3D's tutorial (5 cm on its ~5 m fragments)
    "indoor": 0.05,  # Open3D's registration tutorials on RGB-D fragments of rooms
    "outdoor_lidar": 0.3,  # KISS-Matcher's default resolution (KITTI), small_gicp's 0.25 m example
}
# Whether a kind's scans are stored in their sensor's frame (the sensor at the frame's origin): the RGB-D frames
# and LiDAR sweeps are; the Stanford range scans' frame origin is the turntable, not the scanner.
SENSOR_AT_ORIGIN = {"object": False, "indoor": True, "outdoor_lidar": True}
OVERLAP_DISTANCE = 3.0  # × voxel: a point of one scan overlaps the other if it has a point this near (truth)
MIN_OVERLAP = 0.3  # pairs whose overlap (share of the source's points, at the true poses) is at least this


@dataclasses.dataclass
class ScanSet:
    """One set's part: ``clouds[i] (N_i, 3)`` float64 in scan ``i``'s frame, ``poses (S, 4, 4)`` (truth)."""
    name: str
    kind: str
    names: list
    clouds: list
    poses: np.ndarray
    voxel: float  # the voxel the tools' documentation gives for this kind of data (VOXEL)
    extent: float  # diagonal of the part's bounding box in the common frame (success: translation < 2 %)
    meta: dict
    origins: np.ndarray  # (S, 3): each scan's frame origin in its file's coordinates (errors are taken there)
    sensors: bool  # whether the origins are the sensor positions (normals can be turned toward them)


def available() -> list:
    """Names of the sets under ``data/`` (folders with a ``meta.json``), sorted."""
    if not os.path.isdir(DATA):
        return []
    return sorted(d for d in os.listdir(DATA) if os.path.isfile(os.path.join(DATA, d, "meta.json")))


def kind(name: str) -> str:
    """The kind of set ``name`` (its ``meta.json``)."""
    with open(os.path.join(DATA, name, "meta.json")) as f:
        return json.load(f)["kind"]


def load(name: str, part: str) -> ScanSet:
    """The ``part`` (``"tune"``, ``"report"`` or ``"all"``) of set ``name``; ``name`` may also be
    ``"<set>@grid"``: that set moved into the national grid (:func:`georeferenced`)."""
    from rpmnet_jax.io import clouds as clouds_io
    from rpmnet_jax.io import poses as poses_io
    if name.endswith("@grid"):
        return georeferenced(load(name[:-len("@grid")], part))
    folder = os.path.join(DATA, name)
    with open(os.path.join(folder, "meta.json")) as f:
        meta = json.load(f)
    if part not in ("tune", "report", "all"):
        raise ValueError(f"part must be 'tune', 'report' or 'all', got {part!r}")
    names = meta["tune"] + meta["report"] if part == "all" else list(meta[part])
    truth = poses_io.read_poses(os.path.join(folder, "poses.conf"))
    files = {os.path.splitext(f)[0]: f for f in os.listdir(folder) if f.endswith(".ply")}
    clouds = [np.asarray(clouds_io.read_cloud(os.path.join(folder, files[n]))[0], np.float64) for n in names]
    poses = np.stack([truth[n] for n in names])
    return ScanSet(name, meta["kind"], names, clouds, poses, VOXEL[meta["kind"]], _extent(clouds, poses), meta,
                   np.zeros((len(names), 3)), SENSOR_AT_ORIGIN[meta["kind"]])


def georeferenced(s: ScanSet) -> ScanSet:
    """``s`` moved into the national grid: every scan holds ``p + GRID_ORIGIN``; the poses become
    ``G P G⁻¹`` (``G`` the shift), so the motion between any two scans is the same rigid motion written in grid
    coordinates, and each scan's sensor sits at ``GRID_ORIGIN``."""
    clouds = [points + GRID_ORIGIN for points in s.clouds]
    poses = translation(GRID_ORIGIN) @ s.poses @ translation(-GRID_ORIGIN)
    meta = dict(s.meta, kind="georeferenced", georeferenced_from=s.name)
    return ScanSet(s.name + "@grid", "georeferenced", s.names, clouds, poses, s.voxel, _extent(clouds, poses), meta,
                   s.origins + GRID_ORIGIN, s.sensors)


def subset(s: ScanSet, keep) -> ScanSet:
    """The scans ``keep`` (indices) of ``s``; the extent is the subset's."""
    clouds, poses = [s.clouds[i] for i in keep], s.poses[keep]
    return dataclasses.replace(s, names=[s.names[i] for i in keep], clouds=clouds, poses=poses,
                               extent=_extent(clouds, poses), origins=s.origins[keep])


def _extent(clouds, poses) -> float:
    world = np.concatenate([p @ pose[:3, :3].T + pose[:3, 3] for p, pose in zip(clouds, poses)])
    return float(np.linalg.norm(world.max(0) - world.min(0)))


def overlap(s: ScanSet, a: int, b: int) -> float:
    """Share of scan ``a``'s points within ``OVERLAP_DISTANCE × voxel`` of scan ``b`` at the true poses."""
    from scipy.spatial import cKDTree
    motion = np.linalg.inv(s.poses[b]) @ s.poses[a]
    moved = s.clouds[a] @ motion[:3, :3].T + motion[:3, 3]
    dist, _ = cKDTree(s.clouds[b]).query(moved, distance_upper_bound=OVERLAP_DISTANCE * s.voxel)
    return float(np.mean(np.isfinite(dist)))


def pairs(s: ScanSet, max_pairs: int, seed: int = 0) -> list:
    """Up to ``max_pairs`` ordered pairs ``(a, b)`` of the part's scans whose overlap is at least
    ``MIN_OVERLAP`` (a seeded choice among them when there are more), in a fixed order."""
    candidates = [(a, b) for a in range(len(s.names)) for b in range(len(s.names))
                  if a < b and overlap(s, a, b) >= MIN_OVERLAP]
    rng = np.random.default_rng(seed)
    if len(candidates) > max_pairs:
        keep = np.sort(rng.choice(len(candidates), max_pairs, replace=False))
        candidates = [candidates[k] for k in keep]
    return candidates


def translation(offset) -> np.ndarray:
    """The ``(4, 4)`` motion ``x ↦ x + offset`` (``offset (3,)``)."""
    out = np.eye(4)
    out[:3, 3] = offset
    return out


def errors(estimate, truth, at) -> tuple:
    """``(rotation error °, translation error)`` of ``estimate (4, 4)`` against ``truth (4, 4)`` (both map a
    source onto a reference), the translation error being the displacement of the source's point ``at (3,)``
    (its frame's origin): the same numbers whether the clouds sit near the origin or in a national grid."""
    from rpmnet_jax import metrics
    to_local, back = translation(-np.asarray(at)), translation(at)
    return metrics.transform_errors(to_local @ estimate @ back, to_local @ truth @ back)


def turn(points: np.ndarray, seed: int) -> tuple:
    """``(turned points, motion (4, 4))``: ``points (N, 3)`` turned by a seeded angle in [90°, 180°] about a
    random axis through their centroid; the motion maps the original points onto the turned ones."""
    from scipy.spatial.transform import Rotation
    rng = np.random.default_rng(seed)
    axis = rng.normal(size=3)
    angle = np.radians(rng.uniform(90.0, 180.0))
    rot = Rotation.from_rotvec(axis / np.linalg.norm(axis) * angle).as_matrix()
    centre = points.mean(0)
    motion = np.eye(4)
    motion[:3, :3], motion[:3, 3] = rot, centre - rot @ centre
    return points @ rot.T + motion[:3, 3], motion
