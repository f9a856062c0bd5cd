"""The ``rpmnet-eval-scans`` CLI: ground truth composed from a ``.conf``, pairwise results and their JSON, the
multiway evaluation, its errors."""

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from conftest import synthetic_scans
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
    assert row["rpm"]["err_r_deg"] < 2.0 and row["rpm"]["err_t"] < 0.002  # measured 0.89° and 0.001 (256 points)
    assert "identity deg/mm" in capsys.readouterr().out


def test_cli_rejects_unknown_pairs(scans, capsys):
    folder, _ = scans
    rc = eval_scans.main(["--scans", str(folder), "--conf", "scans.conf", "--pairs", "a:zzz", "--methods", "identity"])
    assert rc == 2 and "--pairs" in capsys.readouterr().err


def test_eval_multiway_reports_per_scan_errors(tmp_path, capsys):
    """``eval_scans --multiway`` on three synthetic scans of one shape with a ``.conf``: both methods run, the
    JSON has every scan's errors (the first scan's are zero), the plot is written."""
    from rpmnet_jax.evaluation import baselines

    clouds, poses = synthetic_scans()
    names = ["s0", "s1", "s2"]
    for name, cloud in zip(names, clouds):
        cloud_io.write_cloud(str(tmp_path / f"{name}.ply"), cloud)
    scan_poses.write_poses(str(tmp_path / "scans.conf"), [f"{n}.ply" for n in names], poses)
    methods = "rpmnet_multiway" + ("" if baselines.open3d_available() else ",open3d_multiway")
    out, plot = tmp_path / "res.json", tmp_path / "merged.png"
    rc = eval_scans.main(["--scans", str(tmp_path), "--conf", "scans.conf", "--multiway", "--multiway-methods",
                          methods, "--baseline-voxel", "0.004", "--output", str(out), "--plot", str(plot)])
    assert rc == 0, capsys.readouterr().err
    res = json.loads(out.read_text())
    assert res["scans"] == names and set(res["per_scan"]) == set(methods.split(","))
    ours = res["per_scan"]["rpmnet_multiway"]
    # the first scan: zero up to round-off; the others within 1° and 2 mm (1% of the ~0.2 shape; measured
    # 0.0006° and 5e-7)
    assert ours[0]["rotation_deg"] < 1e-5 and all(r["rotation_deg"] < 1.0 and r["rms"] < 2e-3 for r in ours), ours
    assert plot.stat().st_size > 0 and "within 0.5 deg and 1 mm" in capsys.readouterr().out
