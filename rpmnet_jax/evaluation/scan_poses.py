"""Poses of range scans in Stanford ``.conf`` files (``bmesh NAME tx ty tz qx qy qz qw``): read (ground truth),
written (:func:`rpmnet_jax.align_scans`' answer), and per-scan errors.

Convention (checked on the Stanford bunny: 98–99% of each posed scan lies within 1 mm of the reconstruction):
world points are ``p @ R + t`` with ``R`` the matrix of the quaternion, i.e. the pose of a scan is
``T = [[R^T, t], [0, 1]]``, and the motion taking scan A onto scan B is ``T_B^-1 T_A``.
"""

from __future__ import annotations

import os

import numpy as np

from rpmnet_jax.ops import se3


def read_poses(conf_path: str) -> dict:
    """``{scan name: (4, 4) pose}`` from a Stanford ``.conf`` file."""
    from scipy.spatial.transform import Rotation

    poses = {}
    with open(conf_path) as f:
        for line in f:
            parts = line.split()
            if len(parts) == 9 and parts[0] == "bmesh":
                t, q = np.array(parts[2:5], float), np.array(parts[5:9], float)
                pose = np.eye(4)
                pose[:3, :3] = Rotation.from_quat(q).as_matrix().T
                pose[:3, 3] = t
                poses[os.path.splitext(parts[1])[0]] = pose
    if not poses:
        raise ValueError(f"no 'bmesh' lines in {conf_path}")
    return poses


def relative_motion(poses: dict, src: str, ref: str) -> np.ndarray:
    """The ``(4, 4)`` motion taking scan ``src`` onto scan ``ref``: ``T_ref^-1 T_src``."""
    return np.linalg.inv(poses[ref]) @ poses[src]


def write_poses(path: str, names, poses) -> None:
    """Writes ``poses (S, 4, 4)`` (scan → common frame) as a Stanford ``.conf``: one line
    ``bmesh NAME tx ty tz qx qy qz qw`` per scan, in :func:`read_poses`' convention (the quaternion of ``Rᵀ``)."""
    from scipy.spatial.transform import Rotation

    lines = []
    for name, pose in zip(names, np.asarray(poses, np.float64)):
        q = Rotation.from_matrix(pose[:3, :3].T).as_quat()
        lines.append(f"bmesh {name} " + " ".join(f"{v:.10g}" for v in (*pose[:3, 3], *q)) + "\n")
    with open(path, "w") as f:
        f.writelines(lines)


def pose_errors(poses, true_poses, clouds) -> list:
    """Per scan ``(rotation error in degrees, RMS displacement of its points)`` of ``poses (S, 4, 4)`` against
    ``true_poses (S, 4, 4)``, both taken relative to the first scan; ``clouds[i] (N_i, 3)`` in scan ``i``'s own
    frame. A NaN pose (a scan left out) gives ``(nan, nan)``."""
    poses, true_poses = np.asarray(poses, np.float64), np.asarray(true_poses, np.float64)
    out = []
    for pose, truth, points in zip(np.linalg.inv(poses[0]) @ poses, np.linalg.inv(true_poses[0]) @ true_poses, clouds):
        if not np.all(np.isfinite(pose)):
            out.append((float("nan"), float("nan")))
            continue
        rot = se3.rotation_angle_deg(truth[:3, :3].T @ pose[:3, :3])
        moved = points @ (pose[:3, :3] - truth[:3, :3]).T + (pose[:3, 3] - truth[:3, 3])
        out.append((float(rot), float(np.sqrt(np.mean(np.sum(moved ** 2, axis=1))))))
    return out
