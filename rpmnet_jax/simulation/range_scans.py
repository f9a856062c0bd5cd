"""Simulated range scans of a triangle mesh with their true poses, like a scanner's: a pinhole depth camera on a
sphere around the mesh, the nearest exact ray–triangle hit per pixel (a z-buffer), Gaussian noise along each
pixel's ray, grazing hits dropped, each scan's points in its own sensor frame.

Sensor frame: x right, y down, z along the optical axis. Pixel ``(u, v)`` of a ``W × W`` image looks along
``((u + ½ − W/2) / f, (v + ½ − W/2) / f, 1)`` with ``f = (W/2) / tan(fov/2)``. A pose maps sensor points into
the mesh frame: ``mesh point = R p + t``.
"""

from __future__ import annotations

import json
import math
import os
from typing import NamedTuple

import numba
import numpy as np

from rpmnet_jax import input_checks as checks
from rpmnet_jax.io import clouds, poses as poses_io

FILL = 0.9  # the mesh's bounding sphere spans this share of the field of view (default distance)
ROLL_JITTER_DEG = 10.0  # uniform ± about the optical axis
DISTANCE_JITTER = 0.05  # uniform ± share of the distance
DIRECTION_JITTER = 0.15  # std of the viewing direction's jitter, as a share of the mean angle between cameras
MAX_DIRECTION_JITTER_DEG = 5.0
EDGE_TOLERANCE = 1e-9  # barycentric slack: rays through a shared edge hit one of its triangles, never neither


class RangeScan(NamedTuple):
    points: np.ndarray  # (N, 3) float64, sensor frame
    pose: np.ndarray  # (4, 4) float64: sensor → mesh frame


@numba.njit(cache=True)
def _zbuffer(tris, size, focal):
    """``(depth (W, W), face (W, W))``: per pixel the nearest hit's z (inf if none) and its triangle (-1 if
    none) of ``tris (F, 3, 3)`` (sensor frame; vertex rows), by Möller–Trumbore for each pixel centre in each
    triangle's projected bounding box."""
    depth = np.full((size, size), np.inf)
    face = np.full((size, size), -1, np.int64)
    half = 0.5 * size
    for f in range(tris.shape[0]):
        a, b, c = tris[f, 0], tris[f, 1], tris[f, 2]
        u0, u1, v0, v1 = 0, size - 1, 0, size - 1
        if min(a[2], b[2], c[2]) > 0.0:  # all in front: the projected box, else every pixel
            ua, ub, uc = a[0] / a[2], b[0] / b[2], c[0] / c[2]
            va, vb, vc = a[1] / a[2], b[1] / b[2], c[1] / c[2]
            u0 = max(u0, int(math.floor(min(ua, ub, uc) * focal + half - 0.5)))
            u1 = min(u1, int(math.ceil(max(ua, ub, uc) * focal + half - 0.5)))
            v0 = max(v0, int(math.floor(min(va, vb, vc) * focal + half - 0.5)))
            v1 = min(v1, int(math.ceil(max(va, vb, vc) * focal + half - 0.5)))
        e1, e2 = b - a, c - a
        for v in range(v0, v1 + 1):
            dy = (v + 0.5 - half) / focal
            for u in range(u0, u1 + 1):
                dx = (u + 0.5 - half) / focal
                px, py, pz = dy * e2[2] - e2[1], e2[0] - dx * e2[2], dx * e2[1] - dy * e2[0]  # d × e2
                det = e1[0] * px + e1[1] * py + e1[2] * pz
                if det == 0.0:
                    continue
                sx, sy, sz = -a[0], -a[1], -a[2]  # ray origin − a
                bu = (sx * px + sy * py + sz * pz) / det
                if bu < -EDGE_TOLERANCE or bu > 1.0 + EDGE_TOLERANCE:
                    continue
                qx, qy, qz = sy * e1[2] - sz * e1[1], sz * e1[0] - sx * e1[2], sx * e1[1] - sy * e1[0]  # s × e1
                bv = (dx * qx + dy * qy + qz) / det
                if bv < -EDGE_TOLERANCE or bu + bv > 1.0 + EDGE_TOLERANCE:
                    continue
                t = (e2[0] * qx + e2[1] * qy + e2[2] * qz) / det
                if 0.0 < t < depth[v, u]:
                    depth[v, u], face[v, u] = t, f
    return depth, face


