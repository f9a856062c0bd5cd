"""Many scans into one frame: voxel downsampling, point-to-plane information, the robust pose graph, pose files,
``align_scans`` on real bunny scans, and the ``rpmnet-register-scans`` CLI with its errors."""

import itertools
import os

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from conftest import DATA, require, rotation_error_deg
import rpmnet_jax
from rpmnet_jax.cli import register_scans
from rpmnet_jax.io import poses as scan_poses
from rpmnet_jax.evaluation import pose_errors
from rpmnet_jax.geometry import cloud, sampling, scoring
from rpmnet_jax.io import clouds as cloud_io
from rpmnet_jax.multiway import pose_graph

BUNNY = DATA / "stanford_bunny"


def _random_pose(rng, trans=0.1):
    pose = np.eye(4)
    pose[:3, :3] = Rotation.random(random_state=rng.integers(1 << 30)).as_matrix()
    pose[:3, 3] = rng.normal(size=3) * trans
    return pose


def test_voxel_downsample_means_per_cube():
    pts = np.array([[0.1, 0.1, 0.1], [0.3, 0.3, 0.3], [1.2, 0.1, 0.1], [1.4, 0.1, 0.1]])
    nrm = np.array([[0, 0, 1.0], [0, 1.0, 0], [1.0, 0, 0], [1.0, 0, 0]])
    got, got_n = sampling.voxel_downsample(pts, nrm, 1.0)
    order = np.argsort(got[:, 0])
    np.testing.assert_allclose(got[order], [[0.2, 0.2, 0.2], [1.3, 0.1, 0.1]])
    np.testing.assert_allclose(got_n[order], [[0, 2 ** -0.5, 2 ** -0.5], [1, 0, 0]], atol=1e-12)
    assert sampling.voxel_downsample(pts, None, 1.0)[1] is None
    with pytest.raises(ValueError, match="voxel_size"):
        sampling.voxel_downsample(pts, None, 0.0)


