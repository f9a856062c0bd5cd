"""Stanford ``.conf`` scan poses: the convention (checked against the real bunny's ``bun.conf`` and its
reconstruction, and against conf lines written by hand), relative motions, and round trips of written files."""

import numpy as np
import pytest
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from conftest import DATA, random_pose, require
from rpmnet_jax.io import clouds as cloud_io
from rpmnet_jax.io import poses as scan_poses

BUNNY = DATA / "stanford_bunny"


@pytest.fixture(scope="module")
def bunny():
    require(BUNNY / "bun.conf", "Stanford bunny scans")
    mesh, _ = cloud_io.read_cloud(str(BUNNY / "bun_zipper_res2.ply"))
    return scan_poses.read_poses(str(BUNNY / "bun.conf")), cKDTree(mesh)


@pytest.mark.parametrize("name", ["bun045", "bun090", "bun315"])
def test_posed_scans_lie_on_the_reconstruction(bunny, name):
    poses, mesh = bunny
    points, _ = cloud_io.read_cloud(str(BUNNY / f"{name}.ply"))
    pose = poses[name]
    dist, _ = mesh.query(points @ pose[:3, :3].T + pose[:3, 3])
    assert np.mean(dist < 0.002) > 0.98  # within 2 mm of a vertex of the 8k-vertex reconstruction
    # the other reading of the quaternion (R instead of R^T) puts most of the scan off the surface
    dist_t, _ = mesh.query(points @ pose[:3, :3] + pose[:3, 3])
    assert np.mean(dist_t < 0.002) < 0.2


def test_relative_motion_maps_one_scan_onto_the_other(bunny):
    poses, mesh = bunny
    src, _ = cloud_io.read_cloud(str(BUNNY / "bun045.ply"))
    motion = scan_poses.relative_motion(poses, "bun045", "bun000")
    moved = src @ motion[:3, :3].T + motion[:3, 3]  # in bun000's frame
    world = moved @ poses["bun000"][:3, :3].T + poses["bun000"][:3, 3]
    dist, _ = mesh.query(world)
    assert np.mean(dist < 0.002) > 0.98


def _conf_line(name, pose):
    """A ``bmesh`` line written by the file's own definition: world points are ``p @ R + t``, ``R`` the
    quaternion's matrix (so ``R = pose_rotationᵀ``); SciPy's quaternions are ``(x, y, z, w)`` as the file's."""
    q = Rotation.from_matrix(pose[:3, :3].T).as_quat()
    return f"bmesh {name}.ply " + " ".join(repr(float(v)) for v in (*pose[:3, 3], *q)) + "\n"


def test_read_poses_of_hand_written_lines(tmp_path):
    """Other lines (``camera``, blank) are skipped, names lose their extension; a file without ``bmesh`` lines
    is an error."""
    rng = np.random.default_rng(0)
    poses = {"a": random_pose(rng), "b": random_pose(rng)}
    conf = tmp_path / "scans.conf"
    conf.write_text("camera 0 0 0 0 0 0 1\n\n" + "".join(_conf_line(n, p) for n, p in poses.items()))
    got = scan_poses.read_poses(str(conf))
    assert list(got) == ["a", "b"]
    for name, pose in poses.items():
        np.testing.assert_allclose(got[name], pose, atol=1e-12)  # float64 repr in the file: round-off only
    (tmp_path / "none.conf").write_text("camera 0 0 0 0 0 0 1\n")
    with pytest.raises(ValueError, match="no 'bmesh' lines"):
        scan_poses.read_poses(str(tmp_path / "none.conf"))


def test_relative_motion_takes_one_scan_s_points_to_the_other_s():
    """Two scans of the same world points, each in its own frame: the relative motion maps scan a's points
    exactly onto scan b's."""
    rng = np.random.default_rng(1)
    world = rng.normal(size=(50, 3))
    poses = {"a": random_pose(rng), "b": random_pose(rng)}  # scan → world
    local = {n: (world - p[:3, 3]) @ p[:3, :3] for n, p in poses.items()}
    motion = scan_poses.relative_motion(poses, "a", "b")
    np.testing.assert_allclose(local["a"] @ motion[:3, :3].T + motion[:3, 3], local["b"], atol=1e-12)


def test_conf_files_round_trip(tmp_path):
    rng = np.random.default_rng(0)
    poses = np.stack([np.eye(4)] + [random_pose(rng) for _ in range(3)])
    names = ["a.ply", "b.ply", "site 2 station 7.pcd", "d.xyz"]  # a name with spaces reads back whole
    scan_poses.write_poses(str(tmp_path / "p.conf"), names, poses)
    got = scan_poses.read_poses(str(tmp_path / "p.conf"))
    assert list(got) == ["a", "b", "site 2 station 7", "d"]
    np.testing.assert_allclose(np.stack(list(got.values())), poses, atol=1e-8)  # 10 significant digits written
    if (BUNNY / "bun.conf").is_file():  # bun.conf's own convention survives a write
        true = scan_poses.read_poses(str(BUNNY / "bun.conf"))
        scan_poses.write_poses(str(tmp_path / "bun.conf"), [f"{n}.ply" for n in true], np.stack(list(true.values())))
        again = scan_poses.read_poses(str(tmp_path / "bun.conf"))
        np.testing.assert_allclose(np.stack(list(again.values())), np.stack(list(true.values())), atol=1e-8)


def test_conf_names_with_spaces_quotes_and_tabs_round_trip(tmp_path):
    """A name that holds whitespace, ``"`` or ``\\`` is written quoted and reads back as it was (runs of spaces, a
    leading space, a tab); plain names are written as the Stanford files have them; an unquoted name with spaces, as
    a hand-written file may have, reads as everything before the seven numbers."""
    rng = np.random.default_rng(2)
    names = ["site  2  station 7.pcd", " lead.ply", 'say "hi".xyz', "tab\there.ply", "back\\slash.ply", "café 1.las",
             "bun000.ply", "scans.e57#2"]
    poses = np.stack([random_pose(rng) for _ in names])
    scan_poses.write_poses(str(tmp_path / "p.conf"), names, poses)
    lines = (tmp_path / "p.conf").read_text(encoding="utf-8").splitlines()
    assert len(lines) == len(names) and lines[0].startswith('bmesh "site  2  station 7.pcd" ')
    assert lines[-2].startswith("bmesh bun000.ply ") and lines[-1].startswith("bmesh scans.e57#2 ")
    got = scan_poses.read_poses(str(tmp_path / "p.conf"))
    assert list(got) == ["site  2  station 7", " lead", 'say "hi"', "tab\there", "back\\slash", "café 1", "bun000",
                         "scans.e57#2"]
    np.testing.assert_allclose(np.stack(list(got.values())), poses, atol=1e-12)
    (tmp_path / "hand.conf").write_text("camera 0 0 0 0 0 0 1\n" + _conf_line("site 2\tstation 7", poses[0]))
    assert list(scan_poses.read_poses(str(tmp_path / "hand.conf"))) == ["site 2\tstation 7"]