def focal_length(image_size: int, fov_deg: float) -> float:
    """Pixels from the optical centre to the image edge over ``tan(fov / 2)``."""
    return 0.5 * image_size / math.tan(math.radians(fov_deg) / 2)


def scan(vertices, faces, pose, *, image_size: int = 640, fov_deg: float = 40.0, noise: float = 0.0,
         max_incidence_deg: float = 80.0, rng=None) -> RangeScan:
    """The scan of the mesh ``vertices (V, 3)``, ``faces (F, 3)`` by a camera at ``pose (4, 4)`` (sensor → mesh
    frame): one point per pixel whose ray hits the mesh at most ``max_incidence_deg`` from the face normal, moved
    along the ray by Gaussian noise of std ``noise`` (``rng``: a NumPy generator, needed when ``noise > 0``)."""
    pose = np.asarray(pose, np.float64)
    sensor = (np.asarray(vertices, np.float64) - pose[:3, 3]) @ pose[:3, :3]  # R^T (x - t)
    tris = np.ascontiguousarray(sensor[np.asarray(faces, np.int64)])
    focal = focal_length(image_size, fov_deg)
    depth, face = _zbuffer(tris, image_size, focal)
    v, u = np.nonzero(face >= 0)
    rays = np.stack([(u + 0.5 - image_size / 2) / focal, (v + 0.5 - image_size / 2) / focal, np.ones(len(u))], 1)
    hits = depth[v, u, None] * rays
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    hit_tris = tris[face[v, u]]
    normals = np.cross(hit_tris[:, 1] - hit_tris[:, 0], hit_tris[:, 2] - hit_tris[:, 0])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    keep = np.abs(np.sum(normals * rays, axis=1)) >= math.cos(math.radians(max_incidence_deg))
    hits, rays = hits[keep], rays[keep]
    if noise > 0:
        hits += rng.normal(0.0, noise, (len(hits), 1)) * rays
    return RangeScan(hits, pose)


def look_at(position, target, roll_deg: float = 0.0) -> np.ndarray:
    """The ``(4, 4)`` pose of a camera at ``position (3,)`` looking at ``target (3,)``: image up as close to
    the mesh's +z as the view allows (+y when looking along z), then rolled by ``roll_deg`` about the optical
    axis."""
    z = np.asarray(target, np.float64) - position
    z /= np.linalg.norm(z)
    up = np.array([0.0, 0.0, 1.0]) if abs(z[2]) < 0.99 else np.array([0.0, 1.0, 0.0])
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)  # image down
    r = math.radians(roll_deg)
    x, y = math.cos(r) * x + math.sin(r) * y, -math.sin(r) * x + math.cos(r) * y
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = np.stack([x, y, z], 1), position
    return pose


def sensor_poses(center, distance: float, num_scans: int, rng) -> np.ndarray:
    """``(S, 4, 4)`` camera poses looking at ``center (3,)`` from a Fibonacci sphere of radius ``distance``
    (neighbouring cameras overlap), each direction, distance and roll jittered a little (``rng``)."""
    i = np.arange(num_scans) + 0.5
    z = 1.0 - 2.0 * i / num_scans
    phi = math.pi * (3.0 - math.sqrt(5.0)) * i  # the golden angle
    dirs = np.stack([np.sqrt(1 - z ** 2) * np.cos(phi), np.sqrt(1 - z ** 2) * np.sin(phi), z], 1)
    spread = min(math.radians(MAX_DIRECTION_JITTER_DEG), DIRECTION_JITTER * math.sqrt(4 * math.pi / num_scans))
    poses = []
    for d in dirs:
        axis = np.cross(d, rng.normal(size=3))
        axis /= np.linalg.norm(axis)
        angle = rng.normal(0.0, spread)
        d = d * math.cos(angle) + np.cross(axis, d) * math.sin(angle)  # Rodrigues, axis ⟂ d
        dist = distance * (1.0 + rng.uniform(-DISTANCE_JITTER, DISTANCE_JITTER))
        poses.append(look_at(center + dist * d, center, rng.uniform(-ROLL_JITTER_DEG, ROLL_JITTER_DEG)))
    return np.stack(poses)


