"""Rebuilds ``benchmarks/real_scans/data/tum_fr1_desk/`` from a copy of its source repository.

The set is 9 real indoor RGB-D depth frames of the TUM RGB-D benchmark, sequence ``freiburg1_desk`` (a hand-held
Kinect moved over an office desk), with the benchmark's motion-capture ground truth. The frames come from a public
GitHub repository (the code of the book "14 lectures on visual SLAM") that carried nine consecutive frames of the
sequence unchanged, with the sequence's ``groundtruth.txt``, under ``ch8/data/`` at one commit of its history (they
were removed from the tree later, so take a full clone, not a shallow one)::

    git clone https://github.com/gaoxiang12/slambook.git slambook

then::

    python benchmarks/real_scans/build_indoor.py --source slambook --out benchmarks/real_scans/data/tum_fr1_desk

The files are read at commit ``SOURCE_COMMIT`` with ``git show`` (``--source`` may also be a folder that has the
commit's ``ch8/data/`` checked out). ``--check`` also prints the pose check of ``SOURCE.md`` (needs SciPy).

Only data are read (``ch8/data/depth/<timestamp>.png``, ``ch8/data/groundtruth.txt``); no code of that repository
is used. Each depth image (640x480, 16-bit, 5000 units per metre, already registered to the colour camera) is
back-projected with the pinhole intrinsics that TUM gives for its pre-registered depth images (the ROS default:
fx = fy = 525, cx = 319.5, cy = 239.5, no undistortion) into the colour camera's optical frame (x right, y down,
z forward), in metres; every pixel with a depth is used, in row-major order, thinned to the first point of each
occupied ``VOXEL`` cube, then to at most ``MAX_POINTS`` drawn without replacement by a generator seeded from
``SEED`` and the frame's name (kept in order); written as binary little-endian PLY with float32 ``x y z`` only.
A frame's pose is TUM's ground truth (colour camera -> motion-capture world frame: ``p_world = R(q) p + t``)
interpolated at the depth image's timestamp (linear in ``t``, slerp in ``q``, between the two bracketing
ground-truth samples, about 10 ms apart). ``poses.conf`` holds them in :func:`rpmnet_jax.io.poses.write_poses`'
convention; ``meta.json`` and ``SOURCE.md`` say where it all came from. Run it twice and the output is byte for
byte the same.
"""

from __future__ import annotations

import io
import itertools
import sys

import numpy as np

import build_common as common

SET_NAME = "tum_fr1_desk"
SOURCE_URL = "https://github.com/gaoxiang12/slambook"
SOURCE_COMMIT = "5037ba38cdf9289cfc6955b0e0a24860ab9ad59a"  # the last commit with ch8/data/{depth,rgb}/*.png
SOURCE_DIR = "ch8/data"
# The nine depth frames the source holds (TUM file names: the depth image's timestamp, seconds since the epoch).
STAMPS = ["1305031453.374112", "1305031453.404816", "1305031453.436941", "1305031453.473352", "1305031453.505218",
          "1305031453.538301", "1305031453.574074", "1305031453.605314", "1305031453.636951"]
