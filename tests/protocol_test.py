"""Evaluation: classical RPM baseline, eval CLI outputs, --transforms-file with ground truth."""

import csv
import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rpmnet_jax.cli import evaluate as eval_cli
from rpmnet_jax import data
from rpmnet_jax.evaluation import protocol
from rpmnet_jax.evaluation import baselines
from rpmnet_jax import metrics
from rpmnet_jax.data import synthetic

NUM_POINTS = 128


@pytest.fixture(scope="module")
def tiny_root(tmp_path_factory):
    # 26 test shapes cycle through the categories: labels 20..25 form the 6-pair unseen-category test split.
    return synthetic.write_dataset(tmp_path_factory.mktemp("tiny"), num_train=2, num_test=26, seed=3)


def test_classical_rpm_registers_easy_clean_pair():
    src = synthetic.sample_shape(np.random.default_rng(4), 4, 256)[:, :3]
    rot = Rotation.from_euler("xyz", [30, -20, 25], degrees=True).as_matrix()
    trans = np.array([0.2, -0.1, 0.15])
    ref = src @ rot.T + trans
    pred = np.asarray(baselines.classical_rpm(src[None], ref[None].astype(np.float32)))[-1]
    gt = np.concatenate([rot, trans[:, None]], axis=1)[None]
    m = metrics.registration_metrics(pred, gt, src[None], ref[None], src[None])
    assert m["err_r_deg"][0] < 1.0
    assert m["err_t"][0] < 0.01


def _read_csv(path):
    with open(path) as f:
        rows = list(csv.reader(f))
    return rows[0], rows[1:]


def test_eval_cli_writes_documented_files(tiny_root, random_weights, tmp_path, capsys):
    out = tmp_path / "out"
    rc = eval_cli.main(["--dataset=partial", "--data-root", tiny_root, "--checkpoint", random_weights,
                        "--methods", "rpmnet,identity", "--num-points", str(NUM_POINTS), "--iters", "3",
                        "--batch-size", "4", "--figures", "2", "--no-progress", "--output", str(out)])
    assert rc == 0
    printed = capsys.readouterr().out
    assert "rpmnet" in printed and "identity" in printed and "Rot. MAE" in printed
    for name in ("metrics.json", "per_pair.csv", "transforms.npy", "per_pair_rpmnet.csv", "per_pair_identity.csv",
                 "transforms_identity.npy", "chamfer_per_iteration.png", "qualitative.png"):
        assert (out / name).is_file(), name
    header, rows = _read_csv(out / "per_pair.csv")
    assert tuple(header) == protocol.CSV_COLUMNS
    assert len(rows) == 6
    transforms = np.load(out / "transforms.npy")
    assert transforms.shape == (6, 3, 3, 4)
    assert np.load(out / "transforms_identity.npy").shape == (6, 1, 3, 4)
    report = json.loads((out / "metrics.json").read_text())
    rpmnet = report["methods"]["rpmnet"]
    assert rpmnet["pairs"] == 6 and len(rpmnet["chamfer_per_iteration"]) == 3
    assert set(rpmnet["summary"]) == {"r_rmse", "r_mae", "t_rmse", "t_mae", "err_r_deg_mean", "err_r_deg_rmse",
                                      "err_t_mean", "err_t_rmse", "chamfer_dist"}
    # The CSV rows are the metrics of the saved transforms.
    ds = data.ModelNet40(tiny_root, "test", "partial", num_points=NUM_POINTS)
    batch = {k: np.stack([ds[i][k] for i in range(6)]) for k in ("points_src", "points_ref", "points_raw",
                                                                  "transform_gt")}
    expect = metrics.registration_metrics(transforms[:, -1], batch["transform_gt"], batch["points_src"],
                                          batch["points_ref"], batch["points_raw"])
    np.testing.assert_allclose([float(r[header.index("err_r_deg")]) for r in rows], expect["err_r_deg"], rtol=1e-6)


