"""E57 through pye57: double-precision coordinates 4,000 km from the origin round-trip within 1e-6; several scans
come back one by one with their names and stored poses; colours, intensity and NaN rows come back; a scan without
Cartesian coordinates, or a multi-scan file read as one cloud, is a one-line error."""

import sys

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rpmnet_jax.io import clouds as cloud_io
from rpmnet_jax.io import columns
from rpmnet_jax.io import e57

pye57 = pytest.importorskip("pye57")


def _georeferenced(n=3000, seed=0):
    rng = np.random.default_rng(seed)
    return np.array([4.0e6, 4.0e6, 100.0]) + rng.uniform(0, 80, (n, 3)).round(3) + rng.normal(size=(n, 3)) * 1e-4


def _pose(seed):
    pose = np.eye(4)
    pose[:3, :3] = Rotation.from_euler("xyz", [5 * seed, -10, 30 * seed], degrees=True).as_matrix()
    pose[:3, 3] = [4.0e6 + seed, 4.0e6 - 2 * seed, 50.0]
    return pose


def test_round_trip_keeps_georeferenced_precision(tmp_path):
    pts = _georeferenced()
    pts[11] = np.nan
    rgb = np.random.default_rng(1).integers(0, 256, (len(pts), 3)).astype(np.float64)
    intensity = np.random.default_rng(2).normal(size=len(pts))
    path = str(tmp_path / "c.e57")
    cloud_io.write_cloud(path, pts, colours=rgb, intensity=intensity)
    got = cloud_io.read(path)
    finite = np.all(np.isfinite(pts), axis=1)
    error = np.abs(got.points[finite] - pts[finite]).max()
    print(f".e57 max abs error {error:.3g}")
    assert error <= 1e-6 and np.isnan(got.points[11]).all() and len(got.points) == len(pts)
    np.testing.assert_array_equal(got.colours, rgb)
    np.testing.assert_array_equal(got.intensity, intensity)
    with pye57.E57(path) as f:  # pye57 reads it on its own (the invalid row left out)
        assert len(f.read_scan(0)["cartesianX"]) == len(pts) - 1


def test_several_scans_with_names_and_poses(tmp_path):
    rng = np.random.default_rng(3)
    local = [rng.normal(size=(200 + 10 * k, 3)) for k in range(3)]
    scans = [e57.Scan(columns.Cloud(local[0]), "north", _pose(0)), e57.Scan(columns.Cloud(local[1]), None, None),
             e57.Scan(columns.Cloud(local[2], colours=rng.uniform(size=(220, 3))), "south", _pose(2))]
    path = str(tmp_path / "s.e57")
    e57.write(path, scans)
    got = e57.read_scans(path)
    assert [s.name for s in got] == ["north", None, "south"]
    assert got[1].pose is None
    for k in (0, 2):
        np.testing.assert_allclose(got[k].pose, _pose(k), atol=1e-9)
        np.testing.assert_array_equal(got[k].cloud.points, local[k])  # the scan's own frame
    np.testing.assert_array_equal(got[2].cloud.colours, scans[2].cloud.colours)  # fractional colours as float64
    with pytest.raises(cloud_io.CloudError, match="holds 3 scans"):
        cloud_io.read(path)
    one = str(tmp_path / "one.e57")
    e57.write(one, [scans[2]])
    np.testing.assert_allclose(cloud_io.read(one).points, local[2] @ _pose(2)[:3, :3].T + _pose(2)[:3, 3],
                               rtol=0, atol=1e-8)  # one scan: in the file's frame


def _spherical_only(path, n=50):
    """An E57 file whose one scan has only spherical coordinates."""
    from pye57 import libe57

    f = pye57.E57(path, mode="w")
    imf = f.image_file
    node, prototype = libe57.StructureNode(imf), libe57.StructureNode(imf)
    node.set("guid", libe57.StringNode(imf, "{spherical}"))
    fields = ("sphericalRange", "sphericalAzimuth", "sphericalElevation")
    for name in fields:
        prototype.set(name, libe57.FloatNode(imf, 0.0, libe57.E57_DOUBLE))
    points = libe57.CompressedVectorNode(imf, prototype, libe57.VectorNode(imf, True))
    node.set("points", points)
    f.data3d.append(node)
    data = {name: np.random.default_rng(0).uniform(0.1, 1.0, n) for name in fields}
    buffers = libe57.VectorSourceDestBuffer()
    for name in fields:
        buffers.append(libe57.SourceDestBuffer(imf, name, data[name], n, True, True))
    writer = points.writer(buffers)
    writer.write(n)
    writer.close()
    f.close()


def test_scan_without_cartesian_fields_is_one_line_error(tmp_path):
    path = str(tmp_path / "sph.e57")
    _spherical_only(path)
    with pytest.raises(cloud_io.CloudError, match="no Cartesian coordinates") as info:
        cloud_io.read(path)
    assert "\n" not in str(info.value)


def test_damaged_file_and_missing_pye57(tmp_path, monkeypatch):
    (tmp_path / "bad.e57").write_bytes(b"not an e57 file" * 100)
    with pytest.raises(cloud_io.CloudError, match="cannot read as E57") as info:
        cloud_io.read(str(tmp_path / "bad.e57"))
    assert "\n" not in str(info.value)
    monkeypatch.setitem(sys.modules, "pye57", None)
    with pytest.raises(cloud_io.CloudError, match=r"pip install 'rpmnet_jax\[scanners\]'"):
        cloud_io.check_format("out.e57")
