"""The PLY vertex reader: the same table as plyfile, bit for bit, on every layout it reads itself; plyfile for the
rest; a damaged file is a one-line CloudError, never anything else."""

import numpy as np
import pytest
from plyfile import PlyData, PlyElement

from conftest import DATA, require

from rpmnet_jax.io import clouds as cloud_io
from rpmnet_jax.io import ply


def _vertices(n=50, seed=0):
    rng = np.random.default_rng(seed)
    table = np.empty(n, dtype=[("x", "f4"), ("y", "f4"), ("z", "f8"), ("nx", "f4"), ("ny", "f4"), ("nz", "f4"),
                               ("red", "u1"), ("intensity", "i2")])
    for name in table.dtype.names:
        table[name] = rng.normal(size=n) * (100 if name in "xyz" else 1) if table.dtype[name].kind == "f" else \
            rng.integers(0, 100, n)
    return table


def _faces(n=7):
    return np.array([([0, 1, 2],)] * n, dtype=[("vertex_indices", "i4", (3,))])


def _write(path, vertices, *, text, byte_order="<", faces_first=False):
    elements = [PlyElement.describe(vertices, "vertex"), PlyElement.describe(_faces(), "face")]
    PlyData(elements[::-1] if faces_first else elements, text=text, byte_order=byte_order).write(str(path))
    return str(path)


@pytest.mark.parametrize("text,byte_order", [(True, "<"), (False, "<"), (False, ">")])
@pytest.mark.parametrize("faces_first", [False, True])  # True: not the fast layout, plyfile reads it
def test_vertices_equal_plyfiles(tmp_path, text, byte_order, faces_first):
    vertices = _vertices()
    path = _write(tmp_path / "v.ply", vertices, text=text, byte_order=byte_order, faces_first=faces_first)
    got, expected = ply.read_vertices(path), PlyData.read(path)["vertex"].data
    assert got.dtype.names == expected.dtype.names
    for name in expected.dtype.names:
        assert got[name].dtype.kind == expected[name].dtype.kind
        np.testing.assert_array_equal(got[name], expected[name])
    points, normals = cloud_io.read_cloud(path)
    assert points.dtype == np.float64 and normals.shape == (50, 3)
    np.testing.assert_array_equal(points[:, 2], vertices["z"])  # a double property keeps every bit


def test_header_is_read_as_written(tmp_path):
    path = _write(tmp_path / "v.ply", _vertices(5), text=True)
    with open(path, "rb") as f:
        header = ply.read_header(f)
        assert f.tell() == header.size
    assert header.format == "ascii" and [e.name for e in header.elements] == ["vertex", "face"]
    assert header.elements[0].count == 5 and header.elements[1].properties == [("vertex_indices", "list")]


@pytest.mark.parametrize("text", [True, False])
def test_a_short_vertex_table_is_one_line_error(tmp_path, text):
    path = _write(tmp_path / "v.ply", _vertices(), text=text)
    data = open(path, "rb").read()
    body = data.index(b"end_header\n") + len(b"end_header\n")
    end = body + (sum(len(line) + 1 for line in data[body:].split(b"\n")[:3]) if text else 100)  # 3 whole rows
    (tmp_path / "cut.ply").write_bytes(data[:end])
    with pytest.raises(cloud_io.CloudError, match="declares 50 vertices") as info:
        cloud_io.read_cloud(str(tmp_path / "cut.ply"))
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("text", [True, False])
def test_damaged_files_give_one_line_errors_or_a_cloud(tmp_path, text):
    """200 seeded damages (a byte overwritten, a cut, a byte dropped) of an ASCII and a binary file: every one is
    read (an (N, 3) float64 cloud) or refused with a one-line CloudError, nothing else escapes."""
    data = open(_write(tmp_path / "v.ply", _vertices(20), text=text), "rb").read()
    rng = np.random.default_rng(1)
    outcomes = set()
    for k in range(200):
        damaged = bytearray(data)
        where = int(rng.integers(len(damaged)))
        kind = k % 3
        if kind == 0:
            damaged[where] = int(rng.integers(256))
        elif kind == 1:
            damaged = damaged[:where]
        else:
            del damaged[where]
        path = tmp_path / f"d{k}.ply"
        path.write_bytes(bytes(damaged))
        try:
            points, _ = cloud_io.read_cloud(str(path))
            assert points.ndim == 2 and points.shape[1] == 3 and points.dtype == np.float64
            outcomes.add("read")
        except cloud_io.CloudError as e:
            assert "\n" not in str(e)
            outcomes.add("refused")
    assert outcomes == {"read", "refused"}  # both happen: the damages are neither all harmless nor all fatal


# ---- meshes ---------------------------------------------------------------------------------------------------

