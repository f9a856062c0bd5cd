"""Rebuilds ``benchmarks/real_scans/data/kitti_04/`` from a copy of its source repository.

The set is 26 real outdoor LiDAR sweeps (Velodyne HDL-64E) of the KITTI odometry benchmark, sequence 04 (a
straight country road), with the benchmark's ground-truth poses. The sweeps come from a public GitHub repository
that carries frames 0-50 of sequence 04 unchanged (``velodyne/*.bin``, ``calib.txt``) and the ground-truth
``poses/04.txt`` under ``KITTI_SAMPLE/ODOMETRY/``; get it with::

    git clone https://github.com/AbdelazizHamadi/3D-scene-reconstruction-using-camera-Lidar-with-KITTI-dataset.git kitti_sample
    git -C kitti_sample checkout 00bc059cab648642c9862d2070f3069460d6c45e

then::

    python benchmarks/real_scans/build_lidar.py --source kitti_sample --out benchmarks/real_scans/data/kitti_04

(``--check`` also prints the pose check of ``SOURCE.md``; it needs SciPy.)

Only the data are read (``sequences/04/velodyne/<frame>.bin``, ``sequences/04/calib.txt``, ``poses/04.txt``); no
code of that repository is used. Every second frame (0, 2, ..., 50) is kept, about 2.7 m apart. Each sweep stays in
its own Velodyne frame (metres): the points between ``MIN_RANGE`` and ``MAX_RANGE`` of the sensor, thinned to the
first point (in file order) of each occupied ``VOXEL`` cube, then to at most ``MAX_POINTS`` drawn without
replacement by a generator seeded from ``SEED`` and the sweep's name (kept in file order); the coordinates are the
source's float32 values, unchanged, written as binary little-endian PLY with float32 ``x y z`` only. KITTI's poses
are those of the left grey camera; a sweep's pose is ``Tr^-1 @ P @ Tr`` (``P`` the camera pose of ``poses/04.txt``,
``Tr`` the Velodyne -> camera transform of ``calib.txt``), i.e. Velodyne frame -> the Velodyne frame of frame 0.
``poses.conf`` holds them in :func:`rpmnet_jax.io.poses.write_poses`' convention; ``meta.json`` and ``SOURCE.md``
say where it all came from. Run it twice and the output is byte for byte the same.
"""

from __future__ import annotations

import os
import sys

import numpy as np

import build_common as common

SET_NAME = "kitti_04"
SOURCE_URL = "https://github.com/AbdelazizHamadi/3D-scene-reconstruction-using-camera-Lidar-with-KITTI-dataset"
SOURCE_COMMIT = "00bc059cab648642c9862d2070f3069460d6c45e"
SOURCE_DIR = "KITTI_SAMPLE/ODOMETRY"
SEQUENCE = "04"
FRAMES = list(range(0, 51, 2))  # every second frame of the 51 in the source: 26 sweeps, ~2.7 m apart
NAMES = [f"kitti04_{i:06d}" for i in FRAMES]
TUNE = NAMES[:10]  # frames 0-18: the first ~25 m of road
REPORT = NAMES[10:]  # frames 20-50: the next ~42 m
MIN_RANGE = 1.0  # metres from the sensor
MAX_RANGE = 50.0
VOXEL = 0.25  # metres: the first point of each occupied cube is kept
MAX_POINTS = 30_000
SEED = 20240612
LICENCE = (
    "KITTI Vision Benchmark Suite (odometry benchmark, sequence 04): \"All datasets and benchmarks on this page are "
    "copyright by us and published under the Creative Commons Attribution-NonCommercial-ShareAlike 3.0 License. "
    "This means that you must attribute the work in the manner specified by the authors, you may not use this work "
    "for commercial purposes and if you alter, transform, or build upon this work, you may distribute the resulting "
    "work only under the same license.\" (CC BY-NC-SA 3.0, https://creativecommons.org/licenses/by-nc-sa/3.0/; "
    "non-commercial redistribution with attribution is allowed, and this subsample is distributed under the same "
    "licence.) Attribution: A. Geiger, P. Lenz, R. Urtasun, Are we ready for Autonomous Driving? The KITTI Vision "
    "Benchmark Suite, CVPR 2012, https://www.cvlibs.net/datasets/kitti/ . The source GitHub repository's own "
    "licence (GPL-3.0) covers its code, none of which is used here."
)
SENSOR = ("Velodyne HDL-64E (KITTI recording platform, 10 Hz, 64 beams); sweeps as published in the KITTI odometry "
          "benchmark, each in the Velodyne's own frame (x forward, y left, z up)")
