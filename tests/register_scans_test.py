"""The ``rpmnet-register-scans`` CLI: one-line errors that write nothing, the poses, merged cloud and plot it
writes, a scan that overlaps nothing left out, a SIGKILLed run resumed from its ``--cache`` (the poses of a run
from scratch on Dask workers)."""

import os
import re
import signal
import socket
import subprocess
import sys
import time

import numpy as np
import pytest

from conftest import DATA, require, ring_scans, rotation_error_deg, synthetic_scans
from rpmnet_jax.cli import register_scans
from rpmnet_jax.geometry import sampling
from rpmnet_jax.io import clouds as cloud_io
from rpmnet_jax.io import poses as scan_poses

BUNNY = DATA / "stanford_bunny"


def _write_scans(tmp_path, clouds, names):
    paths = []
    for c, n in zip(clouds, names):
        paths.append(str(tmp_path / f"{n}.npy"))
        cloud_io.write_cloud(paths[-1], c)
    return paths


def _assert_refused(tmp_path, capsys, cases: dict) -> None:
    """Each ``{message: scan arguments}`` case exits 2 with a one-line error containing ``message`` and writes
    neither the poses nor the merged cloud."""
    out, merged = tmp_path / "poses.conf", tmp_path / "m.ply"
    for message, scans in cases.items():
        rc = register_scans.main(scans + ["--out-poses", str(out), "--out-merged", str(merged)])
        err = capsys.readouterr().err
        assert rc == 2 and message in err and len(err.strip().splitlines()) == 1, (message, err)
        assert not out.exists() and not merged.exists()


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
    _assert_refused(tmp_path, capsys, cases)
    rc = register_scans.main([str(tmp_path / "a.xyz"), str(tmp_path / "sub" / "a.xyz"), "--out-poses",
                              str(tmp_path / "no" / "p.conf")])
    assert rc == 2 and "does not exist" in capsys.readouterr().err
    rc = register_scans.main([str(tmp_path / "a.xyz"), str(tmp_path / "sub" / "a.xyz"), "--out-poses", str(out),
                              "--html", str(tmp_path / "r.png")])
    err = capsys.readouterr().err
    assert rc == 2 and "--html must name a .html file" in err and len(err.strip().splitlines()) == 1, err
    assert not out.exists() and not (tmp_path / "r.png").exists()


def test_cli_writes_poses_merged_cloud_plot_and_page(tmp_path, capsys):
    clouds, poses = synthetic_scans()
    folder = tmp_path / "scans"
    folder.mkdir()
    paths = _write_scans(folder, clouds, ["s0", "s1", "s2"])
    out, merged, plot = tmp_path / "poses.conf", tmp_path / "merged.ply", tmp_path / "scans.png"
    rc = register_scans.main([str(folder), "--out-poses", str(out), "--out-merged", str(merged), "--plot", str(plot),
                              "--html", str(tmp_path / "scans.html")])
    assert rc == 0, capsys.readouterr().err
    got = scan_poses.read_poses(str(out))
    assert list(got) == ["s0", "s1", "s2"] and out.read_text().startswith("bmesh s0.npy 0 0 0 0 0 0 1")
    truth = np.linalg.inv(poses[0]) @ poses
    for name, want in zip(got, truth):
        assert rotation_error_deg(got[name][:3, :3], want[:3, :3]) < 1.0  # align_scans measured 0.0006° here
    points, _ = cloud_io.read_cloud(str(merged))
    assert "property double x" in merged.read_bytes()[:300].decode("ascii", "replace")  # float64
    want = np.concatenate([c @ t[:3, :3].T + t[:3, 3] for c, t in zip(clouds, truth)])
    # 1% of the ~0.2 shape: what 1° of rotation error moves its points by
    assert points.shape == want.shape and np.sqrt(np.mean(np.sum((points - want) ** 2, axis=1))) < 2e-3
    assert plot.stat().st_size > 0 and len(paths) == 3
    page = (tmp_path / "scans.html").read_text(encoding="utf-8")
    assert all(f'"name": "s{i}.npy"' in page for i in range(3)) and "<th>scans placed</th><td>3 of 3</td>" in page


