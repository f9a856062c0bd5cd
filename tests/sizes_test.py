"""Sizes and sensors of a scan set: a LiDAR-like sweep is seen from inside, an object is not; the voxel and the
plane bar follow; bad viewpoints are refused with one line."""

import numpy as np
import pytest

from conftest import synthetic_shape
from rpmnet_jax.geometry import normals, sensors
from rpmnet_jax.multiway import sizes


def _sweep(seed: int, centre=(0.0, 0.0, 0.0)) -> np.ndarray:
    """A LiDAR-like sweep from a sensor at ``centre``: rays every 1° of azimuth and elevation (-25° to 3°) onto
    the ground 1.7 m below, or onto a wall 12 m away where it comes first; 80 m range, 1 cm noise."""
    az, el = np.meshgrid(np.radians(np.arange(0.0, 360.0, 1.0)), np.radians(np.arange(-25.0, 4.0, 1.0)))
    d = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], -1).reshape(-1, 3)
    with np.errstate(divide="ignore"):
        ground = np.where(d[:, 2] < 0, -1.7 / d[:, 2], np.inf)
    with np.errstate(divide="ignore"):
        wall = np.where(d[:, 1] > 0, 12.0 / d[:, 1], np.inf)
    t = np.minimum(ground, wall)
    seen = t < 80.0  # the scanner's range
    d, t = d[seen], t[seen] + np.random.default_rng(seed).normal(scale=0.01, size=int(seen.sum()))
    return t[:, None] * d + centre


def _object(seed: int) -> np.ndarray:
    """A half sphere of radius 0.1 two metres in front of the origin (a scanner's view of an object)."""
    v = np.random.default_rng(seed).normal(size=(2000, 3))
    v = v / np.linalg.norm(v, axis=1, keepdims=True)
    return 0.1 * v[v[:, 0] < 0] + [2.0, 0.0, 0.0]


def test_a_sweep_is_taken_from_its_origin_and_an_object_is_not():
    assert sensors.taken_from(_sweep(0), np.zeros(3)) and sensors.inside(_sweep(0), np.zeros(3))
    assert not sensors.taken_from(_object(0), np.zeros(3))  # a scanner far away: every point at one distance
    assert not sensors.inside(_object(0), np.zeros(3))
    shape, _ = synthetic_shape(seed=0, n=4000)  # a surface around its own centre, evenly sampled (a long one,
    # far points 4× as far as near ones, would look like a sweep: viewpoints="none" is for those)
    assert not sensors.taken_from(shape - shape.mean(axis=0), np.zeros(3))
    assert not sensors.taken_from(_sweep(0) + [512_000.0, 4_100_000.0, 120.0], np.zeros(3))  # in a grid: not there


def test_sensors_auto_takes_the_frame_origin_of_a_sweep_only():
    found = sensors.positions([_sweep(0), _object(1)], "auto")
    np.testing.assert_array_equal(found[0], 0.0)
    assert found[1] is None
    assert all(s is not None for s in sensors.positions([_object(0), _object(1)], "origin"))
    assert sensors.positions([_sweep(0), _sweep(1)], "none") == [None, None]
    given = sensors.positions([_sweep(0), _sweep(1), _object(0)], [None, (1.0, 2.0, 3.0), "auto"])
    assert given[0] is None and given[1].tolist() == [1.0, 2.0, 3.0] and given[2] is None


@pytest.mark.parametrize("viewpoints, message", [
    ("sensor", "viewpoints must be one of"), ([None], "got 1 viewpoints for 2 scans"), ([None, "up"], "one of"),
    ([None, (0.0, np.nan, 0.0)], "viewpoint of scan 1"), ([None, (0.0, 1.0)], "viewpoint of scan 1")])
def test_bad_viewpoints_are_refused(viewpoints, message):
    with pytest.raises(ValueError, match=message):
        sensors.positions([_sweep(0), _sweep(1)], viewpoints)


def test_the_voxel_is_a_scene_share_when_every_sensor_is_surrounded_else_an_object_share():
    sweeps = [_sweep(0), _sweep(1)]
    origin = [np.zeros(3)] * 2
    voxel, scene = sizes.voxel(sweeps, origin, None)
    assert scene and voxel == pytest.approx(sizes.SCENE_RELATIVE_VOXEL / sizes.OBJECT_RELATIVE_VOXEL
                                            * sizes.voxel(sweeps, [None, None], None)[0])
    assert sizes.voxel(sweeps, [None, None], None)[1] is False
    assert sizes.voxel(sweeps, [np.zeros(3), np.array([0.0, 0.0, 100.0])], None)[1] is False  # one sensor outside
    assert sizes.voxel(sweeps, origin, 0.25) == (0.25, True)  # the caller's voxel stands
    assert sizes.plane_residual(True) < sizes.plane_residual(False)


def test_normals_facing_a_sensor_point_at_it():
    points = _sweep(2)
    n = normals.facing(points, np.zeros(3))
    assert np.all(np.sum(n * -points, axis=1) >= 0)  # every normal toward the sensor at the origin
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-9)
    assert np.median(np.abs(n[:3000, 2])) > 0.999  # the ground's normals are vertical
