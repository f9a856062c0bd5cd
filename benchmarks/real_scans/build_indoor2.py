"""Rebuilds ``benchmarks/real_scans/data/tum_fr3_cabinet/`` from a copy of its source repository.

The set is 16 real indoor RGB-D depth frames of the TUM RGB-D benchmark, sequence ``freiburg3_cabinet`` (a
hand-held structured-light camera carried in a loop around a cabinet standing on a bare floor), with the
benchmark's motion-capture ground truth. Unlike ``tum_fr1_desk`` (nine frames 33 ms apart), neighbouring frames
here are about 0.67 s apart: 16-22 cm and 5-17 degrees. The frames come from a public GitHub repository (the code
of the paper "Object Detection and Mapping with Bounding Box Constraints", MFI 2021) that carries 58 key frames of
the sequence (its ``data/depth_imgs/NNNN_depth_raw.png``) with the sequence's ground-truth pose of each
(``data/truth_cam_poses.txt``)::

    git clone https://github.com/benchun123/cuboid_slam_with_bbox_constraints.git cuboid_slam

then::

    python benchmarks/real_scans/build_indoor2.py --source cuboid_slam --out benchmarks/real_scans/data/tum_fr3_cabinet

The files are read at commit ``SOURCE_COMMIT`` with ``git show`` (``--source`` may also be a folder that has the
commit's ``data/`` checked out). ``--check`` also prints the pose check of ``SOURCE.md`` (needs SciPy).

Only data are read (``data/depth_imgs/NNNN_depth_raw.png``, ``data/truth_cam_poses.txt``); no code of that
repository is used. Each depth image (640x480, 16-bit, 5000 units per metre, registered to the colour camera by
the OpenNI driver) is back-projected with TUM's intrinsics for the freiburg3 colour camera (fx = 535.4,
fy = 539.2, cx = 320.1, cy = 247.6; TUM's freiburg3 images need no undistortion) into the colour camera's optical
frame (x right, y down, z forward), in metres; every pixel with a depth is used, in row-major order, thinned to the
first point of each occupied ``VOXEL`` cube, then to at most ``MAX_POINTS`` drawn without replacement by a
generator seeded from ``SEED`` and the frame's name (kept in order); written as binary little-endian PLY with
float32 ``x y z`` only. A frame's pose is the ground-truth line the source gives for it (TUM's ``groundtruth.txt``
format, ``timestamp tx ty tz qx qy qz qw``: colour camera -> motion-capture world frame, ``p_world = R(q) p + t``),
the 100 Hz motion-capture sample nearest the key frame, used as it is (the source keeps no image timestamps, so
nothing is interpolated). ``poses.conf`` holds them in :func:`rpmnet_jax.io.poses.write_poses`' convention;
``meta.json`` and ``SOURCE.md`` say where it all came from. Run it twice and the output is byte for byte the same.
"""

from __future__ import annotations

import argparse
import io
import json
import os
import subprocess
import sys
import zlib

import numpy as np

