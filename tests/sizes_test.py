"""Sizes and sensors of a scan set: a LiDAR-like sweep is seen from inside, an object is not; the voxel and the
plane bar follow; bad viewpoints are refused with one line."""

import numpy as np
import pytest

from rpmnet_jax.geometry import normals
from rpmnet_jax.multiway import sizes


def _sweep(seed: int, centre=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Ground rings and a wall around a sensor at ``centre``: ranges 2-40 m, as many points per ring as a LiDAR
    sweep has (in its own frame)."""
    rng = np.random.default_rng(seed)
    r = rng.uniform(2, 40, 3000)
    a = rng.uniform(0, 2 * np.pi, 3000)
    ground = np.stack([r * np.cos(a), r * np.sin(a), np.full_like(r, -1.7)], 1)
    wall = np.stack([rng.uniform(-40, 40, 1000), np.full(1000, 12.0), rng.uniform(-1.7, 4, 1000)], 1)
    return np.concatenate([ground, wall]) + centre


def _object(seed: int) -> np.ndarray:
    """A half sphere of radius 0.1 two metres in front of the origin (a scanner's view of an object)."""
    v = np.random.default_rng(seed).normal(size=(2000, 3))
    v = v / np.linalg.norm(v, axis=1, keepdims=True)
    return 0.1 * v[v[:, 0] < 0] + [2.0, 0.0, 0.0]


def test_a_sweep_surrounds_its_sensor_and_an_object_does_not():
    assert sizes.surrounds(_sweep(0), np.zeros(3))
    assert not sizes.surrounds(_object(0), np.zeros(3))  # outside its bounding box
    centred = _object(0) - [2.0, 0.0, 0.0]  # around its own centre: inside the box, but all points near as far
    assert not sizes.surrounds(np.concatenate([centred, -centred]), np.zeros(3))


def test_sensors_auto_takes_the_frame_origin_of_a_sweep_only():
    found = sizes.sensors([_sweep(0), _object(1)], "auto")
    np.testing.assert_array_equal(found[0], 0.0)
    assert found[1] is None
    assert all(s is not None for s in sizes.sensors([_object(0), _object(1)], "origin"))
    assert sizes.sensors([_sweep(0), _sweep(1)], "none") == [None, None]
    given = sizes.sensors([_sweep(0), _sweep(1), _object(0)], [None, (1.0, 2.0, 3.0), "auto"])
    assert given[0] is None and given[1].tolist() == [1.0, 2.0, 3.0] and given[2] is None


@pytest.mark.parametrize("viewpoints, message", [
    ("sensor", "viewpoints must be one of"), ([None], "got 1 viewpoints for 2 scans"), ([None, "up"], "one of"),
    ([None, (0.0, np.nan, 0.0)], "viewpoint of scan 1"), ([None, (0.0, 1.0)], "viewpoint of scan 1")])
def test_bad_viewpoints_are_refused(viewpoints, message):
    with pytest.raises(ValueError, match=message):
        sizes.sensors([_sweep(0), _sweep(1)], viewpoints)


def test_the_voxel_is_a_scene_share_when_every_sensor_is_surrounded_else_an_object_share():
    sweeps = [_sweep(0), _sweep(1)]
    origin = [np.zeros(3)] * 2
    voxel, scene = sizes.voxel(sweeps, origin, None)
    assert scene and voxel == pytest.approx(sizes.SCENE_RELATIVE_VOXEL / sizes.OBJECT_RELATIVE_VOXEL
                                            * sizes.voxel(sweeps, [None, None], None)[0])
    assert sizes.voxel(sweeps, [None, None], None)[1] is False
    assert sizes.voxel(sweeps, [np.zeros(3), np.array([100.0, 0, 0])], None)[1] is False  # one sensor outside
    assert sizes.voxel(sweeps, origin, 0.25) == (0.25, True)  # the caller's voxel stands
    assert sizes.plane_residual(True) < sizes.plane_residual(False)


def test_normals_facing_a_sensor_point_at_it():
    points = _sweep(2)
    n = normals.facing(points, np.zeros(3))
    assert np.all(np.sum(n * -points, axis=1) >= 0)  # every normal toward the sensor at the origin
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-9)
    assert np.median(np.abs(n[:3000, 2])) > 0.999  # the ground's normals are vertical