NAMES = ["fr1desk_" + s.replace(".", "_") for s in STAMPS]
TUNE = NAMES[:4]  # the first 4 consecutive frames (0.10 s)
REPORT = NAMES[4:]  # the next 5 (0.13 s); no frame in both
INTRINSICS = (525.0, 525.0, 319.5, 239.5)  # fx, fy, cx, cy: TUM's values for its registered depth images
DEPTH_SCALE = 5000.0  # depth-image units per metre (TUM)
VOXEL = 0.01  # metres: the first point (row-major pixel order) of each occupied cube is kept
MAX_POINTS = 40_000
SEED = 20240613
LICENCE = (
    "TUM RGB-D SLAM Dataset and Benchmark (Computer Vision Group, Technical University of Munich), sequence "
    "freiburg1_desk: \"Unless stated otherwise, all data in the TUM RGB-D Dataset is licensed under a Creative "
    "Commons 4.0 Attribution License (CC BY 4.0) and the accompanying source code is licensed under a BSD-2-Clause "
    "License.\" (https://cvg.cit.tum.de/data/datasets/rgbd-dataset, https://creativecommons.org/licenses/by/4.0/; "
    "redistribution and adaptation are allowed with attribution.) Attribution: J. Sturm, N. Engelhard, F. Endres, "
    "W. Burgard, D. Cremers, A Benchmark for the Evaluation of RGB-D SLAM Systems, IROS 2012. This subsample "
    "(back-projected, thinned point clouds) is an adaptation of that data, distributed under CC BY 4.0. The source "
    "GitHub repository's own licence (MIT) covers its code, none of which is used here."
)
SENSOR = ("Microsoft Kinect (first generation, structured light), TUM's 'freiburg1' sensor, hand-held; depth images "
          "640x480 at 30 Hz registered to the colour camera by the OpenNI driver; ground truth from an 8-camera "
          "motion-capture system at 100 Hz. Each frame here is in the colour camera's optical frame (x right, "
          "y down, z forward)")
SOURCE_MD = """\
# tum_fr1_desk: real indoor RGB-D frames (TUM RGB-D, freiburg1_desk), with motion-capture ground truth

Written by `benchmarks/real_scans/build_indoor.py`; rebuild it with that script rather than editing it.

## Source

- Data: the TUM RGB-D SLAM Dataset and Benchmark, sequence `rgbd_dataset_freiburg1_desk` (a hand-held Kinect
  moved over two office desks), https://cvg.cit.tum.de/data/datasets/rgbd-dataset (Computer Vision Group,
  Technical University of Munich; J. Sturm, N. Engelhard, F. Endres, W. Burgard, D. Cremers, IROS 2012). Ground
  truth: the sequence's `groundtruth.txt` (motion capture, 100 Hz: `timestamp tx ty tz qx qy qz qw`, the pose of
  the colour camera's optical centre in the motion-capture world frame).
- Copy read: {url} at commit `{commit}` (2016-11-21; the images were removed from the tree
  by the next commit, so a full clone is needed), folder `{path}/`: the nine depth images `depth/<timestamp>.png`
  it holds (frames 1305031453.374112-1305031453.636951 of the sequence, consecutive, unchanged TUM files) and the
  sequence's whole `groundtruth.txt` (2,335 poses). Only these data files were read; no code of that repository is
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
Evaluation of RGB-D SLAM Systems", IROS 2012. The source GitHub repository's own licence (MIT) covers its code,
none of which is used here.

## What is here

- {count} frames: all the source holds, nine consecutive depth frames of the sequence (30 Hz, {span:.2f} s in all),
  split by frame into two runs that share no frame:
  - `tune` (the first 4): {tune}
  - `report` (the next 5): {report}
  The camera moves {travel_cm:.1f} cm and turns {turn:.1f} deg from the first frame to the last
  ({step_cm:.1f}-{step_max_cm:.1f} cm and {step_deg:.1f}-{step_max_deg:.1f} deg between consecutive frames), so every
  pair overlaps heavily and, as captured, is nearly aligned already: the set is for registration from a perturbed
  start (turned sources), not for wide-baseline pairs.
- Each `<frame>.ply`: binary little-endian PLY, float32 `x y z` only, in the frame's own colour-camera optical
  frame (x right, y down, z forward; not posed), in metres. The depth image (16-bit PNG, {scale:g} units per metre,
  registered to the colour camera) is back-projected with fx = {fx:g}, fy = {fy:g}, cx = {cx:g}, cy = {cy:g} (TUM's
  values for its registered depth images; no undistortion), every pixel with a depth ({depth_range} m here), in
  row-major order; thinned to the first point of each occupied {voxel:g} m cube, then to at most {max_points}
  drawn uniformly without replacement by `numpy.random.default_rng([{seed}, crc32(frame name)])` (kept in order).
  The images have {source_points} pixels with a depth, so the frames here have {kept_points} points.
- `poses.conf`: each frame's ground-truth pose, colour-camera frame -> motion-capture world frame, written by
  `rpmnet_jax.io.poses.write_poses`: TUM's `groundtruth.txt` interpolated at the depth image's timestamp (linear
  in the translation, slerp in the rotation, between the two bracketing samples, about 10 ms apart).
- `meta.json`: name, kind, source, commit, licence, units, sensor, the tune/report split, the intrinsics, the
  timestamps, and the thinning parameters.

## Check of the poses

Printed by `build_indoor.py --check`. Each of the 36 pairs of frames, both posed (full-resolution back-projections,
every pixel with a depth): of the points of the first, {within2} lie within 2 cm of the second and {within3}
within 3 cm (median nearest distance {median_nn}); on the thinned files here, {kept2} within 2 cm and {kept3}
within 3 cm. With the poses inverted (`p_world = R^T (p - t)`, the other reading of TUM's quaternions) only
{inverted2} lie within 2 cm, and with no poses at all (identity) {identity2}. With TUM's calibrated freiburg1
colour intrinsics (fx 517.3, fy 516.5, cx 318.6, cy 255.3) instead, {fr1_2} lie within 2 cm. Extent of the set
in the common frame: bounding box {extent}, diagonal {diagonal:.2f} m.

## Rebuild

    git clone {url}.git slambook
    python benchmarks/real_scans/build_indoor.py --source slambook --out benchmarks/real_scans/data/tum_fr1_desk
"""
# The numbers of the pose check, as `--check` printed them for this build (SOURCE.md quotes them).
CHECK = {"within2": "89.1-99.9% (mean 96.6%)", "within3": "94.2-100.0%", "median_nn": "2.2-6.8 mm",
         "kept2": "84.5-99.7% (mean 94.6%)", "kept3": "92.0-100.0%", "inverted2": "19.7-99.1% (mean 53.6%)",
         "identity2": "6.4-99.0% (mean 39.0%)", "fr1_2": "87.7-99.9% (mean 96.2%)"}