SET_NAME = "tum_fr3_cabinet"
SOURCE_URL = "https://github.com/benchun123/cuboid_slam_with_bbox_constraints"
SOURCE_COMMIT = "d228cfa2cd2bae42d568ee573165999977cc5e61"  # 2023-03-17; the data are unchanged since 2021-06-16
SOURCE_DIR = "data"
GROUNDTRUTH = "truth_cam_poses.txt"  # one line per key frame, in key-frame order (58)
SOURCE_FRAMES = 58
# The key frames used (indices into the source's 58): 1-16, a run of 16 consecutive key frames. Key frame 0 is
# left out (its ground truth fits its depth image worst: 28% of its points within 2 cm of key frame 1, against
# 63-92% for the neighbours kept); 16 frames of at most 40,000 points fill the 8 MB budget of a set.
KEYFRAMES = list(range(1, 17))
NAMES = [f"fr3cabinet_kf{k:02d}" for k in KEYFRAMES]
TUNE = NAMES[:6]  # the first 6 consecutive frames (key frames 1-6, about 3.4 s)
REPORT = NAMES[6:]  # the next 10 (key frames 7-16, about 6.7 s); no frame in both
INTRINSICS = (535.4, 539.2, 320.1, 247.6)  # fx, fy, cx, cy: TUM's values for the freiburg3 colour camera
ROS_DEFAULT = (525.0, 525.0, 319.5, 239.5)  # the other set TUM names for registered depth images (check only)
DEPTH_SCALE = 5000.0  # depth-image units per metre (TUM)
VOXEL = 0.01  # metres: the first point (row-major pixel order) of each occupied cube is kept
MAX_POINTS = 40_000
SEED = 20240613
LICENCE = (
    "TUM RGB-D SLAM Dataset and Benchmark (Computer Vision Group, Technical University of Munich), sequence "
    "freiburg3_cabinet: \"Unless stated otherwise, all data in the TUM RGB-D Dataset is licensed under a Creative "
    "Commons 4.0 Attribution License (CC BY 4.0) and the accompanying source code is licensed under a BSD-2-Clause "
    "License.\" (https://cvg.cit.tum.de/data/datasets/rgbd-dataset, https://creativecommons.org/licenses/by/4.0/; "
    "redistribution and adaptation are allowed with attribution.) Attribution: J. Sturm, N. Engelhard, F. Endres, "
    "W. Burgard, D. Cremers, A Benchmark for the Evaluation of RGB-D SLAM Systems, IROS 2012. This subsample "
    "(back-projected, thinned point clouds) is an adaptation of that data, distributed under CC BY 4.0. The source "
    "GitHub repository (which states no licence of its own) only carried the TUM files; none of its code is used."
)
SENSOR = ("Structured-light RGB-D camera (TUM's 'freiburg3' sensor, PrimeSense type), hand-held; depth images "
          "640x480 at 30 Hz registered 1:1 to the colour camera by the OpenNI driver; ground truth from TUM's "
          "motion-capture system at 100 Hz. Each frame here is in the colour camera's optical frame (x right, "
          "y down, z forward)")