SOURCE_MD = """\
# kitti_04: real outdoor LiDAR sweeps (KITTI odometry, sequence 04), with ground-truth poses

Written by `benchmarks/real_scans/build_lidar.py`; rebuild it with that script rather than editing it.

## Source

- Data: the KITTI Vision Benchmark Suite, visual odometry / SLAM benchmark, sequence 04 (a straight country road
  near Karlsruhe), https://www.cvlibs.net/datasets/kitti/eval_odometry.php (Karlsruhe Institute of Technology and
  Toyota Technological Institute at Chicago; A. Geiger, P. Lenz, R. Urtasun, CVPR 2012). Ground truth: the
  benchmark's `poses/04.txt` (from the car's GPS/IMU with RTK correction; KITTI states it as accurate to < 10 cm).
- Copy read: {url}
  at commit `{commit}`, folder `{path}/`: frames 000000-000050 of `sequences/04/velodyne/` (float32
  `x y z reflectance`, as KITTI ships them), `sequences/04/calib.txt` and the ground-truth `poses/04.txt`
  (271 poses, the whole sequence). Only these data files were read; no code of that repository is used or copied.
- Sensor: {sensor}.
- Units: metres.

## Licence

The data are KITTI's. KITTI's terms, as its web site states them:

> All datasets and benchmarks on this page are copyright by us and published under the Creative Commons
> Attribution-NonCommercial-ShareAlike 3.0 License. This means that you must attribute the work in the manner
> specified by the authors, you may not use this work for commercial purposes and if you alter, transform, or
> build upon this work, you may distribute the resulting work only under the same license.

CC BY-NC-SA 3.0 (https://creativecommons.org/licenses/by-nc-sa/3.0/) allows non-commercial redistribution with
attribution; this subsample is an adaptation and is distributed under the same licence (CC BY-NC-SA 3.0), for
non-commercial use only. Attribution: A. Geiger, P. Lenz and R. Urtasun, "Are we ready for Autonomous Driving?
The KITTI Vision Benchmark Suite", CVPR 2012. The source GitHub repository's own licence (GPL-3.0) covers its
code, none of which is used here.

## What is here

- {count} sweeps: every second frame of frames 0-50 ({first}-{last}), 2.63-2.86 m apart (1.31-1.43 m per frame
  at 47-52 km/h; {travel:.1f} m travelled from the first to the last kept sweep), split by sweep into two
  contiguous stretches of the road that share no sweep:
  - `tune` (frames 0-18): {tune}
  - `report` (frames 20-50): {report}
- Each `<sweep>.ply`: binary little-endian PLY, float32 `x y z` only, in the sweep's own Velodyne frame (not
  posed), in metres; reflectance dropped. Points {min_range:g}-{max_range:g} m from the sensor, thinned to the
  first point (in file order) of each occupied {voxel:g} m cube, then to at most {max_points} drawn uniformly without
  replacement by `numpy.random.default_rng([{seed}, crc32(sweep name)])` and kept in file order. The coordinates
  are the source's float32 values, unchanged. The sources have 122,796-125,512 points, 117,866-122,906 of them in
  range, in 23,541-31,304 occupied cubes, so the sweeps here have 23,541-30,000 points (fewer further along the
  road).
- `poses.conf`: each sweep's ground-truth pose, Velodyne frame -> common frame (the Velodyne frame of frame 0),
  written by `rpmnet_jax.io.poses.write_poses`. KITTI's poses are those of the left grey camera (`P`, camera
  frame -> frame 0's camera frame); a sweep's pose is `inv(Tr) @ P @ Tr` with `Tr` the Velodyne -> camera
  transform of `calib.txt`.
- `meta.json`: name, kind, source, commit, licence, units, sensor, the tune/report split, the KITTI frame of each
  sweep, and the thinning parameters.

The sweeps are KITTI's as published, each in its own sensor frame (not in a world frame). They are already
deskewed: KITTI's odometry `readme.txt` says the Velodyne's rotation "has been eliminated from this postprocessed
data by compensating for the egomotion!! Note that this is in contrast to the raw data." (quoted in
https://github.com/TixiaoShan/LIO-SAM/issues/34); nothing is re-deskewed here. Whatever moved during the drive (other
traffic) is left in.

## Check of the poses

Printed by `build_lidar.py --check`. Each of the 25 pairs of consecutive kept sweeps (2.63-2.86 m apart), both
posed: of the points of the first (full-resolution source, in range), {overlap} lie within 0.5 m of the second.
Their point-to-plane distance to the second sweep (normal from its 12 nearest points, planar neighbourhoods
only): median {p2p_full} per pair (points ahead of the sensor {front}, behind it {rear}), {within5} of them
within 5 cm; their nearest-neighbour distance: median {nn_full} (bounded by the HDL-64E's ring spacing, not by
the poses). On the thinned files here the point-to-plane median is {p2p_kept}. With `Tr` applied the other way
round (`Tr @ P @ inv(Tr)`) the point-to-plane median is {swapped} and only {swapped5} lie within 5 cm; with the
camera poses used unconverted, only {camera} of the points have a neighbour within 1 m.

## Rebuild

    git clone {url}.git kitti_sample
    git -C kitti_sample checkout {commit}
    python benchmarks/real_scans/build_lidar.py --source kitti_sample --out benchmarks/real_scans/data/kitti_04
"""
# The numbers of the pose check, as `--check` printed them for this build (SOURCE.md quotes them).
CHECK = {"overlap": "84-90%", "p2p_full": "2.1-2.9 cm", "front": "2.0-2.5 cm", "rear": "2.2-3.2 cm",
         "within5": "76-88%", "nn_full": "6.3-9.2 cm", "p2p_kept": "1.3-2.6 cm", "swapped": "8.0-13.2 cm",
         "swapped5": "18-33%", "camera": "6-13%"}