def read_source(source: str, name: str) -> bytes:
    """The bytes of ``SOURCE_DIR/name`` at ``SOURCE_COMMIT`` (git), or from a checked-out ``source`` folder."""
    return common.read_source(source, SOURCE_COMMIT, f"{SOURCE_DIR}/{name}", SOURCE_URL)


def read_groundtruth(text: str) -> np.ndarray:
    """``(N, 8)`` rows ``timestamp tx ty tz qx qy qz qw`` of a TUM ``groundtruth.txt``, sorted by time."""
    rows = [line.split() for line in text.splitlines() if line.strip() and not line.startswith("#")]
    table = np.array(rows, dtype=np.float64)
    if table.ndim != 2 or table.shape[1] != 8:
        raise ValueError("groundtruth.txt: expected 8 numbers a line")
    return table[np.argsort(table[:, 0], kind="stable")]


def pose_at(groundtruth: np.ndarray, stamp: float) -> np.ndarray:
    """``(4, 4)`` colour camera -> world at ``stamp``: linear in ``t``, slerp in ``q``, between bracketing samples."""
    from scipy.spatial.transform import Rotation, Slerp

    i = int(np.searchsorted(groundtruth[:, 0], stamp))
    if i == 0 or i == len(groundtruth):
        raise ValueError(f"{stamp}: outside the ground truth ({groundtruth[0, 0]}-{groundtruth[-1, 0]})")
    a, b = groundtruth[i - 1], groundtruth[i]
    if b[0] - a[0] > 0.05:
        raise ValueError(f"{stamp}: ground-truth gap of {b[0] - a[0]:.3f} s")
    w = (stamp - a[0]) / (b[0] - a[0])
    pose = np.eye(4)
    pose[:3, :3] = Slerp([a[0], b[0]], Rotation.from_quat([a[4:8], b[4:8]]))([stamp])[0].as_matrix()
    pose[:3, 3] = (1.0 - w) * a[1:4] + w * b[1:4]
    return pose


