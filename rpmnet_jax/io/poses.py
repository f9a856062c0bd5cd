"""Poses of range scans in Stanford ``.conf`` files (``bmesh NAME tx ty tz qx qy qz qw``): read (ground truth),
written (:func:`rpmnet_jax.align_scans`' answer).

A NAME with whitespace, a quote or a backslash is written as a JSON string (``bmesh "site 2.ply" …``); the reader
takes a NAME in double quotes as one, else everything between ``bmesh`` and the last seven numbers.

Convention (checked on the Stanford bunny: 98–99% of each posed scan lies within 1 mm of the reconstruction):
world points are ``p @ R + t`` with ``R`` the matrix of the quaternion, i.e. the pose of a scan is
``T = [[R^T, t], [0, 1]]``, and the motion taking scan A onto scan B is ``T_B^-1 T_A``.
"""

from __future__ import annotations

import json
import os

import numpy as np

from rpmnet_jax.io import clouds


def read_poses(conf_path: str) -> dict:
    """``{scan name: (4, 4) pose}`` from a Stanford ``.conf`` file (names without a point-cloud extension)."""
    from scipy.spatial.transform import Rotation

    poses = {}
    with open(conf_path, encoding="utf-8") as f:
        for line in f:
            head = line.split(None, 1)
            if len(head) < 2 or head[0] != "bmesh":
                continue
            parts = head[1].rsplit(None, 7)  # [NAME, tx, ty, tz, qx, qy, qz, qw]: NAME keeps its own spaces
            if len(parts) != 8:
                continue
            numbers = np.array(parts[1:], float)
            pose = np.eye(4)
            pose[:3, :3] = Rotation.from_quat(numbers[3:]).as_matrix().T
            pose[:3, 3] = numbers[:3]
            name = _unquote(parts[0].strip())
            stem, ext = os.path.splitext(name)  # bun000.ply -> bun000; scans.e57#2 stays
            poses[stem if ext.lower() in clouds.FORMATS else name] = pose
    if not poses:
        raise ValueError(f"no 'bmesh' lines in {conf_path}")
    return poses


def relative_motion(poses: dict, src: str, ref: str) -> np.ndarray:
    """The ``(4, 4)`` motion taking scan ``src`` onto scan ``ref``: ``T_ref^-1 T_src``."""
    return np.linalg.inv(poses[ref]) @ poses[src]


def write_poses(path: str, names, poses) -> None:
    """Writes ``poses (S, 4, 4)`` (scan → common frame) as a Stanford ``.conf``: one line
    ``bmesh NAME tx ty tz qx qy qz qw`` per scan, in :func:`read_poses`' convention (the quaternion of ``Rᵀ``; a
    NAME with whitespace in double quotes)."""
    from scipy.spatial.transform import Rotation

    lines = []
    for name, pose in zip(names, np.asarray(poses, np.float64)):
        q = Rotation.from_matrix(pose[:3, :3].T).as_quat()
        lines.append(f"bmesh {_quote(name)} " + " ".join(f"{v:.17g}" for v in (*pose[:3, 3], *q)) + "\n")
    with open(path, "w", encoding="utf-8") as f:
        f.writelines(lines)


def _quote(name: str) -> str:
    """``name`` as written in a ``.conf``: as it is, or a JSON string when it holds whitespace, ``"`` or ``\\``."""
    plain = name.isprintable() and name.split() == [name] and '"' not in name and "\\" not in name
    return name if plain else json.dumps(name, ensure_ascii=False)


def _unquote(text: str) -> str:
    """The name that :func:`_quote` wrote as ``text`` (a Stanford name, unquoted, is itself)."""
    if len(text) >= 2 and text[0] == text[-1] == '"':
        try:
            return json.loads(text)
        except json.JSONDecodeError:
            pass
    return text