def read_kitti_poses(path: str) -> np.ndarray:
    """``(F, 4, 4)`` poses of a KITTI odometry ``poses/<seq>.txt`` (12 numbers a line: a 3x4 matrix, row-major)."""
    rows = np.loadtxt(path, dtype=np.float64, ndmin=2)
    if rows.shape[1] != 12:
        raise ValueError(f"{path}: {rows.shape[1]} numbers a line, expected 12")
    poses = np.tile(np.eye(4), (len(rows), 1, 1))
    poses[:, :3, :] = rows.reshape(-1, 3, 4)
    return poses


def read_velo_to_cam(path: str) -> np.ndarray:
    """``(4, 4)`` Velodyne -> left camera transform: the ``Tr:`` line of a KITTI odometry ``calib.txt``."""
    with open(path) as f:
        for line in f:
            key, _, values = line.partition(":")
            if key.strip() == "Tr":
                tr = np.eye(4)
                tr[:3, :] = np.array(values.split(), dtype=np.float64).reshape(3, 4)
                return tr
    raise ValueError(f"{path}: no 'Tr:' line")


def read_sweep(path: str) -> np.ndarray:
    """``(N, 3)`` float32 ``x y z`` of a KITTI ``.bin`` sweep (float32 ``x y z reflectance`` rows)."""
    data = np.fromfile(path, dtype="<f4")
    if data.size == 0 or data.size % 4:
        raise ValueError(f"{path}: {data.size} floats, not a non-empty multiple of 4")
    return data.reshape(-1, 4)[:, :3]


