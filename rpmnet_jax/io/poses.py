"""Poses of range scans in Stanford ``.conf`` files (``bmesh NAME tx ty tz qx qy qz qw``): read (ground truth),
written (:func:`rpmnet_jax.align_scans`' answer).

Convention (checked on the Stanford bunny: 98–99% of each posed scan lies within 1 mm of the reconstruction):
world points are ``p @ R + t`` with ``R`` the matrix of the quaternion, i.e. the pose of a scan is
``T = [[R^T, t], [0, 1]]``, and the motion taking scan A onto scan B is ``T_B^-1 T_A``.
"""

from __future__ import annotations

import os

import numpy as np

from rpmnet_jax.io import clouds


def read_poses(conf_path: str) -> dict:
    """``{scan name: (4, 4) pose}`` from a Stanford ``.conf`` file (names without a point-cloud extension)."""
    from scipy.spatial.transform import Rotation

    poses = {}
    with open(conf_path) as f:
        for line in f:
            parts = line.split()
            if len(parts) >= 9 and parts[0] == "bmesh":  # a name with spaces spans several parts
                t, q = np.array(parts[-7:-4], float), np.array(parts[-4:], float)
                parts = [parts[0], " ".join(parts[1:-7])]
                pose = np.eye(4)
                pose[:3, :3] = Rotation.from_quat(q).as_matrix().T
                pose[:3, 3] = t
                stem, ext = os.path.splitext(parts[1])  # bun000.ply -> bun000; scans.e57#2 stays
                poses[stem if ext.lower() in clouds.FORMATS else parts[1]] = pose
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
        lines.append(f"bmesh {name} " + " ".join(f"{v:.17g}" for v in (*pose[:3, 3], *q)) + "\n")
    with open(path, "w") as f:
        f.writelines(lines)
