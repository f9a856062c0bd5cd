"""PCD colours: PCL's packed ``rgb`` (``0xAARRGGBB`` in the bits of a float32, or a uint32) reads back every byte,
binary and ASCII, with alpha 255 (a NaN as a float32) and without; the writer's packed colours read back."""

import numpy as np
import pytest

from rpmnet_jax.io import clouds as cloud_io, columns, pcd


def _colours(alpha: int) -> tuple:
    """Every red 0–255 with green and blue apart from it: ``(rgb (256, 3) float64, packed (256,) uint32)``."""
    red = np.arange(256, dtype=np.uint32)
    green, blue = (red * 7 + 3) % 256, (red * 13 + 5) % 256
    packed = (np.uint32(alpha) << 24) | (red << 16) | (green << 8) | blue
    return np.c_[red, green, blue].astype(np.float64), packed


def _header(kind: str, rgb_type: str, n: int) -> str:
    return (f"# .PCD v0.7\nVERSION 0.7\nFIELDS x y z rgb\nSIZE 4 4 4 4\nTYPE F F F {rgb_type}\nCOUNT 1 1 1 1\n"
            f"WIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA {kind}\n")


@pytest.mark.parametrize("rgb_type", ["F", "U"])
@pytest.mark.parametrize("alpha", [255, 0])
def test_binary_packed_colour_reads_back_every_byte(tmp_path, rgb_type, alpha):
    """With alpha 255, ``0xFFRRGGBB`` as a float32 is a NaN, a signalling one for a red of 128–191; widened to
    float64 it came back quiet, its red changed (128 -> 192, 160 -> 224)."""
    rgb, packed = _colours(alpha)
    table = np.zeros(len(rgb), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("rgb", "<u4")])
    table["x"] = np.arange(len(rgb))
    table["rgb"] = packed  # the float32's bits, as PCL (TYPE F) and Open3D write them
    (tmp_path / "c.pcd").write_bytes(_header("binary", rgb_type, len(rgb)).encode() + table.tobytes())
    cloud = cloud_io.read(str(tmp_path / "c.pcd"))
    np.testing.assert_array_equal(cloud.colours, rgb)
    np.testing.assert_array_equal(cloud.points[:, 0], np.arange(len(rgb)))


def test_ascii_packed_colour_as_pcl_writes_it(tmp_path):
    """PCL's ASCII writer gives ``rgb`` as the uint32 of its bits under ``TYPE U`` (alpha 255 stays a number)."""
    rgb, packed = _colours(255)
    body = "".join(f"{i} 0 0 {p}\n" for i, p in enumerate(packed))
    (tmp_path / "c.pcd").write_text(_header("ascii", "U", len(rgb)) + body)
    np.testing.assert_array_equal(cloud_io.read(str(tmp_path / "c.pcd")).colours, rgb)


def test_ascii_packed_colour_as_a_float(tmp_path):
    """``TYPE F`` text is the float32 whose bits are the colour (alpha 0: every value a finite float, most of them
    subnormal)."""
    rgb, packed = _colours(0)
    body = "".join(f"{i} 0 0 {np.format_float_scientific(v)}\n" for i, v in enumerate(packed.view(np.float32)))
    (tmp_path / "c.pcd").write_text(_header("ascii", "F", len(rgb)) + body)
    np.testing.assert_array_equal(cloud_io.read(str(tmp_path / "c.pcd")).colours, rgb)


def test_written_packed_colours_read_back(tmp_path):
    rgb, _ = _colours(0)
    points = np.random.default_rng(0).normal(size=(len(rgb), 3))
    cloud_io.write_cloud(str(tmp_path / "c.pcd"), points, colours=rgb)
    assert b"FIELDS x y z rgb" in (tmp_path / "c.pcd").read_bytes()[:200]
    cloud = cloud_io.read(str(tmp_path / "c.pcd"))
    np.testing.assert_array_equal(cloud.colours, rgb)
    np.testing.assert_array_equal(cloud.points, points)


def test_a_viewpoint_is_where_the_sensor_stood_and_moves_with_the_cloud(tmp_path):
    """PCL's ``VIEWPOINT tx ty tz qw qx qy qz``: its translation is the sensor's position in the cloud's coordinates
    (``None`` for PCL's default, which says nothing); a bad line is one error; ``moved`` moves it with the points."""
    body = "1 2 3\n4 5 6\n"

    def write(viewpoint):
        path = tmp_path / "v.pcd"
        path.write_text(f"VERSION .7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 2\nHEIGHT 1\n"
                        f"VIEWPOINT {viewpoint}\nPOINTS 2\nDATA ascii\n{body}")
        return str(path)

    assert pcd.read(write("0 0 0 1 0 0 0")).viewpoint is None
    cloud = pcd.read(write("10.5 -2 0.25 1 0 0 0"))
    assert cloud.viewpoint.tolist() == [10.5, -2.0, 0.25]
    turn = np.array([[0.0, -1.0, 0.0, 1.0], [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]])
    assert cloud.moved(turn).viewpoint.tolist() == [3.0, 10.5, 0.25]
    with pytest.raises(columns.CloudError, match="VIEWPOINT"):
        pcd.read(write("1 2 3"))
