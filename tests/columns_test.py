"""Columns by name, not by count: file names (PLY, PCD, text headers, structured NPY) decide what is xyz, normals,
colour and intensity; headerless tables by count only where unambiguous; ``columns=`` names them by position;
every bad case is a one-line CloudError."""

import numpy as np
import pytest

from rpmnet_jax.io import clouds as cloud_io
from rpmnet_jax.io import columns


def _xyzrgb(n=40, seed=0):
    rng = np.random.default_rng(seed)
    return rng.normal(size=(n, 3)) * 10 + 1e3, rng.integers(0, 256, (n, 3)).astype(np.float64)


def _one_line_error(match, fn, *args, **kwargs):
    with pytest.raises(cloud_io.CloudError, match=match) as info:
        fn(*args, **kwargs)
    assert "\n" not in str(info.value)
    return str(info.value)


def test_parse_names_and_aliases():
    assert columns.parse("x,y,z,red,G,b,_,intensity") == ["x", "y", "z", "r", "g", "b", None, "intensity"]
    assert columns.parse(["x", "y", "z", "nx", "ny", "nz"]) == ["x", "y", "z", "nx", "ny", "nz"]
    _one_line_error("unknown column name 'w'", columns.parse, "x,y,z,w")


@pytest.mark.parametrize("header,delimiter", [("//X Y Z R G B", " "), ("x,y,z,r,g,b", ","),
                                              ("# x y z red green blue", " "), ("X Y Z Red Green Blue", " ")])
def test_text_header_names_the_columns(tmp_path, header, delimiter):
    pts, rgb = _xyzrgb()
    path = tmp_path / "c.txt"
    np.savetxt(path, np.concatenate([pts, rgb], 1), fmt="%.17g", delimiter=delimiter, header=header, comments="")
    cloud = cloud_io.read(str(path))
    np.testing.assert_array_equal(cloud.points, pts)
    np.testing.assert_array_equal(cloud.colours, rgb)
    assert cloud.normals is None and cloud.intensity is None


def test_text_header_skips_unknown_names_and_reads_intensity(tmp_path):
    pts, _ = _xyzrgb()
    inten = np.arange(len(pts), dtype=np.float64)
    path = tmp_path / "c.csv"
    np.savetxt(path, np.c_[inten, pts, inten * 2], fmt="%.17g", delimiter=",", header="Label,X,Y,Z,Intensity",
               comments="")
    cloud = cloud_io.read(str(path))
    np.testing.assert_array_equal(cloud.points, pts)
    np.testing.assert_array_equal(cloud.intensity, inten * 2)


def test_headerless_tables_by_count(tmp_path):
    pts, rgb = _xyzrgb()
    nrm = np.random.default_rng(1).normal(size=pts.shape)
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    np.savetxt(tmp_path / "i.xyz", np.c_[pts, np.arange(len(pts))], fmt="%.17g")
    cloud = cloud_io.read(str(tmp_path / "i.xyz"))  # 4 columns: x y z intensity
    np.testing.assert_array_equal(cloud.intensity, np.arange(len(pts)))
    np.save(tmp_path / "n.npy", np.c_[pts, nrm])
    np.testing.assert_array_equal(cloud_io.read(str(tmp_path / "n.npy")).normals, nrm)  # unit: normals, as before
    np.savetxt(tmp_path / "rgb.xyz", np.c_[pts, rgb], fmt="%.17g")
    message = _one_line_error("not unit normals", cloud_io.read, str(tmp_path / "rgb.xyz"))
    assert "--columns" in message
    np.save(tmp_path / "seven.npy", np.c_[pts, rgb, rgb[:, :1]])
    _one_line_error("ambiguous.*--columns", cloud_io.read, str(tmp_path / "seven.npy"))


def test_columns_keyword_names_by_position(tmp_path):
    pts, rgb = _xyzrgb()
    np.savetxt(tmp_path / "rgb.xyz", np.c_[pts, rgb, rgb[:, 0]], fmt="%.17g")
    cloud = cloud_io.read(str(tmp_path / "rgb.xyz"), columns="x,y,z,r,g,b,_")
    np.testing.assert_array_equal(cloud.colours, rgb)
    assert cloud.intensity is None
    points, normals = cloud_io.read_cloud(str(tmp_path / "rgb.xyz"), columns="_,_,_,x,y,z,intensity")
    np.testing.assert_array_equal(points, rgb)
    assert normals is None