def test_transforms_file_with_ground_truth_gives_zero_error(tiny_root, tmp_path):
    ds = data.ModelNet40(tiny_root, "test", "noisy", num_points=NUM_POINTS)
    samples = [ds[i] for i in range(len(ds))]
    gt = np.stack([s["transform_gt"] for s in samples])
    np.save(tmp_path / "gt.npy", gt)
    out = tmp_path / "out"
    rc = eval_cli.main(["--dataset=noisy", "--data-root", tiny_root, "--transforms-file", str(tmp_path / "gt.npy"),
                        "--num-points", str(NUM_POINTS), "--figures", "0", "--no-progress", "--output", str(out)])
    assert rc == 0
    header, rows = _read_csv(out / "per_pair.csv")
    col = {name: np.array([float(r[header.index(name)]) for r in rows]) for name in header}
    for name in ("r_mae", "t_mae", "err_t"):  # the file's transforms are the ground truth bit for bit
        np.testing.assert_array_equal(col[name], 0.0, err_msg=name)
    # The isotropic angle of the residual M = RᵀR is atan2(|vee(M - Mᵀ)| / 2, (tr M - 1) / 2): M is exactly
    # symmetric in floating point (the same products in the same order), so the angle is 0 up to round-off
    # (an arccos of the trace alone read the float32 orthogonality defect of R as up to 0.013°).
    assert col["err_r_deg"].max() < 1e-4
    floor = metrics.registration_metrics(gt, gt, np.stack([s["points_src"] for s in samples]),
                                         np.stack([s["points_ref"] for s in samples]),
                                         np.stack([s["points_raw"] for s in samples]))["chamfer_dist"]
    assert np.all(floor > 0)  # noise keeps the floor above zero
    np.testing.assert_allclose(col["chamfer_dist"], floor, rtol=1e-5)


def test_eval_cli_errors(tiny_root, tmp_path, capsys):
    with pytest.raises(SystemExit):
        eval_cli.main(["--synthetic", "--methods", "rpmnet,bogus"])
    assert "unknown methods" in capsys.readouterr().err
    np.save(tmp_path / "short.npy", np.zeros((2, 3, 4)))
    rc = eval_cli.main(["--data-root", tiny_root, "--transforms-file", str(tmp_path / "short.npy"),
                        "--num-points", str(NUM_POINTS), "--output", str(tmp_path / "o")])
    assert rc == 2
    assert "--transforms-file" in capsys.readouterr().err


@pytest.mark.parametrize("method", ["icp", "fgr"])
def test_open3d_baselines_register_easy_pair(method):
    why = baselines.open3d_available()
    if why:
        pytest.skip(why)
    src = synthetic.sample_shape(np.random.default_rng(4), 4, 512)
    rot = Rotation.from_euler("xyz", [10, -5, 8], degrees=True).as_matrix()
    trans = np.array([0.05, 0.0, 0.02])
    ref = np.concatenate([src[:, :3] @ rot.T + trans, src[:, 3:] @ rot.T], axis=1)
    pred = protocol.method_fn(method)(src[None], ref[None])
    assert pred.shape == (1, 1, 3, 4)
    gt = np.concatenate([rot, trans[:, None]], axis=1)[None]
    assert metrics.registration_metrics(pred[:, -1], gt, src[None], ref[None], src[None])["err_r_deg"][0] < 1.0


@pytest.mark.parametrize("method", ["ransac_icp", "fgr_icp"])
def test_open3d_recipes_register_a_large_rotation_precisely(method):
    """Open3D's classical recipe (FPFH + RANSAC or FGR, then point-to-plane ICP) from any start: 120° about a
    random axis on an asymmetric shape (one right answer), two different samplings of its surface."""
    why = baselines.open3d_available()
    if why:
        pytest.skip(why)
    from conftest import asymmetric_shape, rotation_about
    pts, nrm = asymmetric_shape(seed=1, n=2048)
    cloud = np.concatenate([pts, nrm], axis=1).astype(np.float32)
    src, ref = cloud[::2], cloud[1::2]
    rot = rotation_about([0.3, -0.8, 0.5], 120)
    trans = np.array([0.1, -0.05, 0.2])
    ref = np.concatenate([ref[:, :3] @ rot.T + trans, ref[:, 3:] @ rot.T], axis=1).astype(np.float32)
    pred = protocol.method_fn(method)(src[None], ref[None])
    assert pred.shape == (1, 1, 3, 4)
    gt = np.concatenate([rot, trans[:, None]], axis=1)[None]
    m = metrics.registration_metrics(pred[:, -1], gt, src[None], ref[None], src[None])
    assert m["err_r_deg"][0] < 1.0 and m["err_t"][0] < 0.01


@pytest.mark.parametrize("method", protocol.NETWORK_METHODS)
def test_every_network_method_reads_the_checkpoint(tiny_root, tmp_path, capsys, method):
    """--checkpoint reaches every method that runs the network (network_icp once silently used the default)."""
    missing = tmp_path / "missing.npz"
    rc = eval_cli.main(["--dataset=partial", "--data-root", tiny_root, "--checkpoint", str(missing),
                        "--methods", method, "--num-points", str(NUM_POINTS), "--no-progress",
                        "--output", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert rc == 2 and "missing.npz" in err and len(err.strip().splitlines()) == 1


def test_network_methods_are_the_methods_that_use_params():
    assert set(protocol.NETWORK_METHODS) <= set(protocol.METHODS)
    assert set(protocol.PIPELINES) - set(protocol.NETWORK_METHODS) == {"classical_icp"}
