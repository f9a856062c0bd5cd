"""Per-scan errors of estimated scan poses against true ones (e.g. a Stanford ``.conf``'s, read by
:func:`rpmnet_jax.io.poses.read_poses`)."""

from __future__ import annotations

import numpy as np

from rpmnet_jax.ops import se3


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
