"""Range-scan evaluation: pose file parsing, ground-truth composition, CLI output."""

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rpmnet_jax.cli import eval_scans
from rpmnet_jax import metrics
from rpmnet_jax.io import poses as scan_poses
from rpmnet_jax.io import clouds as cloud_io
from rpmnet_jax.data import synthetic


def _conf_line(name, pose):
    q = Rotation.from_matrix(pose[:3, :3].T).as_quat()  # file stores R with world = p @ R + t
    return f"bmesh {name}.ply {' '.join(map(str, pose[:3, 3]))} {' '.join(map(str, q))}\n"


@pytest.fixture()
def scans(tmp_path):
    """Two 'scans' of one synthetic shape, each in its own sensor frame, with their poses."""
    rng = np.random.default_rng(0)
    world = synthetic.sample_shape(rng, 9, 3000)[:, :3] * 0.1
    poses = {}
    for name, angles, t in (("a", [0, 30, 0], [0.01, 0.0, -0.02]), ("b", [0, -10, 5], [0.0, 0.02, 0.0])):
        pose = np.eye(4)
        pose[:3, :3] = Rotation.from_euler("xyz", angles, degrees=True).as_matrix()
        pose[:3, 3] = t
        poses[name] = pose
        local = (world - pose[:3, 3]) @ pose[:3, :3]  # world = R local + t
        cloud_io.write_cloud(str(tmp_path / f"{name}.ply"), local)
    with open(tmp_path / "scans.conf", "w") as f:
        f.write("camera 0 0 0 0 0 0 1\n")
        f.writelines(_conf_line(n, p) for n, p in poses.items())
    return tmp_path, poses


def test_read_poses_round_trips(scans):
    folder, poses = scans
    got = scan_poses.read_poses(str(folder / "scans.conf"))
    for name, pose in poses.items():
        np.testing.assert_allclose(got[name], pose, atol=1e-12)


def test_errors_of_known_transforms():
    gt = np.eye(4)
    pred = np.eye(4)
    pred[:3, :3] = Rotation.from_euler("z", 12, degrees=True).as_matrix()
    pred[:3, 3] = [0.0, 0.3, 0.4]
    err_r, err_t = metrics.transform_errors(pred, gt)
    assert err_r == pytest.approx(12.0) and err_t == pytest.approx(0.5)


def test_cli_ground_truth_and_outputs(scans, tmp_path, capsys):
    folder, poses = scans
    out = tmp_path / "res.json"
    rc = eval_scans.main(["--scans", str(folder), "--conf", "scans.conf", "--pairs", "a:b", "--methods", "rpm,identity",
                          "--num-points", "256", "--output", str(out)])
    assert rc == 0
    res = json.loads(out.read_text())
    row = res["pairs"][0]
    gt = np.linalg.inv(poses["b"]) @ poses["a"]
    assert row["gt_rotation_deg"] == pytest.approx(metrics.transform_errors(gt, np.eye(4))[0])
    # identity's error is the ground-truth motion itself; RPM on an exact overlap recovers it.
    assert row["identity"]["err_r_deg"] == pytest.approx(row["gt_rotation_deg"], abs=1e-6)
    assert row["rpm"]["err_r_deg"] < 2.0 and row["rpm"]["err_t"] < 0.002
    assert "identity deg/mm" in capsys.readouterr().out


def test_cli_rejects_unknown_pairs(scans, capsys):
    folder, _ = scans
    rc = eval_scans.main(["--scans", str(folder), "--conf", "scans.conf", "--pairs", "a:zzz", "--methods", "identity"])
    assert rc == 2 and "--pairs" in capsys.readouterr().err