def simulate(vertices, faces, num_scans: int, *, image_size: int = 640, fov_deg: float = 40.0,
             noise: float = 0.0005, distance: float | None = None, max_incidence_deg: float = 80.0,
             seed: int = 0, progress=None) -> list:
    """``num_scans`` :class:`RangeScan` of the mesh ``vertices (V, 3)``, ``faces (F, 3)`` from cameras around it
    (:func:`sensor_poses` about the centre of its bounding box; :func:`scan` each). ``distance`` (mesh units)
    defaults to the one at which the bounding sphere spans ``FILL`` of the field of view; ``noise``: std along
    each ray, mesh units. Deterministic per ``seed`` (the poses and pixels do not depend on ``noise``).
    ``progress(done, total)`` after each scan."""
    vertices, faces = np.asarray(vertices, np.float64), np.asarray(faces)
    if vertices.ndim != 2 or vertices.shape[1] != 3 or not np.all(np.isfinite(vertices)):
        raise ValueError(f"vertices must be a finite (V, 3) array, got shape {vertices.shape}")
    if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0 or faces.dtype.kind not in "iu":
        raise ValueError(f"faces must be a non-empty (F, 3) integer array, got {faces.dtype} {faces.shape}")
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise ValueError(f"faces index vertices outside 0..{len(vertices) - 1}")
    checks.require_at_least("num_scans", num_scans, 1)
    checks.require_at_least("image_size", image_size, 1)
    checks.require_positive("distance", distance, optional=True)
    checks.require_at_least("noise", noise, 0.0)
    if not 0 < fov_deg < 180 or not 0 < max_incidence_deg <= 90:
        raise ValueError(f"fov_deg must be in (0, 180) and max_incidence_deg in (0, 90], got {fov_deg}, "
                         f"{max_incidence_deg}")
    used = vertices[np.unique(faces)]
    center = 0.5 * (used.min(0) + used.max(0))
    radius = float(np.linalg.norm(used - center, axis=1).max())
    if distance is None:
        distance = radius / math.sin(FILL * math.radians(fov_deg) / 2)
    elif distance <= radius:
        raise ValueError(f"distance {distance} puts cameras inside the mesh's bounding sphere (radius {radius:.4g})")
    pose_rng, noise_rng = (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(2))
    scans = []
    for k, pose in enumerate(sensor_poses(center, distance, num_scans, pose_rng)):
        scans.append(scan(vertices, faces, pose, image_size=image_size, fov_deg=fov_deg, noise=noise,
                          max_incidence_deg=max_incidence_deg, rng=noise_rng))
        if progress is not None:
            progress(k + 1, num_scans)
    return scans


def write_set(folder: str, scans, *, shuffle_seed: int | None = None, settings: dict | None = None) -> list:
    """Writes ``scans`` to ``folder`` as ``scan000.ply …`` (binary PLY, float64) and ``truth.conf`` (each
    file's pose, :func:`rpmnet_jax.io.poses.write_poses`, in file-name order); with ``shuffle_seed`` file ``k``
    holds scan ``perm[k]`` of a seeded permutation, so file order says nothing about overlap. ``settings``
    (how the set was made) go to ``settings.json`` with that order. A folder holding other point-cloud files is
    refused (``ValueError``): they would read as scans of the set. Returns the scan index in each file, in
    file order."""
    order = (list(range(len(scans))) if shuffle_seed is None
             else np.random.default_rng(shuffle_seed).permutation(len(scans)).tolist())
    width = max(3, len(str(len(scans) - 1)))
    names = [f"scan{k:0{width}d}" for k in range(len(scans))]
    os.makedirs(folder, exist_ok=True)
    others = sorted(f for f in os.listdir(folder)
                    if f.lower().endswith(clouds.FORMATS) and os.path.splitext(f)[0] not in names)
    if others:  # a reader of the folder would take them for scans of this set
        raise ValueError(f"{folder} holds other point-cloud files ({', '.join(others[:3])}, ...); use an empty "
                         "folder")
    for name, s in zip(names, order):
        clouds.write_cloud(os.path.join(folder, name + ".ply"), scans[s].points)
    poses_io.write_poses(os.path.join(folder, "truth.conf"), names, [scans[s].pose for s in order])
    if settings is not None:
        with open(os.path.join(folder, "settings.json"), "w") as f:
            json.dump({**settings, "files": names, "simulated_index": order}, f, indent=1)
    return order