@pytest.mark.parametrize("spec,match", [("x,y,z", "names 3 columns, the file has 7"), ("x,y,z,r,g,b,q", "unknown"),
                                        ("x,y,z,r,g,_,_", "colours need all of r g b"),
                                        ("x,x,z,r,g,b,_", "'x' is named twice"), ("_,_,_,r,g,b,_", "no x y z")])
def test_bad_columns_are_one_line_errors(tmp_path, spec, match):
    pts, rgb = _xyzrgb()
    np.savetxt(tmp_path / "rgb.txt", np.c_[pts, rgb, rgb[:, 0]], fmt="%.17g")
    _one_line_error(match, cloud_io.read, str(tmp_path / "rgb.txt"), columns=spec)


def test_ply_and_pcd_names(tmp_path):
    from plyfile import PlyData, PlyElement

    pts, rgb = _xyzrgb()
    table = np.empty(len(pts), dtype=[("x", "f8"), ("y", "f8"), ("z", "f8"), ("scalar_Intensity", "f4"),
                                      ("diffuse_red", "u1"), ("diffuse_green", "u1"), ("diffuse_blue", "u1")])
    for k, n in enumerate("xyz"):
        table[n] = pts[:, k]
    table["scalar_Intensity"] = np.arange(len(pts)) / 4
    for k, n in enumerate(("diffuse_red", "diffuse_green", "diffuse_blue")):
        table[n] = rgb[:, k]
    PlyData([PlyElement.describe(table, "vertex")]).write(str(tmp_path / "c.ply"))
    cloud = cloud_io.read(str(tmp_path / "c.ply"))
    np.testing.assert_array_equal(cloud.colours, rgb)
    np.testing.assert_array_equal(cloud.intensity, np.arange(len(pts)) / 4)
    # PCL's packed rgb (a float32 holding 0x00RRGGBB), ASCII
    packed = ((rgb[:, 0].astype(np.uint32) << 16) | (rgb[:, 1].astype(np.uint32) << 8) | rgb[:, 2].astype(np.uint32))
    as_float = packed.view(np.float32)
    (tmp_path / "c.pcd").write_text(
        "VERSION 0.7\nFIELDS x y z rgb\nSIZE 8 8 8 4\nTYPE F F F F\nCOUNT 1 1 1 1\n"
        f"WIDTH {len(pts)}\nHEIGHT 1\nPOINTS {len(pts)}\nDATA ascii\n"
        + "\n".join(f"{x:.17g} {y:.17g} {z:.17g} {c:.9g}" for (x, y, z), c in zip(pts, as_float)))
    cloud = cloud_io.read(str(tmp_path / "c.pcd"))
    np.testing.assert_array_equal(cloud.points, pts)
    np.testing.assert_array_equal(cloud.colours, rgb)


def test_cloud_moved_and_rows():
    pts, rgb = _xyzrgb(5)
    cloud = columns.Cloud(pts, np.tile([0.0, 0.0, 1.0], (5, 1)), rgb, np.arange(5.0))
    t = np.eye(4)
    t[:3, :3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]
    t[:3, 3] = [1, 2, 3]
    moved = cloud.moved(t)
    np.testing.assert_allclose(moved.points, pts @ t[:3, :3].T + t[:3, 3])
    assert moved.colours is rgb and moved.intensity is cloud.intensity
    assert cloud.rows(np.array([True, False, True, False, False])).intensity.tolist() == [0.0, 2.0]


def test_integer_type():
    assert columns.integer_type(np.array([0.0, 255.0])) == "u1"
    assert columns.integer_type(np.array([0.0, 256.0])) == "u2"
    assert columns.integer_type(np.array([0.5])) == "f8"
    assert columns.integer_type(np.array([70000.0])) == "f8"