def in_range(points: np.ndarray) -> np.ndarray:
    """The rows of ``points (N, 3)`` between ``MIN_RANGE`` and ``MAX_RANGE`` of the sensor, in order."""
    ranges = np.linalg.norm(points.astype(np.float64), axis=1)
    return points[(ranges >= MIN_RANGE) & (ranges <= MAX_RANGE)]


def thin(points: np.ndarray, name: str) -> np.ndarray:
    """The rows kept for sweep ``name``: in range, the first of each occupied voxel, at most ``MAX_POINTS``."""
    return common.subsample(common.first_per_voxel(in_range(points), VOXEL), name, MAX_POINTS, SEED)


def sweep_poses(source: str, variant: str = "velodyne") -> np.ndarray:
    """``(len(FRAMES), 4, 4)``: each kept sweep's pose, Velodyne frame -> frame 0's Velodyne frame
    (``variant="velodyne"``: ``inv(Tr) @ P @ Tr``). For the check only: ``"swapped"`` gives ``Tr @ P @ inv(Tr)``,
    ``"camera"`` the camera poses ``P`` as they are."""
    folder = os.path.join(source, SOURCE_DIR)
    camera = read_kitti_poses(os.path.join(folder, "poses", SEQUENCE + ".txt"))
    if len(camera) <= max(FRAMES):
        raise ValueError(f"poses/{SEQUENCE}.txt has {len(camera)} poses, need frame {max(FRAMES)}")
    tr = read_velo_to_cam(os.path.join(folder, "sequences", SEQUENCE, "calib.txt"))
    if variant == "camera":
        return camera[FRAMES]
    if variant == "swapped":
        return tr @ camera[FRAMES] @ np.linalg.inv(tr)
    return np.linalg.inv(tr) @ camera[FRAMES] @ tr


def build(source: str, out: str) -> dict:
    """Writes the set into ``out`` from the work tree ``source``; ``{sweep: (source points, kept points)}``."""
    velodyne = os.path.join(source, SOURCE_DIR, "sequences", SEQUENCE, "velodyne")
    poses = sweep_poses(source)
    sweeps = [read_sweep(os.path.join(velodyne, f"{frame:06d}.bin")) for frame in FRAMES]
    for name, points in zip(NAMES, sweeps):
        if not np.all(np.isfinite(points)):
            raise ValueError(f"{name}: non-finite points")
    counts = common.write_scans(out, NAMES, sweeps, [thin(points, name) for name, points in zip(NAMES, sweeps)])
    travel = float(np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1).sum())
    meta = {
        **common.source_meta(SET_NAME, "outdoor_lidar", SOURCE_URL, SOURCE_COMMIT, SOURCE_DIR, LICENCE),
        "sensor": SENSOR,
        "tune": TUNE,
        "report": REPORT,
        "kitti_sequence": SEQUENCE,
        "kitti_frames": dict(zip(NAMES, FRAMES)),
        "range_m": [MIN_RANGE, MAX_RANGE],
        "voxel_m": VOXEL,
        "points_per_sweep": MAX_POINTS,
        "seed": SEED,
        "source_points": {n: c[0] for n, c in counts.items()},
    }
    common.write_set_files(out, NAMES, poses, meta, SOURCE_MD, sensor=SENSOR, first=NAMES[0], last=NAMES[-1],
                           travel=travel, min_range=MIN_RANGE, max_range=MAX_RANGE, voxel=VOXEL,
                           max_points=f"{MAX_POINTS:,}", **CHECK)
    return counts


