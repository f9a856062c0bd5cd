"""Ground truth of range scans with known poses: Stanford ``.conf`` files (``bmesh NAME tx ty tz qx qy qz qw``).

Convention (checked on the Stanford bunny: 98–99% of each posed scan lies within 1 mm of the reconstruction):
world points are ``p @ R + t`` with ``R`` the matrix of the quaternion, i.e. the pose of a scan is
``T = [[R^T, t], [0, 1]]``, and the motion taking scan A onto scan B is ``T_B^-1 T_A``.
"""

from __future__ import annotations

import os

import numpy as np


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