def test_console_entry_point_starts():
    import subprocess
    import sys
    out = subprocess.run([sys.executable, "-c", "from rpmnet_jax.cli.register_scans import entry; entry()", "--help"],
                         capture_output=True, text=True, env=dict(os.environ, RPMNET_COMPILATION_CACHE="off"))
    assert out.returncode == 0 and "usage:" in out.stdout, out.stderr[-2000:]


@pytest.mark.slow
def test_cli_leaves_out_a_scan_that_overlaps_nothing(tmp_path, capsys):
    """Three bunny scans and a synthetic box: the box is reported and left out; the rest is written."""
    from rpmnet_jax.data import synthetic

    require(BUNNY / "bun.conf", "Stanford bunny scans")
    bunny = scan_poses.read_poses(str(BUNNY / "bun.conf"))
    names = ["bun000", "bun045", "bun315"]
    clouds = [sampling.voxel_downsample(cloud_io.read_cloud(str(BUNNY / f"{n}.ply"))[0], None, 0.002)[0]
              for n in names]
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


def test_e57_with_three_scans_registers_as_three_files(tmp_path, capsys):
    """One E57 file holding the three scans, each with a stored pose a few degrees off: the same relative poses as
    three separate files give, written in the file's frame (the first scan keeps its stored pose)."""
    pytest.importorskip("pye57")
    from scipy.spatial.transform import Rotation

    from rpmnet_jax.io import columns, e57

    clouds, poses = synthetic_scans()
    paths = _write_scans(tmp_path, clouds, ["s0", "s1", "s2"])
    rc = register_scans.main(paths + ["--out-poses", str(tmp_path / "files.conf")])
    assert rc == 0, capsys.readouterr().err
    from_files = scan_poses.read_poses(str(tmp_path / "files.conf"))
    nudge = np.eye(4)
    nudge[:3, :3] = Rotation.from_euler("xyz", [2, -3, 1], degrees=True).as_matrix()
    nudge[:3, 3] = [0.004, -0.002, 0.003]
    stored = [p @ nudge if k else p for k, p in enumerate(poses)]  # a starting guess, not the answer
    e57.write(str(tmp_path / "scans.e57"), [e57.Scan(columns.Cloud(c), None, p) for c, p in zip(clouds, stored)])
    merged = tmp_path / "merged.ply"
    rc = register_scans.main([str(tmp_path / "scans.e57"), "--out-poses", str(tmp_path / "e57.conf"), "--out-merged",
                              str(merged)])
    out = capsys.readouterr().out
    assert rc == 0 and "3 of 3 scans have stored poses" in out
    from_e57 = scan_poses.read_poses(str(tmp_path / "e57.conf"))
    assert list(from_e57) == ["scans.e57#0", "scans.e57#1", "scans.e57#2"]
    first = from_e57["scans.e57#0"]
    np.testing.assert_allclose(first, poses[0], atol=1e-8)  # the first scan stays where its pose put it
    for k in (1, 2):
        relative = np.linalg.inv(first) @ from_e57[f"scans.e57#{k}"]
        want = from_files[f"s{k}"]
        assert rotation_error_deg(relative[:3, :3], want[:3, :3]) < 0.05
        assert np.abs(relative[:3, 3] - want[:3, 3]).max() < 2e-4  # the shape is ~0.2 across
    assert len(cloud_io.read(str(merged)).points) == sum(len(c) for c in clouds)