def _mesh_file(path, polygons, *, text, byte_order="<", coord="f4", list_name="vertex_indices", faces_first=False,
               num_vertices=None):
    """A PLY mesh of ``polygons`` (lists of vertex rows) over seeded random vertices with an extra property."""
    rng = np.random.default_rng(0)
    n = num_vertices or 1 + max(max(p) for p in polygons)
    vertex = np.empty(n, dtype=[("x", coord), ("y", coord), ("z", coord), ("confidence", "f4")])
    for name in vertex.dtype.names:
        vertex[name] = rng.normal(size=n)
    face = np.empty(len(polygons), dtype=[(list_name, "O")])
    face[list_name] = [np.asarray(p, np.int32) for p in polygons]
    elements = [PlyElement.describe(vertex, "vertex"), PlyElement.describe(face, "face")]
    PlyData(elements[::-1] if faces_first else elements, text=text, byte_order=byte_order).write(str(path))
    return str(path), vertex


LAYOUTS = [(True, "<"), (False, "<"), (False, ">")]


@pytest.mark.parametrize("text,byte_order", LAYOUTS)
@pytest.mark.parametrize("coord", ["f4", "f8"])
@pytest.mark.parametrize("list_name", ["vertex_indices", "vertex_index"])
def test_a_triangle_mesh_reads_as_written(tmp_path, text, byte_order, coord, list_name):
    tris = [[0, 1, 2], [2, 1, 3], [3, 4, 0], [4, 5, 6]]
    path, vertex = _mesh_file(tmp_path / "m.ply", tris, text=text, byte_order=byte_order, coord=coord,
                              list_name=list_name)
    vertices, faces = ply.read_mesh(path)
    assert vertices.dtype == np.float64 and faces.dtype == np.int64
    np.testing.assert_array_equal(vertices, np.stack([vertex[k].astype(np.float64) for k in "xyz"], 1))
    np.testing.assert_array_equal(faces, tris)
    fallback = ply._mesh_with_plyfile(path)  # the direct parse and plyfile agree bit for bit
    np.testing.assert_array_equal(vertices, fallback[0])
    np.testing.assert_array_equal(faces, fallback[1])


@pytest.mark.parametrize("text,byte_order", LAYOUTS)
@pytest.mark.parametrize("faces_first", [False, True])
def test_polygons_are_fan_triangulated(tmp_path, text, byte_order, faces_first):
    polygons = [[0, 1, 2, 3], [3, 2, 4], [4, 5, 6, 7, 8]]
    path, _ = _mesh_file(tmp_path / "p.ply", polygons, text=text, byte_order=byte_order, faces_first=faces_first)
    _, faces = ply.read_mesh(path)
    np.testing.assert_array_equal(faces, [[0, 1, 2], [0, 2, 3], [3, 2, 4], [4, 5, 6], [4, 6, 7], [4, 7, 8]])


def test_the_header_keeps_list_types(tmp_path):
    path, _ = _mesh_file(tmp_path / "m.ply", [[0, 1, 2]], text=False)
    with open(path, "rb") as f:
        face = ply.read_header(f).elements[1]
    assert face.properties == [("vertex_indices", "list")] and face.lists == {"vertex_indices": ("uchar", "int")}


@pytest.mark.parametrize("text", [True, False])
def test_bad_meshes_are_one_line_errors(tmp_path, text):
    path, _ = _mesh_file(tmp_path / "m.ply", [[0, 1, 2], [2, 1, 3]], text=text)
    data = open(path, "rb").read()
    cases = {"cut": data[:len(data) - 7], "no faces": _write(tmp_path / "v.ply", _vertices(5), text=text)}
    cases["no faces"] = open(cases["no faces"], "rb").read().replace(b"element face 7", b"element edge 7")
    bad_index = _mesh_file(tmp_path / "b.ply", [[0, 1, 2], [2, 1, 7]], text=text, num_vertices=5)[0]
    cases["index out of range"] = open(bad_index, "rb").read()
    reasons = {"cut": "early end-of", "no faces": "no face element", "index out of range": "outside the 5 vertices"}
    for name, body in cases.items():
        (tmp_path / "bad.ply").write_bytes(body)
        with pytest.raises(cloud_io.CloudError, match=reasons[name]) as info:
            ply.read_mesh(str(tmp_path / "bad.ply"))
        assert "\n" not in str(info.value) and "bad.ply" in str(info.value), name


def test_the_stanford_bunny_mesh():
    path = require(DATA / "stanford_bunny" / "bun_zipper_res2.ply", "the Stanford bunny mesh (../shared/data)")
    vertices, faces = ply.read_mesh(str(path))
    assert vertices.shape == (8171, 3) and faces.shape == (16301, 3)
    assert 0.14 < np.ptp(vertices, axis=0).max() < 0.17  # metres
