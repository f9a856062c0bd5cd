"""LAS and LAZ through laspy: georeferenced coordinates (4,000 km from the origin, mm detail) round-trip within
1e-6, colours, intensity, normals and NaN rows come back; an empty file or a missing laspy is a one-line error."""

import sys

import numpy as np
import pytest

from rpmnet_jax.io import clouds as cloud_io
from rpmnet_jax.io import las

laspy = pytest.importorskip("laspy")


def _georeferenced(n=3000, seed=0):
    rng = np.random.default_rng(seed)
    pts = np.array([4.0e6, 4.0e6, 100.0]) + rng.uniform(0, 80, (n, 3)).round(3) + rng.normal(size=(n, 3)) * 1e-4
    nrm = rng.normal(size=(n, 3))
    return pts, nrm / np.linalg.norm(nrm, axis=1, keepdims=True), rng.integers(0, 65536, (n, 3)).astype(np.float64)


@pytest.mark.parametrize("ext", [".las", ".laz"])
def test_round_trip_keeps_georeferenced_precision(tmp_path, ext):
    pts, nrm, rgb = _georeferenced()
    pts[7] = np.nan
    intensity = np.arange(len(pts), dtype=np.float64)
    path = str(tmp_path / f"c{ext}")
    cloud_io.write_cloud(path, pts, nrm, rgb, intensity)
    got = cloud_io.read(path)
    finite = np.all(np.isfinite(pts), axis=1)
    error = np.abs(got.points[finite] - pts[finite]).max()
    print(f"{ext} max abs error {error:.3g}")
    assert error <= 1e-6 and got.points.dtype == np.float64
    assert np.isnan(got.points[7]).all() and len(got.points) == len(pts)  # the NaN row stays a row
    np.testing.assert_array_equal(got.colours, rgb)
    np.testing.assert_array_equal(got.intensity, intensity)
    np.testing.assert_array_equal(got.normals, nrm)
    with open(path, "rb") as f:  # a real LAS/LAZ file that laspy reads on its own
        assert laspy.read(f).header.point_count == len(pts)


def test_fractional_intensity_and_unit_colours(tmp_path):
    pts, _, _ = _georeferenced(100)
    rgb = np.random.default_rng(1).uniform(size=(100, 3))
    intensity = np.linspace(-1, 1, 100)
    path = str(tmp_path / "c.las")
    cloud_io.write_cloud(path, pts, colours=rgb, intensity=intensity)
    got = cloud_io.read(path)
    np.testing.assert_array_equal(got.intensity, intensity)  # float64 extra bytes
    np.testing.assert_allclose(got.colours / 65535, rgb, atol=1e-5)  # 0-1 scaled to LAS's 16 bits


def test_header_frame_fits_int32():
    pts = np.array([[4.0e6, -4.0e6, 0.0], [4.0e6 + 150.0, -4.0e6 + 2000.0, 9e5]])
    offsets, scales = las.header_frame(pts)
    np.testing.assert_array_equal(offsets, np.floor(pts.min(0)))
    np.testing.assert_array_equal(scales, [1e-7, 1e-6, 1e-3])
    assert np.all((pts.max(0) - offsets) / scales < 2 ** 31 - 1)


def test_empty_las_is_one_line_error(tmp_path):
    header = laspy.LasHeader(point_format=6, version="1.4")
    laspy.LasData(header).write(str(tmp_path / "e.las"))
    with pytest.raises(cloud_io.CloudError, match="no points") as info:
        cloud_io.read(str(tmp_path / "e.las"))
    assert "\n" not in str(info.value)


def test_missing_laspy_names_the_extra(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "laspy", None)
    with pytest.raises(cloud_io.CloudError, match=r"pip install 'rpmnet_jax\[scanners\]'"):
        cloud_io.check_format(str(tmp_path / "out.laz"))