def read_depth(data: bytes) -> np.ndarray:
    """``(480, 640)`` uint16 depth image of a TUM 16-bit PNG."""
    from PIL import Image

    image = Image.open(io.BytesIO(data))
    depth = np.array(image)
    if depth.dtype != np.uint16 or depth.ndim != 2:
        raise ValueError(f"depth image: mode {image.mode}, expected 16-bit single channel")
    return depth


def back_project(depth: np.ndarray, intrinsics=INTRINSICS) -> np.ndarray:
    """``(N, 3)`` float64 points of every pixel with a depth, row-major, in the camera's optical frame (metres)."""
    fx, fy, cx, cy = intrinsics
    v, u = np.nonzero(depth)
    z = depth[v, u].astype(np.float64) / DEPTH_SCALE
    return np.column_stack([(u - cx) * z / fx, (v - cy) * z / fy, z])


def thin(points: np.ndarray, name: str) -> np.ndarray:
    """The rows kept for frame ``name``: the first of each occupied voxel, then at most ``MAX_POINTS``."""
    return common.subsample(common.first_per_voxel(points, VOXEL), name, MAX_POINTS, SEED)


def frame_poses(source: str) -> np.ndarray:
    """``(9, 4, 4)``: each frame's ground-truth pose at its depth timestamp (colour camera -> world)."""
    groundtruth = read_groundtruth(read_source(source, "groundtruth.txt").decode("ascii"))
    return np.stack([pose_at(groundtruth, float(s)) for s in STAMPS])


def _motion(poses: np.ndarray):
    from scipy.spatial.transform import Rotation

    def rel(a, b):
        m = np.linalg.inv(a) @ b
        return np.linalg.norm(m[:3, 3]), np.degrees(Rotation.from_matrix(m[:3, :3]).magnitude())

    steps = np.array([rel(poses[i], poses[i + 1]) for i in range(len(poses) - 1)])
    return rel(poses[0], poses[-1]), steps


def _range(values, fmt):
    values = np.asarray(values)
    return fmt.format(values.min()) if np.isclose(values.min(), values.max()) else \
        (fmt + "-" + fmt).format(values.min(), values.max())


def build(source: str, out: str) -> dict:
    """Writes the set into ``out`` from the clone ``source``; ``{frame: (source points, kept points)}``."""
    poses = frame_poses(source)
    frames = [back_project(read_depth(read_source(source, f"depth/{stamp}.png"))) for stamp in STAMPS]
    kept = [thin(points, name) for name, points in zip(NAMES, frames)]
    counts = common.write_scans(out, NAMES, frames, kept)
    depth_range = min(p[:, 2].min() for p in frames), max(p[:, 2].max() for p in frames)
    (travel, turn), steps = _motion(poses)
    world = np.concatenate([common.posed(k, p) for k, p in zip(kept, poses)])
    size = world.max(axis=0) - world.min(axis=0)
    fx, fy, cx, cy = INTRINSICS
    meta = {
        **common.source_meta(SET_NAME, "indoor", SOURCE_URL, SOURCE_COMMIT, SOURCE_DIR, LICENCE),
        "sensor": SENSOR,
        "tune": TUNE,
        "report": REPORT,
        "tum_sequence": "rgbd_dataset_freiburg1_desk",
        "depth_timestamps": dict(zip(NAMES, STAMPS)),
        "intrinsics": {"fx": fx, "fy": fy, "cx": cx, "cy": cy, "depth_scale": DEPTH_SCALE},
        "voxel_m": VOXEL,
        "points_per_scan": MAX_POINTS,
        "seed": SEED,
        "source_points": {n: c[0] for n, c in counts.items()},
    }
    common.write_set_files(
        out, NAMES, poses, meta, SOURCE_MD, sensor=SENSOR, span=float(STAMPS[-1]) - float(STAMPS[0]),
        travel_cm=100 * travel, turn=turn, step_cm=100 * steps[:, 0].min(), step_max_cm=100 * steps[:, 0].max(),
        step_deg=steps[:, 1].min(), step_max_deg=steps[:, 1].max(), scale=DEPTH_SCALE, fx=fx, fy=fy, cx=cx, cy=cy,
        voxel=VOXEL, max_points=f"{MAX_POINTS:,}", source_points=_range([len(p) for p in frames], "{:,}"),
        kept_points=_range([len(k) for k in kept], "{:,}"), depth_range=f"{depth_range[0]:.2f}-{depth_range[1]:.2f}",
        extent=" x ".join(f"{s:.2f}" for s in size) + " m", diagonal=float(np.linalg.norm(size)), **CHECK)
    return counts