SOURCE_MD = """\
# tum_fr3_cabinet: real indoor RGB-D frames (TUM RGB-D, freiburg3_cabinet), spaced apart, with motion-capture ground truth

Written by `benchmarks/real_scans/build_indoor2.py`; rebuild it with that script rather than editing it.

## Source

- Data: the TUM RGB-D SLAM Dataset and Benchmark, sequence `rgbd_dataset_freiburg3_cabinet` (category "structure
  vs. texture": a hand-held camera carried in a loop around a cabinet standing on a bare floor),
  https://cvg.cit.tum.de/data/datasets/rgbd-dataset (Computer Vision Group, Technical University of Munich;
  J. Sturm, N. Engelhard, F. Endres, W. Burgard, D. Cremers, IROS 2012). Ground truth: lines of the sequence's
  `groundtruth.txt` (motion capture, 100 Hz: `timestamp tx ty tz qx qy qz qw`, the pose of the colour camera's
  optical centre in the motion-capture world frame).
- Copy read: {url} at commit `{commit}` (the data went in on 2021-06-16 and have not changed since), folder
  `{path}/`: the {source_frames} key frames it holds (one every ~20 camera frames, about 0.67 s apart, over the
  whole sequence), as depth images `depth_imgs/NNNN_depth_raw.png` (16-bit TUM depth images, renamed by key-frame
  number; their timestamps are not kept), and `{groundtruth}`: for each key frame, the ground-truth line of the
  motion-capture sample nearest to it ({gt_span}). Only these data files were read; no code of that repository is
  used or copied.
- Sensor: {sensor}.
- Units: metres.

## Licence

The data are TUM's. TUM's terms, as the dataset's web page states them:

> Unless stated otherwise, all data in the TUM RGB-D Dataset is licensed under a Creative Commons 4.0 Attribution
> License (CC BY 4.0) and the accompanying source code is licensed under a BSD-2-Clause License.

CC BY 4.0 (https://creativecommons.org/licenses/by/4.0/) allows redistribution and adaptation with attribution;
this subsample is an adaptation (depth images back-projected to point clouds and thinned) and is distributed under
CC BY 4.0. Attribution: J. Sturm, N. Engelhard, F. Endres, W. Burgard and D. Cremers, "A Benchmark for the
Evaluation of RGB-D SLAM Systems", IROS 2012. The source GitHub repository states no licence of its own; it only
carried TUM's files, and none of its code is used here.

## What is here

- {count} frames: the source's key frames {kf_first}-{kf_last}, consecutive key frames ({span:.1f} s of the
  sequence), split by frame into two runs that share no frame:
  - `tune` (the first {n_tune}): {tune}
  - `report` (the next {n_report}): {report}
  Between consecutive frames the camera moves {step_cm:.1f}-{step_max_cm:.1f} cm and turns
  {step_deg:.1f}-{step_max_deg:.1f} deg (median {step_med_cm:.1f} cm, {step_med_deg:.1f} deg); from the first frame
  to the last, {travel_cm:.1f} cm and {turn:.1f} deg (about a third of the loop around the cabinet). Key frame 0 is
  left out: its ground truth fits its depth image worst (28% of its points within 2 cm of key frame 1, against
  63-92% for the neighbouring pairs kept); the run stops at 16 frames to keep the set within 8 MB.
- Each `<frame>.ply`: binary little-endian PLY, float32 `x y z` only, in the frame's own colour-camera optical
  frame (x right, y down, z forward; not posed), in metres. The depth image (16-bit PNG, {scale:g} units per metre,
  registered to the colour camera) is back-projected with fx = {fx:g}, fy = {fy:g}, cx = {cx:g}, cy = {cy:g} (TUM's
  values for the freiburg3 colour camera, whose images need no undistortion), every pixel with a depth
  ({depth_range} m here), in row-major order; thinned to the first point of each occupied {voxel:g} m cube, then
  to at most {max_points} drawn uniformly without replacement by
  `numpy.random.default_rng([{seed}, crc32(frame name)])` (kept in order). The images have {source_points} pixels
  with a depth, so the frames here have {kept_points} points.
- `poses.conf`: each frame's ground-truth pose, colour-camera frame -> motion-capture world frame, written by
  `rpmnet_jax.io.poses.write_poses`: the source's ground-truth line for the key frame, as it is (the nearest
  100 Hz motion-capture sample; the image timestamps are not in the source, so nothing is interpolated: a
  frame's pose may be off its depth image by up to ~5 ms to the nearest sample plus the unknown colour-depth offset
  of the source's association; at the camera's speed here, about 0.3 m/s and 10-25 deg/s, 25 ms is under 1 cm and
  under 0.7 deg).
- `meta.json`: name, kind, source, commit, licence, units, sensor, the tune/report split, the intrinsics, the
  key-frame numbers and ground-truth timestamps, and the thinning parameters.

## Check of the poses

Printed by `build_indoor2.py --check`. Each of the {n_pairs} pairs of neighbouring frames, both posed
(full-resolution back-projections, every pixel with a depth): of the points of the first, {within2} lie within
2 cm of the second and {within3} within 3 cm (median nearest distance {median_nn}); on the thinned files here,
{kept2} within 2 cm. With no poses at all (identity) {identity2} lie within 2 cm (the floor, seen from about the
same height, overlaps by itself), and with the poses inverted (`p_world = R^T (p - t)`) {inverted2}. With the ROS
default intrinsics (fx = fy = 525, cx 319.5, cy 239.5) instead, {ros2} lie within 2 cm. Point-to-point ICP started
from the ground truth (2 cm voxels, 5 cm gate) raises the share within 2 cm to {icp2}, moving the first frame by
{icp_cm} and {icp_deg} in its own frame: the ground truth, with the image-to-pose timing above and the depth noise
of the sensor at 1-3 m, is good to about a centimetre and a degree, some pairs worse. Extent of the set in the
common frame: bounding box {extent}, diagonal {diagonal:.2f} m.

## Rebuild

    git clone {url}.git cuboid_slam
    python benchmarks/real_scans/build_indoor2.py --source cuboid_slam --out benchmarks/real_scans/data/tum_fr3_cabinet
"""
# The numbers of the pose check, as `--check` printed them for this build (SOURCE.md quotes them).
CHECK = {"within2": "63.1-91.7% (mean 82.1%)", "within3": "74.0-94.1%", "median_nn": "3.4-17.0 mm",
         "kept2": "37.1-86.4% (mean 68.5%)", "identity2": "7.6-76.7% (mean 51.9%)",
         "inverted2": "2.8-13.8% (mean 7.3%)", "ros2": "60.0-91.5% (mean 82.2%)",
         "icp2": "79.8-92.9% (mean 88.5%)", "icp_cm": "0.3-2.6 cm (median 1.0 cm)",
         "icp_deg": "0.3-1.7 deg (median 0.8 deg)"}