def test_scanner_files_with_bad_input_exit_2_and_write_nothing(tmp_path, capsys):
    laspy = pytest.importorskip("laspy")
    pytest.importorskip("pye57")
    from rpmnet_jax.io import columns, e57

    a = np.random.default_rng(0).normal(size=(300, 3))
    cloud_io.write_cloud(str(tmp_path / "a.xyz"), a)
    laspy.LasData(laspy.LasHeader(point_format=6, version="1.4")).write(str(tmp_path / "empty.las"))
    e57.write(str(tmp_path / "one.e57"), [columns.Cloud(a)])
    np.savetxt(tmp_path / "rgb.txt", np.c_[a, np.full((300, 3), 9.0)])
    cases = {
        "no points": [str(tmp_path / "a.xyz"), str(tmp_path / "empty.las")],
        "at least two": [str(tmp_path / "one.e57")],
        "--columns applies to": [str(tmp_path / "a.xyz"), str(tmp_path / "one.e57"), "--columns", "x,y,z"],
        "unknown column name": [str(tmp_path / "a.xyz"), str(tmp_path / "a.xyz"), "--columns", "x,y,w"],
        "not unit normals": [str(tmp_path / "a.xyz"), str(tmp_path / "rgb.txt")],
    }
    _assert_refused(tmp_path, capsys, cases)


def test_bad_scheduler_or_cache_exits_2_and_writes_nothing(tmp_path, capsys):
    clouds, _ = synthetic_scans()
    paths = _write_scans(tmp_path, clouds, ["s0", "s1", "s2"])
    out = tmp_path / "poses.conf"
    (tmp_path / "file").write_text("x")
    cases = {"--scheduler must be": ["--scheduler", "cluster"], "got '0'": ["--scheduler", "0"],
             "is a file": ["--cache", str(tmp_path / "file")],
             "does not exist": ["--cache", str(tmp_path / "no" / "cache")]}
    for message, flags in cases.items():
        rc = register_scans.main(paths + ["--out-poses", str(out), "--cache", str(tmp_path / "c")] + flags)
        err = capsys.readouterr().err
        assert rc == 2 and message in err and len(err.strip().splitlines()) == 1, (message, err)
        assert not out.exists() and not (tmp_path / "c").exists() and not (tmp_path / "no").exists()


@pytest.mark.slow  # waits for the connection timeout (20 s)
def test_a_scheduler_that_does_not_answer_exits_2_and_writes_nothing(tmp_path, capsys):
    pytest.importorskip("distributed")
    clouds, _ = synthetic_scans()
    paths = _write_scans(tmp_path, clouds, ["s0", "s1", "s2"])
    out = tmp_path / "poses.conf"
    with socket.socket() as s:  # a port nothing listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    rc = register_scans.main(paths + ["--out-poses", str(out), "--scheduler", f"tcp://127.0.0.1:{port}"])
    err = capsys.readouterr().err
    assert rc == 2 and "no Dask scheduler answers" in err and len(err.strip().splitlines()) == 1, err
    assert not out.exists()


_CLI = [sys.executable, "-c", "from rpmnet_jax.cli.register_scans import entry; entry()"]


