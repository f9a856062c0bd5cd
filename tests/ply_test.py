"""The PLY vertex reader: the same table as plyfile, bit for bit, on every layout it reads itself; plyfile for the
rest; a damaged file is a one-line CloudError, never anything else."""

import numpy as np
import pytest
from plyfile import PlyData, PlyElement

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
