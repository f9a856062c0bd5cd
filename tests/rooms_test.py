"""The simulated room: rays hit the walls, the door recess and the furniture where geometry says; a station's
points, moved by its pose, lie on the room's surfaces."""

import numpy as np
import pytest

from rpmnet_jax.simulation import rooms


@pytest.mark.parametrize("sensor, direction, distance", [
    ((5.0, 3.0, 1.5), (0, 0, 1), 1.5),  # the ceiling
    ((5.0, 3.0, 1.5), (0, 0, -1), 1.5),  # the floor
    ((5.0, 3.0, 1.5), (-1, 0, 0), 5.0),  # the near wall at x = 0
    ((4.5, 4.0, 1.0), (0, 1, 0), 3.3),  # through the door into the recess: its back wall at y = 7.3
    ((4.5, 4.0, 2.5), (0, 1, 0), 3.0),  # above the door: the wall at y = 7
    ((1.0, 2.2, 1.0), (1, 0, 0), 1.0),  # a column's face at x = 2
    ((4.6, 2.0, 0.2), (0, 1, 0), 1.0),  # the crate's face at y = 3 (it is 0.45 high)
])
def test_a_ray_stops_at_the_first_surface(sensor, direction, distance):
    d = np.asarray(direction, np.float64)[None]
    assert rooms.cast(np.asarray(sensor, np.float64), d)[0] == pytest.approx(distance, abs=1e-9)


def test_a_station_s_points_lie_on_the_room_s_surfaces():
    s = rooms.station((2.5, 3.0), 70.0, seed=1, step_deg=3.0)
    room = s.points @ s.pose[:3, :3].T + s.pose[:3, 3]
    assert len(s.points) > 2000
    np.testing.assert_allclose(s.pose[:3, 3], [2.5, 3.0, rooms.SENSOR_HEIGHT])
    lo, hi = np.array([0.0, 0.0, 0.0]), np.array(rooms.SIZE) + [0.0, rooms.DOOR[1], 0.0]
    slack = 6 * rooms.NOISE
    assert np.all(room >= lo - slack) and np.all(room <= hi + slack)
    # the station's own frame: levelled (the ceiling's points are as high above it as in the room) but turned
    np.testing.assert_allclose(s.points[:, 2], room[:, 2] - rooms.SENSOR_HEIGHT, atol=1e-9)
    assert not np.allclose(s.points[:, :2], room[:, :2] - [2.5, 3.0])


def test_stations_stand_in_free_space():
    for xy in rooms.STATIONS:
        inside = [(lo[0] <= xy[0] <= hi[0]) and (lo[1] <= xy[1] <= hi[1]) for lo, hi in rooms.boxes()]
        assert not any(inside) and 0 < xy[0] < rooms.SIZE[0] and 0 < xy[1] < rooms.SIZE[1]