def _git_show(source: str, path: str) -> bytes | None:
    """The bytes of ``path`` at ``SOURCE_COMMIT`` in the git repository ``source``; None if ``source`` is not one."""
    try:
        done = subprocess.run(["git", "-C", source, "show", f"{SOURCE_COMMIT}:{path}"], capture_output=True,
                              check=False)
    except OSError:
        return None
    return done.stdout if done.returncode == 0 else None


def read_source(source: str, name: str) -> bytes:
    """The bytes of ``SOURCE_DIR/name`` at ``SOURCE_COMMIT`` (git), or from a checked-out ``source`` folder."""
    path = f"{SOURCE_DIR}/{name}"
    data = _git_show(source, path)
    if data is not None:
        return data
    local = os.path.join(source, *path.split("/"))
    if os.path.isfile(local):
        with open(local, "rb") as f:
            return f.read()
    raise OSError(f"{source}: no {path} at commit {SOURCE_COMMIT} (a clone of {SOURCE_URL} is needed)")


def read_groundtruth(text: str) -> np.ndarray:
    """``(58, 8)`` rows ``timestamp tx ty tz qx qy qz qw`` of the source's ``truth_cam_poses.txt``, in key-frame
    order (not sorted: row ``k`` is key frame ``k``)."""
    rows = [line.split() for line in text.splitlines() if line.strip() and not line.startswith("#")]
    table = np.array(rows, dtype=np.float64)
    if table.ndim != 2 or table.shape != (SOURCE_FRAMES, 8):
        raise ValueError(f"{GROUNDTRUTH}: expected {SOURCE_FRAMES} lines of 8 numbers, got {table.shape}")
    if np.any(np.diff(table[:, 0]) <= 0):
        raise ValueError(f"{GROUNDTRUTH}: timestamps not increasing")
    return table


def pose_of(row: np.ndarray) -> np.ndarray:
    """``(4, 4)`` colour camera -> world of one ground-truth row (the quaternion normalised)."""
    from scipy.spatial.transform import Rotation

    pose = np.eye(4)
    pose[:3, :3] = Rotation.from_quat(row[4:8]).as_matrix()
    pose[:3, 3] = row[1:4]
    return pose


def read_depth(data: bytes) -> np.ndarray:
    """``(480, 640)`` uint16 depth image of a TUM 16-bit PNG."""
    from PIL import Image

    image = Image.open(io.BytesIO(data))
    depth = np.array(image)
    if depth.dtype != np.uint16 or depth.shape != (480, 640):
        raise ValueError(f"depth image: mode {image.mode}, size {image.size}, expected 640x480 16-bit")
    return depth


def depth_name(keyframe: int) -> str:
    return f"depth_imgs/{keyframe:04d}_depth_raw.png"


def back_project(depth: np.ndarray, intrinsics=INTRINSICS) -> np.ndarray:
    """``(N, 3)`` float64 points of every pixel with a depth, row-major, in the camera's optical frame (metres)."""
    fx, fy, cx, cy = intrinsics
    v, u = np.nonzero(depth)
    z = depth[v, u].astype(np.float64) / DEPTH_SCALE
    return np.column_stack([(u - cx) * z / fx, (v - cy) * z / fy, z])