def test_plane_fit_information_is_the_right_perturbation_jacobian():
    """``information = JᵀJ / σ²`` with ``J`` the finite-difference Jacobian of the residuals under ``T·Exp(ξ)``."""
    import gtsam

    rng = np.random.default_rng(0)
    src = rng.uniform(-1, 1, size=(200, 3))
    normals = rng.normal(size=(200, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    t = _random_pose(rng)
    ref = src @ t[:3, :3].T + t[:3, 3] + 0.01 * rng.normal(size=(200, 3))
    corr = np.stack([np.arange(200), np.arange(200)], axis=1)
    fit = scoring.plane_fit(src, ref, normals, t, corr)
    eps = 1e-6
    jac = np.stack([(scoring.plane_fit(src, ref, normals, t @ gtsam.Pose3.Expmap(eps * np.eye(6)[k]).matrix(),
                                       corr).residuals - fit.residuals) / eps for k in range(6)], axis=1)
    np.testing.assert_allclose(fit.information, jac.T @ jac / np.mean(fit.residuals ** 2), rtol=1e-4, atol=1e-3)
    assert scoring.plane_fit(src, ref, normals, t, np.zeros((0, 2), int)).information.shape == (6, 6)


def _graph(rng, num_nodes=7, noise_deg=0.05, noise_t=1e-4):
    poses = np.stack([np.eye(4)] + [_random_pose(rng) for _ in range(num_nodes - 1)])
    pairs = list(itertools.combinations(range(num_nodes), 2))
    transforms = []
    for i, j in pairs:
        jitter = np.eye(4)
        jitter[:3, :3] = Rotation.from_rotvec(np.radians(noise_deg) * rng.normal(size=3)).as_matrix()
        jitter[:3, 3] = noise_t * rng.normal(size=3)
        transforms.append(np.linalg.inv(poses[j]) @ poses[i] @ jitter)
    info = np.diag([np.radians(noise_deg) ** -2] * 3 + [noise_t ** -2] * 3)
    return poses, pairs, np.stack(transforms), np.broadcast_to(info, (len(pairs), 6, 6))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_robust_pose_graph_rejects_flipped_edges(seed):
    """5 of 21 edges flipped by 150–180° about random axes (as a symmetric wrong answer is): exactly those are
    rejected, whatever their weights say, and the poses are the truth's; least squares is pulled away."""
    rng = np.random.default_rng(seed)
    poses, pairs, transforms, info = _graph(rng)
    wrong = rng.choice(len(pairs), 5, replace=False)
    transforms = transforms.copy()
    for e in wrong:
        axis = rng.normal(size=3)
        flip = np.eye(4)
        flip[:3, :3] = Rotation.from_rotvec(np.radians(rng.uniform(150, 180)) * axis / np.linalg.norm(axis)).as_matrix()
        transforms[e] = transforms[e] @ flip
    weights = np.ones(len(pairs))
    weights[wrong] = 2.0  # the wrong edges look best: the maximum-weight tree holds them
    sol = pose_graph.optimize(len(poses), pairs, transforms, info, 0, weights=weights)
    assert sorted(np.nonzero(~sol.inlier)[0]) == sorted(wrong)
    for got, want in zip(sol.poses, poses):
        assert rotation_error_deg(got[:3, :3], want[:3, :3]) < 0.2
        assert np.linalg.norm(got[:3, 3] - want[:3, 3]) < 1e-3
    plain = pose_graph.optimize(len(poses), pairs, transforms, info, 0, weights=weights, robust=False)
    assert plain.inlier.all()
    assert max(rotation_error_deg(g[:3, :3], w[:3, :3]) for g, w in zip(plain.poses, poses)) > 5


def test_spanning_tree_and_components():
    rng = np.random.default_rng(3)
    poses, pairs, transforms, info = _graph(rng, num_nodes=5, noise_deg=1e-7, noise_t=1e-9)
    keep = [k for k, (i, j) in enumerate(pairs) if j == i + 1 and j != 4]  # a chain 0-1-2-3; node 4 apart
    tree = pose_graph.spanning_tree_poses(5, [pairs[k] for k in keep], transforms[keep], np.ones(len(keep)), 0)
    np.testing.assert_allclose(tree[:4], poses[:4], atol=1e-9)
    assert np.all(np.isnan(tree[4]))
    np.testing.assert_array_equal(pose_graph.component(5, [pairs[k] for k in keep], 2), [1, 1, 1, 1, 0])
    sol = pose_graph.optimize(5, [pairs[k] for k in keep], transforms[keep], info[keep], 0)  # a tree: plain LM
    assert sol.inlier.all() and np.all(np.isnan(sol.poses[4]))
    np.testing.assert_allclose(sol.poses[:4], poses[:4], atol=1e-7)


def test_conf_files_round_trip(tmp_path):
    rng = np.random.default_rng(0)
    poses = np.stack([np.eye(4)] + [_random_pose(rng) for _ in range(3)])
    names = ["a.ply", "b.ply", "c.pcd", "d.xyz"]
    scan_poses.write_poses(str(tmp_path / "p.conf"), names, poses)
    got = scan_poses.read_poses(str(tmp_path / "p.conf"))
    assert list(got) == ["a", "b", "c", "d"]
    np.testing.assert_allclose(np.stack(list(got.values())), poses, atol=1e-8)
    if (BUNNY / "bun.conf").is_file():  # bun.conf's own convention survives a write
        true = scan_poses.read_poses(str(BUNNY / "bun.conf"))
        scan_poses.write_poses(str(tmp_path / "bun.conf"), [f"{n}.ply" for n in true], np.stack(list(true.values())))
        again = scan_poses.read_poses(str(tmp_path / "bun.conf"))
        np.testing.assert_allclose(np.stack(list(again.values())), np.stack(list(true.values())), atol=1e-8)


def test_pose_errors_relative_to_the_first_scan():
    rng = np.random.default_rng(1)
    truth = np.stack([_random_pose(rng) for _ in range(3)])
    offset = _random_pose(rng)
    pred = offset @ truth  # the same poses in another common frame: no error
    turn = Rotation.from_euler("z", 2, degrees=True).as_matrix()  # in scan 2's own frame
    pred[2, :3, :3] = pred[2, :3, :3] @ turn
    clouds = [rng.normal(size=(50, 3)) for _ in range(3)]
    errors = pose_errors.pose_errors(pred, truth, clouds)
    assert errors[0][0] < 1e-5 and errors[0][1] < 1e-12 and errors[1][0] < 1e-5 and errors[1][1] < 1e-9
    assert errors[2][0] == pytest.approx(2.0)
    rms = np.sqrt(np.mean(np.sum((clouds[2] @ turn.T - clouds[2]) ** 2, axis=1)))
    assert errors[2][1] == pytest.approx(rms)


@pytest.fixture(scope="module")
def bunny():
    require(BUNNY / "bun.conf", "Stanford bunny scans")
    return scan_poses.read_poses(str(BUNNY / "bun.conf"))


def _read(names):
    return [cloud_io.read_cloud(str(BUNNY / f"{n}.ply"))[0] for n in names]


def test_align_scans_four_bunny_scans(bunny):
    names = ["bun000", "bun045", "bun315", "chin"]
    clouds = _read(names)
    result = rpmnet_jax.align_scans(clouds, options=rpmnet_jax.ScanOptions(voxel_size=0.003))
    truth = np.stack([bunny[n] for n in names])
    errors = pose_errors.pose_errors(result.poses, truth, clouds)
    print(dict(zip(names, errors)), result.timings)
    np.testing.assert_allclose(result.poses[0], np.eye(4), atol=1e-9)
    assert all(rot < 1.0 and rms < 2e-3 for rot, rms in errors), errors
    assert result.left_out == () and result.voxel_size == 0.003
    assert len(result.edges) >= 3 and {e.stage for e in result.edges} == {"refine"}
    for e in result.edges:
        assert e.information.shape == (6, 6) and 0 < e.fitness <= 1 and e.inlier_rmse > 0
        assert np.all(np.linalg.eigvalsh(0.5 * (e.information + e.information.T)) > 0)


def _write_scans(tmp_path, clouds, names):
    paths = []
    for c, n in zip(clouds, names):
        paths.append(str(tmp_path / f"{n}.npy"))
        cloud_io.write_cloud(paths[-1], c)
    return paths


def test_cli_bad_input_exits_2_and_writes_nothing(tmp_path, capsys):
    rng = np.random.default_rng(0)
    a = rng.normal(size=(300, 3))
    cloud_io.write_cloud(str(tmp_path / "a.xyz"), a)
    (tmp_path / "sub").mkdir()
    cloud_io.write_cloud(str(tmp_path / "sub" / "a.xyz"), a)
    np.save(tmp_path / "empty.npy", np.zeros((0, 3)))
    (tmp_path / "nothing").mkdir()
    out = tmp_path / "poses.conf"
    cases = {
        "at least two": [str(tmp_path / "a.xyz")],
        "duplicate scan names": [str(tmp_path / "a.xyz"), str(tmp_path / "sub" / "a.xyz")],
        "empty": [str(tmp_path / "a.xyz"), str(tmp_path / "empty.npy")],
        "no such file": [str(tmp_path / "a.xyz"), str(tmp_path / "missing.ply")],
        "no point-cloud files": [str(tmp_path / "nothing")],
        "unknown point-cloud format": [str(tmp_path / "a.xyz"), str(tmp_path / "b.obj")],
    }
    for message, scans in cases.items():
        rc = register_scans.main(scans + ["--out-poses", str(out), "--out-merged", str(tmp_path / "m.ply")])
        err = capsys.readouterr().err
        assert rc == 2 and message in err and len(err.strip().splitlines()) == 1, (message, err)
        assert not out.exists() and not (tmp_path / "m.ply").exists()
    rc = register_scans.main([str(tmp_path / "a.xyz"), str(tmp_path / "sub" / "a.xyz"), "--out-poses",
                              str(tmp_path / "no" / "p.conf")])
    assert rc == 2 and "does not exist" in capsys.readouterr().err


def test_cli_writes_poses_merged_cloud_and_plot(tmp_path, capsys):
    clouds, poses = _synthetic_scans()
    folder = tmp_path / "scans"
    folder.mkdir()
    paths = _write_scans(folder, clouds, ["s0", "s1", "s2"])
    out, merged, plot = tmp_path / "poses.conf", tmp_path / "merged.ply", tmp_path / "scans.png"
    rc = register_scans.main([str(folder), "--out-poses", str(out), "--out-merged", str(merged), "--plot", str(plot)])
    assert rc == 0, capsys.readouterr().err
    got = scan_poses.read_poses(str(out))
    assert list(got) == ["s0", "s1", "s2"] and out.read_text().startswith("bmesh s0.npy 0 0 0 0 0 0 1")
    truth = np.linalg.inv(poses[0]) @ poses
    for name, want in zip(got, truth):
        assert rotation_error_deg(got[name][:3, :3], want[:3, :3]) < 1.0
    points, _ = cloud_io.read_cloud(str(merged))
    assert "property double x" in merged.read_bytes()[:300].decode("ascii", "replace")  # float64
    want = np.concatenate([c @ t[:3, :3].T + t[:3, 3] for c, t in zip(clouds, truth)])
    assert points.shape == want.shape and np.sqrt(np.mean(np.sum((points - want) ** 2, axis=1))) < 2e-3
    assert plot.stat().st_size > 0 and len(paths) == 3


def test_console_entry_point_starts():
    import subprocess
    import sys
    out = subprocess.run([sys.executable, "-c", "from rpmnet_jax.cli.register_scans import entry; entry()", "--help"],
                         capture_output=True, text=True, env=dict(os.environ, RPMNET_COMPILATION_CACHE="off"))
    assert out.returncode == 0 and "usage:" in out.stdout, out.stderr[-2000:]


def _synthetic_scans():
    """Three overlapping partial views ``(N_i, 3)`` of one synthetic shape (~0.2 across), each in its own frame,
    and their poses ``(3, 4, 4)`` (scan → world)."""
    from rpmnet_jax.data import synthetic

    world = synthetic.sample_shape(np.random.default_rng(0), 36, 4000)[:, :3] * 0.1
    clouds, poses = [], []
    for k in range(3):
        pose = np.eye(4)
        pose[:3, :3] = Rotation.from_euler("xyz", [5 * k, 20 * k, -10 * k], degrees=True).as_matrix()
        pose[:3, 3] = [0.01 * k, 0.0, -0.02 * k]
        keep = world[:, 0] > -0.03 + 0.02 * k
        clouds.append((world[keep] - pose[:3, 3]) @ pose[:3, :3])
        poses.append(pose)
    return clouds, np.stack(poses)


def test_align_scans_without_refinement_keeps_the_network_edges():
    clouds, poses = _synthetic_scans()
    result = rpmnet_jax.align_scans(clouds, options=rpmnet_jax.ScanOptions(refine="none"))
    errors = pose_errors.pose_errors(result.poses, poses, clouds)
    assert all(rot < 2.0 for rot, _ in errors), errors
    assert result.edges and {e.stage for e in result.edges} == {"network"} and "refine" not in result.timings
    with pytest.raises(ValueError, match="at least two scans"):
        rpmnet_jax.align_scans(clouds[:1])
    with pytest.raises(ValueError, match="refine"):
        rpmnet_jax.ScanOptions(refine="bad")


def test_eval_multiway_reports_per_scan_errors(tmp_path, capsys):
    """``eval_scans --multiway`` on three synthetic scans of one shape with a ``.conf``: both methods run, the
    JSON has every scan's errors (the first scan's are zero), the plot is written."""
    import json

    from rpmnet_jax.cli import eval_scans
    from rpmnet_jax.evaluation import baselines

    clouds, poses = _synthetic_scans()
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
    assert ours[0]["rotation_deg"] < 1e-5 and all(r["rotation_deg"] < 1.0 and r["rms"] < 2e-3 for r in ours), ours
    assert plot.stat().st_size > 0 and "within 0.5 deg and 1 mm" in capsys.readouterr().out


@pytest.mark.slow
def test_cli_leaves_out_a_scan_that_overlaps_nothing(bunny, tmp_path, capsys):
    """Three bunny scans and a synthetic box: the box is reported and left out; the rest is written."""
    from rpmnet_jax.data import synthetic

    names = ["bun000", "bun045", "bun315"]
    clouds = [sampling.voxel_downsample(c, None, 0.002)[0] for c in _read(names)]
    box = synthetic.sample_shape(np.random.default_rng(0), 8, 3000)[:, :3] * 0.05 + [0.3, 0.0, 0.0]
    paths = _write_scans(tmp_path, clouds + [box], names + ["box"])
    out, merged, plot = tmp_path / "poses.conf", tmp_path / "merged.ply", tmp_path / "scans.png"
    rc = register_scans.main(paths + ["--out-poses", str(out), "--out-merged", str(merged), "--merged-voxel", "0.001",
                                      "--plot", str(plot)])
    captured = capsys.readouterr()
    assert rc == 0, captured.err
    assert "box.npy overlaps none of the placed scans" in captured.err
    got = scan_poses.read_poses(str(out))
    assert list(got) == names
    for n in names:
        truth = np.linalg.inv(bunny["bun000"]) @ bunny[n]
        assert rotation_error_deg(got[n][:3, :3], truth[:3, :3]) < 1.0
    points, _ = cloud_io.read_cloud(str(merged))
    assert 1000 < len(points) < sum(len(c) for c in clouds) and plot.stat().st_size > 0


@pytest.mark.slow
def test_align_scans_all_bunny_scans_within_half_a_degree(bunny):
    names = list(bunny)
    clouds = _read(names)
    result = rpmnet_jax.align_scans(clouds)
    errors = pose_errors.pose_errors(result.poses, np.stack([bunny[n] for n in names]), clouds)
    print(dict(zip(names, errors)), result.timings)
    assert all(rot <= 0.5 and rms <= 1e-3 for rot, rms in errors), dict(zip(names, errors))