@pytest.mark.slow  # three runs of the CLI in their own processes
def test_a_sigkilled_run_resumes_from_its_cache_with_the_same_poses(tmp_path, random_weights):
    clouds, _ = ring_scans(6)
    paths = _write_scans(tmp_path, clouds, [f"scan{k}" for k in range(6)])
    cache = tmp_path / "cache"
    command = _CLI + paths + ["--checkpoint", random_weights, "--cache", str(cache), "--refine", "icp"]
    run = subprocess.Popen(command + ["--out-poses", str(tmp_path / "killed.conf")], stdout=subprocess.PIPE,
                           stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 600
    while time.time() < deadline and not (cache.is_dir() and any(f.startswith("refine0-")
                                                                  for f in os.listdir(cache))):
        assert run.poll() is None, run.communicate()[1][-2000:]
        time.sleep(0.01)
    run.send_signal(signal.SIGKILL)  # in the first refinement round: the pair edges are all on disk
    assert run.wait(timeout=30) == -signal.SIGKILL
    assert not (tmp_path / "killed.conf").exists()  # killed mid-run
    finished = {f: os.stat(cache / f).st_mtime_ns for f in os.listdir(cache) if f.endswith(".npz")}

    resumed = subprocess.run(command + ["--out-poses", str(tmp_path / "resumed.conf")], capture_output=True,
                             text=True, timeout=600)
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    reused, written = map(int, re.search(r"(\d+) pair results reused, (\d+) computed", resumed.stdout).groups())
    print(f"killed with {len(finished)} pair results on disk; resumed: {reused} reused, {written} computed")
    assert reused == len(finished) and written > 0  # none of the finished pairs computed again
    assert len([f for f in os.listdir(cache) if f.endswith(".npz")]) == reused + written
    assert all(os.stat(cache / f).st_mtime_ns == t for f, t in finished.items())

    fresh = subprocess.run(_CLI + paths + ["--checkpoint", random_weights, "--out-poses", str(tmp_path / "fresh.conf"),
                                           "--refine", "icp", "--scheduler", "2"],  # from scratch, on two workers
                           capture_output=True, text=True, timeout=600)
    assert fresh.returncode == 0, fresh.stderr[-2000:]
    a, b = scan_poses.read_poses(str(tmp_path / "resumed.conf")), scan_poses.read_poses(str(tmp_path / "fresh.conf"))
    assert sorted(a) == sorted(b) and len(a) == 6
    for name in a:
        assert rotation_error_deg(a[name][:3, :3], b[name][:3, :3]) < 0.01
        np.testing.assert_allclose(a[name][:3, 3], b[name][:3, 3], atol=1e-6)


def test_a_stored_e57_pose_is_where_its_scanner_stood():
    """Scans moved into an E57 file's frame by their stored poses have their sensors at the poses' origins; a PCD's
    VIEWPOINT is its sensor; the others follow ``--viewpoints``."""
    from rpmnet_jax.io import columns

    pose = np.eye(4)
    pose[:3, 3] = [512_000.0, 4_100_000.0, 120.0]
    plain, seen = columns.Cloud(np.zeros((3, 3))), columns.Cloud(np.zeros((3, 3)), viewpoint=np.array([1.0, 2.0, 3.0]))
    found = register_scans._viewpoints(register_scans._Scans(["a", "b", "c", "d"], [plain, plain, seen, plain],
                                                             [None, pose, None, np.eye(4)], []), "origin")
    assert found[0] == "origin" and found[1].tolist() == [512_000.0, 4_100_000.0, 120.0]
    assert found[2].tolist() == [1.0, 2.0, 3.0]
    assert found[3].tolist() == [0.0, 0.0, 0.0]  # a stored identity pose is a pose: the scanner at the origin


def test_the_page_banner_names_doubtful_scans_and_edges_and_those_left_out():
    """``--html``'s banner: the scans resting on a likely wrong registration, the kept edges at or above the edge
    doubt model's threshold (not those below), and the scans left out, by name."""
    import types

    from rpmnet_jax.multiway import edge_doubt
    from rpmnet_jax.pair_edges import edges

    bar = edge_doubt.load().threshold
    edge = lambda i, j, p: edges.Edge(i, j, np.eye(4), 0.9, 0.01, np.eye(6), 0.001, "classical", p)
    result = types.SimpleNamespace(likely_wrong=(1,), left_out=(3,), edges=[edge(0, 1, bar), edge(0, 2, 0.99 * bar)])
    banner = " ".join(register_scans._alerts(result, ["a.ply", "b.ply", "c.ply", "d.ply"]))
    assert "b.ply" in banner and "a.ply → b.ply" in banner and "d.ply" in banner and "c.ply" not in banner
    assert register_scans._alerts(types.SimpleNamespace(likely_wrong=(), left_out=(), edges=[edge(0, 1, 0.0)]),
                                  ["a.ply", "b.ply"]) == []
