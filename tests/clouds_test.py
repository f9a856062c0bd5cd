"""Point-cloud and transform files: every format round-trips float64 exactly (LAS within its scale), with colours,
intensity and NaN rows; ASCII PCD and PLY read; bad files are one-line ``CloudError`` s."""

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rpmnet_jax.data import synthetic
from rpmnet_jax.io import clouds as cloud_io


def _shape(seed=0, n=200, label=36):
    pts = synthetic.sample_shape(np.random.default_rng(seed), label, n)
    return pts[:, :3].astype(np.float64), pts[:, 3:].astype(np.float64)


@pytest.mark.parametrize("ext", [".ply", ".pcd", ".xyz", ".txt", ".csv", ".npy", ".npz"])
@pytest.mark.parametrize("with_normals", [True, False])
def test_cloud_files_round_trip(tmp_path, ext, with_normals):
    pts, nrm = _shape()
    pts = pts * 100 + 7
    path = str(tmp_path / f"cloud{ext}")
    cloud_io.write_cloud(path, pts, nrm if with_normals else None)
    got, got_n = cloud_io.read_cloud(path)
    np.testing.assert_array_equal(got, pts)  # float64 (text: 17 digits) reads back exactly
    if with_normals:
        np.testing.assert_array_equal(got_n, nrm)
    else:
        assert got_n is None


@pytest.mark.parametrize("ext", [".ply", ".pcd", ".xyz", ".txt", ".csv", ".npy", ".npz", ".las", ".laz", ".e57"])
@pytest.mark.parametrize("colour_max", [255, 65535])
def test_colours_intensity_and_nan_rows_round_trip(tmp_path, ext, colour_max):
    if ext in (".las", ".laz", ".e57"):
        pytest.importorskip("laspy" if ext != ".e57" else "pye57")
    pts, nrm = _shape()
    pts = pts * 100 + 7
    pts[3] = np.nan
    rng = np.random.default_rng(4)
    rgb, intensity = rng.integers(0, colour_max + 1, (len(pts), 3)).astype(np.float64), rng.normal(size=len(pts))
    path = str(tmp_path / f"cloud{ext}")
    cloud_io.write_cloud(path, pts, nrm, rgb, intensity)
    got = cloud_io.read(path)
    assert got.points.shape == pts.shape and np.isnan(got.points[3]).all()
    keep = np.arange(len(pts)) != 3
    np.testing.assert_allclose(got.points[keep], pts[keep], rtol=0, atol=1e-6 if ext in (".las", ".laz") else 0)
    np.testing.assert_array_equal(got.colours, rgb)
    np.testing.assert_array_equal(got.intensity, intensity)
    if ext == ".e57":
        assert got.normals is None  # E57's core standard has no normals
    else:
        np.testing.assert_array_equal(got.normals, nrm)


def test_ascii_pcd_and_ascii_ply(tmp_path):
    pts, _ = _shape(n=50)
    pcd = tmp_path / "a.pcd"
    pcd.write_text("# .PCD v0.7\nVERSION 0.7\nFIELDS x y z rgb\nSIZE 4 4 4 4\nTYPE F F F F\nCOUNT 1 1 1 1\n"
                   f"WIDTH {len(pts)}\nHEIGHT 1\nPOINTS {len(pts)}\nDATA ascii\n"
                   + "\n".join(f"{x} {y} {z} 0" for x, y, z in pts))
    np.testing.assert_allclose(cloud_io.read_cloud(str(pcd))[0], pts, atol=1e-6)  # float64 text: exact; a SIZE 4
    # (float32) field may be read at float32 precision, 6e-8 on these unit-sized points
    from plyfile import PlyData, PlyElement
    table = np.array([tuple(p) for p in pts], dtype=[("x", "f4"), ("y", "f4"), ("z", "f4")])
    PlyData([PlyElement.describe(table, "vertex")], text=True).write(str(tmp_path / "a.ply"))
    # float32 file of unit-sized points: 6e-8 rounding
    np.testing.assert_allclose(cloud_io.read_cloud(str(tmp_path / "a.ply"))[0], pts, atol=1e-6)