def thin(points: np.ndarray, name: str) -> np.ndarray:
    """The rows kept for frame ``name``: the first of each occupied voxel, then at most ``MAX_POINTS``."""
    cells = np.floor(points / VOXEL).astype(np.int64)
    _, first = np.unique(cells, axis=0, return_index=True)
    points = points[np.sort(first)]
    if len(points) > MAX_POINTS:
        rng = np.random.default_rng([SEED, zlib.crc32(name.encode("ascii"))])
        points = points[np.sort(rng.choice(len(points), MAX_POINTS, replace=False))]
    return points


def write_binary_ply(path: str, points: np.ndarray) -> None:
    """Binary little-endian PLY with one ``vertex`` element of float32 ``x y z``."""
    points = np.ascontiguousarray(points, dtype="<f4")
    header = ("ply\nformat binary_little_endian 1.0\n"
              f"element vertex {len(points)}\nproperty float x\nproperty float y\nproperty float z\nend_header\n")
    with open(path, "wb") as f:
        f.write(header.encode("ascii"))
        f.write(points.tobytes())


def groundtruth(source: str) -> np.ndarray:
    return read_groundtruth(read_source(source, GROUNDTRUTH).decode("ascii"))


def frame_poses(source: str) -> np.ndarray:
    """``(16, 4, 4)``: each frame's ground-truth pose (colour camera -> world)."""
    table = groundtruth(source)
    return np.stack([pose_of(table[k]) for k in KEYFRAMES])


def _rel(a: np.ndarray, b: np.ndarray):
    from scipy.spatial.transform import Rotation

    m = np.linalg.inv(a) @ b
    return np.linalg.norm(m[:3, 3]), np.degrees(Rotation.from_matrix(m[:3, :3]).magnitude())


def _motion(poses: np.ndarray):
    steps = np.array([_rel(poses[i], poses[i + 1]) for i in range(len(poses) - 1)])
    return _rel(poses[0], poses[-1]), steps


def _range(values, fmt):
    values = np.asarray(values)
    return fmt.format(values.min()) if np.isclose(values.min(), values.max()) else \
        (fmt + "-" + fmt).format(values.min(), values.max())


