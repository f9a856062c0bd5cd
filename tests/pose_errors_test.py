"""Per-scan pose errors: relative to the first scan, in degrees and RMS point displacement; NaN for a scan left
out."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from conftest import random_pose
from rpmnet_jax.evaluation import pose_errors


def test_pose_errors_relative_to_the_first_scan():
    rng = np.random.default_rng(1)
    truth = np.stack([random_pose(rng) for _ in range(3)])
    offset = random_pose(rng)
    pred = offset @ truth  # the same poses in another common frame: no error
    turn = Rotation.from_euler("z", 2, degrees=True).as_matrix()  # in scan 2's own frame
    pred[2, :3, :3] = pred[2, :3, :3] @ turn
    clouds = [rng.normal(size=(50, 3)) for _ in range(3)]
    errors = pose_errors.pose_errors(pred, truth, clouds)
    # zero up to float64 round-off of the composed poses (an angle of a round-off rotation: ~1e-6°)
    assert errors[0][0] < 1e-5 and errors[0][1] < 1e-12 and errors[1][0] < 1e-5 and errors[1][1] < 1e-9
    assert errors[2][0] == pytest.approx(2.0)
    rms = np.sqrt(np.mean(np.sum((clouds[2] @ turn.T - clouds[2]) ** 2, axis=1)))
    assert errors[2][1] == pytest.approx(rms)


def test_a_scan_left_out_has_nan_errors():
    rng = np.random.default_rng(2)
    truth = np.stack([random_pose(rng) for _ in range(3)])
    pred = truth.copy()
    pred[1] = np.nan
    errors = pose_errors.pose_errors(pred, truth, [rng.normal(size=(20, 3)) for _ in range(3)])
    assert np.isnan(errors[1]).all() and np.isfinite(errors[0]).all() and np.isfinite(errors[2]).all()
    assert errors[2][0] < 1e-5