def test_transform_files_parse_back(tmp_path):
    t = np.eye(4)
    t[:3, :3] = Rotation.from_euler("xyz", [10, -20, 30], degrees=True).as_matrix()
    t[:3, 3] = [1.5, -2, 4.1e6 + 1 / 3]  # a georeferenced translation
    for name in ("t.txt", "t.json"):
        cloud_io.write_transform(str(tmp_path / name), t)
        np.testing.assert_array_equal(cloud_io.read_transform(str(tmp_path / name)), t)
    np.testing.assert_array_equal(np.loadtxt(tmp_path / "t.txt"), t)


def test_candidates_file_holds_every_answer_exactly(tmp_path):
    from rpmnet_jax.pairwise.alignment import Answer

    t = np.eye(4)
    t[:3, 3] = [1 / 3, 2e6, -7.25]
    answers = [Answer(t, 0.9, 0.95, 0.01, "classical", ("classical", "local")),
               Answer(np.eye(4), 0.5, 0.6, 0.02, "local")]
    info = np.diag(np.arange(1.0, 7.0)) / 3
    cloud_io.write_candidates(str(tmp_path / "c.json"), answers, info, seed=3)
    got = json.loads((tmp_path / "c.json").read_text())
    assert [c["init"] for c in got["candidates"]] == ["classical", "local"] and got["seed"] == 3
    assert [c["support"] for c in got["candidates"]] == [["classical", "local"], []]
    np.testing.assert_array_equal(got["candidates"][0]["transform"], t)
    np.testing.assert_array_equal(got["information"], info)
    assert got["candidates"][1]["score"] == 0.5 and got["candidates"][1]["inlier_rmse"] == 0.02


@pytest.mark.parametrize("case,message", [("unknown_ext", "unknown point-cloud format"),
                                          ("missing", "no such file or folder"),
                                          ("missing_folder", "no such file or folder"),
                                          ("folder", "is a folder"), ("folder_no_ext", "is a folder"),
                                          ("empty", "empty"),
                                          ("columns", "ambiguous"), ("garbage", "cannot read as PLY"),
                                          ("npz_names", "needs a 'points' array"),
                                          ("columns_on_las", "--columns applies to"), ("bad_column", "unknown column")])
def test_bad_files_are_one_line_cloud_errors(tmp_path, case, message):
    path = {
        "unknown_ext": lambda: tmp_path / "cloud.obj",
        "missing": lambda: tmp_path / "nope.ply",
        "missing_folder": lambda: tmp_path / "scans",
        "folder": lambda: (tmp_path / "dir.ply").mkdir() or tmp_path / "dir.ply",
        "folder_no_ext": lambda: (tmp_path / "scans").mkdir() or tmp_path / "scans",
        "empty": lambda: np.save(tmp_path / "e.npy", np.zeros((0, 3))) or tmp_path / "e.npy",
        "columns": lambda: np.save(tmp_path / "c.npy", np.zeros((5, 5))) or tmp_path / "c.npy",
        "garbage": lambda: (tmp_path / "g.ply").write_bytes(b"not a ply") and tmp_path / "g.ply",
        "npz_names": lambda: np.savez(tmp_path / "n.npz", a=np.zeros((5, 3)), b=np.zeros((5, 3))) or tmp_path / "n.npz",
        "columns_on_las": lambda: tmp_path / "c.las",
        "bad_column": lambda: np.save(tmp_path / "b.npy", np.zeros((5, 3))) or tmp_path / "b.npy",
    }[case]()
    columns = {"columns_on_las": "x,y,z", "bad_column": "x,y,zed"}.get(case)
    if case == "columns_on_las":
        pytest.importorskip("laspy")
        cloud_io.write_cloud(str(path), np.zeros((5, 3)))
    with pytest.raises(cloud_io.CloudError, match=message) as info:
        cloud_io.read_cloud(str(path), columns=columns)
    assert isinstance(info.value, ValueError) and "\n" not in str(info.value)


def test_check_format_names_the_extension(tmp_path):
    assert cloud_io.check_format("a/B.PLY") == ".ply"
    with pytest.raises(cloud_io.CloudError, match="'.obj'"):
        cloud_io.check_format("mesh.obj")
    (tmp_path / "cloud").write_text("1 2 3\n")
    with pytest.raises(cloud_io.CloudError, match="none"):  # a file without an extension
        cloud_io.check_format(str(tmp_path / "cloud"))
    with pytest.raises(cloud_io.CloudError, match="none"):  # an output's name: whether it exists is no matter
        cloud_io.check_format(str(tmp_path / "merged"))