def build(source: str, out: str) -> dict:
    sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))
    from rpmnet_jax.io import poses as poses_io

    table = groundtruth(source)
    poses = np.stack([pose_of(table[k]) for k in KEYFRAMES])
    stamps = {name: f"{table[k, 0]:.4f}" for k, name in zip(KEYFRAMES, NAMES)}
    os.makedirs(out, exist_ok=True)
    counts, kept_all, depth_range = {}, [], [np.inf, -np.inf]
    for k, name in zip(KEYFRAMES, NAMES):
        points = back_project(read_depth(read_source(source, depth_name(k))))
        depth_range = [min(depth_range[0], points[:, 2].min()), max(depth_range[1], points[:, 2].max())]
        kept = thin(points, name)
        write_binary_ply(os.path.join(out, name + ".ply"), kept)
        counts[name] = (len(points), len(kept))
        kept_all.append(kept)
    poses_io.write_poses(os.path.join(out, "poses.conf"), [n + ".ply" for n in NAMES], poses)
    (travel, turn), steps = _motion(poses)
    world = np.concatenate([k @ p[:3, :3].T + p[:3, 3] for k, p in zip(kept_all, poses)])
    size = world.max(axis=0) - world.min(axis=0)
    fx, fy, cx, cy = INTRINSICS
    meta = {
        "name": SET_NAME,
        "kind": "indoor",
        "source_url": SOURCE_URL,
        "source_commit": SOURCE_COMMIT,
        "source_path": SOURCE_DIR,
        "licence": LICENCE,
        "units": "m",
        "sensor": SENSOR,
        "tune": TUNE,
        "report": REPORT,
        "tum_sequence": "rgbd_dataset_freiburg3_cabinet",
        "source_keyframes": dict(zip(NAMES, KEYFRAMES)),
        "groundtruth_timestamps": stamps,
        "intrinsics": {"fx": fx, "fy": fy, "cx": cx, "cy": cy, "depth_scale": DEPTH_SCALE},
        "voxel_m": VOXEL,
        "points_per_scan": MAX_POINTS,
        "seed": SEED,
        "source_points": {n: c[0] for n, c in counts.items()},
    }
    with open(os.path.join(out, "meta.json"), "w") as f:
        json.dump(meta, f, indent=2)
        f.write("\n")
    source_points = [c[0] for c in counts.values()]
    kept_points = [c[1] for c in counts.values()]
    with open(os.path.join(out, "SOURCE.md"), "w") as f:
        f.write(SOURCE_MD.format(
            url=SOURCE_URL, commit=SOURCE_COMMIT, path=SOURCE_DIR, groundtruth=GROUNDTRUTH,
            source_frames=SOURCE_FRAMES, gt_span=f"{table[0, 0]:.4f}-{table[-1, 0]:.4f}", sensor=SENSOR,
            count=len(NAMES), kf_first=KEYFRAMES[0], kf_last=KEYFRAMES[-1],
            span=table[KEYFRAMES[-1], 0] - table[KEYFRAMES[0], 0], n_tune=len(TUNE), n_report=len(REPORT),
            tune=", ".join(TUNE), report=", ".join(REPORT), travel_cm=100 * travel, turn=turn,
            step_cm=100 * steps[:, 0].min(), step_max_cm=100 * steps[:, 0].max(), step_deg=steps[:, 1].min(),
            step_max_deg=steps[:, 1].max(), step_med_cm=100 * np.median(steps[:, 0]),
            step_med_deg=np.median(steps[:, 1]), scale=DEPTH_SCALE, fx=fx, fy=fy, cx=cx, cy=cy, voxel=VOXEL,
            max_points=f"{MAX_POINTS:,}", seed=SEED, source_points=_range(source_points, "{:,}"),
            kept_points=_range(kept_points, "{:,}"), depth_range=f"{depth_range[0]:.2f}-{depth_range[1]:.2f}",
            n_pairs=len(NAMES) - 1, extent=" x ".join(f"{s:.2f}" for s in size) + " m",
            diagonal=float(np.linalg.norm(size)), **CHECK))
    return counts


def _icp(src: np.ndarray, dst: np.ndarray, iters: int = 25, gate: float = 0.05) -> np.ndarray:
    """``(4, 4)`` point-to-point ICP moving ``src`` onto ``dst`` (both in the common frame), from the identity."""
    from scipy.spatial import cKDTree

    tree, motion = cKDTree(dst), np.eye(4)
    for _ in range(iters):
        moved = src @ motion[:3, :3].T + motion[:3, 3]
        dist, j = tree.query(moved, distance_upper_bound=gate)
        ok = np.isfinite(dist)
        a, b = moved[ok], dst[j[ok]]
        ca, cb = a.mean(axis=0), b.mean(axis=0)
        u, _, vt = np.linalg.svd((a - ca).T @ (b - cb))
        rot = vt.T @ np.diag([1.0, 1.0, np.sign(np.linalg.det(vt.T @ u.T))]) @ u.T
        step = np.eye(4)
        step[:3, :3], step[:3, 3] = rot, cb - rot @ ca
        motion = step @ motion
    return motion