def _plane_residuals(a: np.ndarray, b: np.ndarray, near: float = 0.5, k: int = 12):
    """For the points of posed ``a`` within ``near`` of posed ``b`` (``hit``, a mask of ``a``): their nearest
    distances, and the point-to-plane distances of those whose ``k`` nearest points in ``b`` are planar
    (``planar``, a mask of the hits)."""
    from scipy.spatial import cKDTree

    tree = cKDTree(b)
    dist, idx = tree.query(a, distance_upper_bound=near)
    hit = np.isfinite(dist)
    _, nbr = tree.query(b[idx[hit]], k=k)
    centred = b[nbr] - b[nbr].mean(axis=1, keepdims=True)
    values, vectors = np.linalg.eigh(np.einsum("nki,nkj->nij", centred, centred))
    planar = values[:, 0] / np.maximum(values.sum(axis=1), 1e-12) < 0.02
    plane = np.abs(np.einsum("ij,ij->i", a[hit] - b[idx[hit]], vectors[:, :, 0]))
    return hit, dist[hit], plane[planar], planar


def check(source: str, out: str) -> None:
    """Prints the pose check of ``SOURCE.md``: each kept sweep against the next one, both posed, on the
    full-resolution sources (points in range) and on the thinned files."""
    poses = sweep_poses(source)
    swapped, camera = sweep_poses(source, "swapped"), sweep_poses(source, "camera")
    velodyne = os.path.join(source, SOURCE_DIR, "sequences", SEQUENCE, "velodyne")
    posed = common.posed

    def full(frame):
        return in_range(read_sweep(os.path.join(velodyne, f"{frame:06d}.bin")).astype(np.float64))

    rows = []
    for i in range(len(NAMES) - 1):
        a, b = full(FRAMES[i]), full(FRAMES[i + 1])
        hit, nn, plane, planar = _plane_residuals(posed(a, poses[i]), posed(b, poses[i + 1]))
        front = (a[:, 0] > 0)[hit][planar]  # ahead of the sensor in the first sweep's own frame
        kept = [common.read_written(out, NAMES[j]) for j in (i, i + 1)]
        plane_kept = _plane_residuals(posed(kept[0], poses[i]), posed(kept[1], poses[i + 1]))[2]
        plane_swapped = _plane_residuals(posed(a, swapped[i]), posed(b, swapped[i + 1]))[2]
        hit_camera = _plane_residuals(posed(a, camera[i]), posed(b, camera[i + 1]), near=1.0)[0]
        step = np.linalg.norm(poses[i + 1][:3, 3] - poses[i][:3, 3])
        row = (step, hit.mean(), np.median(nn), np.median(plane), np.median(plane[front]),
               np.median(plane[~front]), np.mean(plane < 0.05), np.median(plane_kept),
               np.median(plane_swapped), np.mean(plane_swapped < 0.05), hit_camera.mean())
        rows.append(row)
        print(f"{NAMES[i]} -> {NAMES[i + 1]}: step {row[0]:.2f} m, within 0.5 m {row[1]:.0%}, NN median "
              f"{row[2]:.3f} m, point-to-plane median {row[3]:.3f} m (front {row[4]:.3f}, rear {row[5]:.3f}), "
              f"<5 cm {row[6]:.0%}; thinned files {row[7]:.3f} m | Tr swapped: {row[8]:.3f} m, <5 cm "
              f"{row[9]:.0%} | camera poses: within 1 m {row[10]:.0%}")
    common.print_columns(rows, ("step (m)", "within 0.5 m", "NN median (m)", "point-to-plane median (m)",
                                "front half (m)", "rear half (m)", "within 5 cm", "thinned files (m)",
                                "Tr swapped: p2plane (m)", "Tr swapped: within 5 cm", "camera poses: within 1 m"),
                         width=26, digits=3)


def main(argv=None) -> int:
    return common.main(argv, __doc__, build, check, set_name=SET_NAME, noun="sweeps", width=16,
                       source_help="local clone of " + SOURCE_URL + " (at " + SOURCE_COMMIT + ")")


if __name__ == "__main__":
    sys.exit(main())