def check(source: str, out: str) -> None:
    """Prints the pose check of ``SOURCE.md``: every pair of frames, both posed, on the full-resolution
    back-projections and on the thinned files; the same with the poses inverted, with none, and with TUM's
    calibrated freiburg1 colour intrinsics."""
    from scipy.spatial import cKDTree

    poses = frame_poses(source)
    depths = [read_depth(read_source(source, f"depth/{s}.png")) for s in STAMPS]
    full = [back_project(d) for d in depths]
    fr1 = [back_project(d, (517.3, 516.5, 318.6, 255.3)) for d in depths]
    kept = [common.read_written(out, n) for n in NAMES]
    identity, inverted = np.tile(np.eye(4), (len(poses), 1, 1)), np.linalg.inv(poses)

    def near(clouds, pose, i, j):
        """Distances (up to 0.1 m) from the points of ``clouds[i]`` to ``clouds[j]``, both posed by ``pose``."""
        a, b = common.posed(clouds[i], pose[i]), common.posed(clouds[j], pose[j])
        return cKDTree(b).query(a, distance_upper_bound=0.1)[0]

    rows = []
    for i, j in itertools.combinations(range(len(NAMES)), 2):
        d, dk, di, d0, df = (near(clouds, pose, i, j) for clouds, pose in
                             ((full, poses), (kept, poses), (full, inverted), (full, identity), (fr1, poses)))
        row = (np.mean(d < 0.02), np.mean(d < 0.03), np.median(d), np.mean(dk < 0.02), np.mean(dk < 0.03),
               np.mean(di < 0.02), np.mean(d0 < 0.02), np.mean(df < 0.02))
        rows.append(row)
        print(f"{NAMES[i]} -> {NAMES[j]}: <2 cm {row[0]:.1%}, <3 cm {row[1]:.1%}, median NN "
              f"{1000 * row[2]:.1f} mm; thinned <2 cm {row[3]:.1%}, <3 cm {row[4]:.1%} | inverted <2 cm "
              f"{row[5]:.1%} | identity <2 cm {row[6]:.1%} | fr1 intrinsics <2 cm {row[7]:.1%}")
    common.print_columns(rows, ("within 2 cm", "within 3 cm", "median NN (m)", "thinned: within 2 cm",
                                "thinned: within 3 cm", "inverted: within 2 cm", "identity: within 2 cm",
                                "fr1 intrinsics: within 2 cm"), width=28, digits=4, mean=True)
    (travel, turn), steps = _motion(poses)
    print(f"first -> last frame: {100 * travel:.1f} cm, {turn:.1f} deg; consecutive: "
          f"{100 * steps[:, 0].min():.1f}-{100 * steps[:, 0].max():.1f} cm, "
          f"{steps[:, 1].min():.1f}-{steps[:, 1].max():.1f} deg")


def main(argv=None) -> int:
    return common.main(argv, __doc__, build, check, set_name=SET_NAME, noun="frames", width=26,
                       source_help="local clone of " + SOURCE_URL + " (full history: commit " + SOURCE_COMMIT + ")")


if __name__ == "__main__":
    sys.exit(main())