def check(source: str, out: str) -> None:
    """Prints the pose check of ``SOURCE.md``: every pair of neighbouring frames, both posed, on the
    full-resolution back-projections and on the thinned files; the same with no poses, with the poses inverted,
    and with the ROS default intrinsics; and how far ICP started from the ground truth moves the first frame."""
    from scipy.spatial import cKDTree

    from rpmnet_jax.io import clouds as clouds_io

    poses = frame_poses(source)
    depths = [read_depth(read_source(source, depth_name(k))) for k in KEYFRAMES]
    full = [back_project(d) for d in depths]
    kept = [np.asarray(clouds_io.read_cloud(os.path.join(out, n + ".ply"))[0], np.float64) for n in NAMES]

    def posed(points, pose):
        return points @ pose[:3, :3].T + pose[:3, 3]

    def near(a, b, limit=0.1):
        dist, _ = cKDTree(b).query(a, distance_upper_bound=limit)
        return dist

    def cells(points, size=0.02):
        _, first = np.unique(np.floor(points / size).astype(np.int64), axis=0, return_index=True)
        return points[np.sort(first)]

    inverted = np.linalg.inv(poses)
    rows = []
    for i in range(len(NAMES) - 1):
        j = i + 1
        a, b = posed(full[i], poses[i]), posed(full[j], poses[j])
        d = near(a, b)
        dk = near(posed(kept[i], poses[i]), posed(kept[j], poses[j]))
        d0 = near(full[i], full[j])
        di = near(posed(full[i], inverted[i]), posed(full[j], inverted[j]))
        ros_i, ros_j = back_project(depths[i], ROS_DEFAULT), back_project(depths[j], ROS_DEFAULT)
        dr = near(posed(ros_i, poses[i]), posed(ros_j, poses[j]))
        motion = _icp(cells(a), cells(b))
        dc = near(posed(a, motion), b)
        own = inverted[i] @ motion @ poses[i]  # the ICP correction in frame i's own frame
        icp_cm, icp_deg = _rel(np.eye(4), own)
        row = (np.mean(d < 0.02), np.mean(d < 0.03), np.median(d), np.mean(dk < 0.02), np.mean(d0 < 0.02),
               np.mean(di < 0.02), np.mean(dr < 0.02), np.mean(dc < 0.02), 100 * icp_cm, icp_deg)
        rows.append(row)
        print(f"{NAMES[i]} -> {NAMES[j]}: <2 cm {row[0]:.1%}, <3 cm {row[1]:.1%}, median NN {1000 * row[2]:.1f} mm;"
              f" thinned <2 cm {row[3]:.1%} | identity {row[4]:.1%} | inverted {row[5]:.1%} | ROS default "
              f"{row[6]:.1%} | ICP <2 cm {row[7]:.1%}, moves {row[8]:.1f} cm {row[9]:.2f} deg", flush=True)
    table = np.array(rows)
    for k, label in enumerate(("within 2 cm", "within 3 cm", "median NN (m)", "thinned: within 2 cm",
                               "identity: within 2 cm", "inverted: within 2 cm", "ROS default: within 2 cm",
                               "after ICP: within 2 cm", "ICP correction (cm)", "ICP correction (deg)")):
        print(f"{label:>28}: {table[:, k].min():.4f} - {table[:, k].max():.4f} (mean {table[:, k].mean():.4f}, "
              f"median {np.median(table[:, k]):.4f})")
    (travel, turn), steps = _motion(poses)
    print(f"first -> last frame: {100 * travel:.1f} cm, {turn:.1f} deg; consecutive: "
          f"{100 * steps[:, 0].min():.1f}-{100 * steps[:, 0].max():.1f} cm, "
          f"{steps[:, 1].min():.1f}-{steps[:, 1].max():.1f} deg")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--source", required=True, help="local clone of " + SOURCE_URL + " (commit " + SOURCE_COMMIT + ")")
    p.add_argument("--out", default=os.path.join(os.path.dirname(os.path.abspath(__file__)), "data", SET_NAME),
                   help="output folder (default: benchmarks/real_scans/data/tum_fr3_cabinet)")
    p.add_argument("--check", action="store_true", help="also print the pose check (needs SciPy)")
    a = p.parse_args(argv)
    try:
        counts = build(a.source, a.out)
    except (ValueError, OSError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    for name, (n, k) in counts.items():
        print(f"{name:<18} {n:>7} -> {k:>6} points")
    print(f"wrote {len(counts)} frames, poses.conf, meta.json and SOURCE.md to {a.out}")
    if a.check:
        check(a.source, a.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
