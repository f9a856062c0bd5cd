"""The range-scan simulator: points on the mesh, the nearest surface only, noise along the ray with the requested
std, grazing hits dropped, deterministic per seed; a written set reads back with its true poses."""

import itertools
import math

import numpy as np
import pytest

from rpmnet_jax.simulation import range_scans
from rpmnet_jax.evaluation import pose_errors
from rpmnet_jax.io import clouds, poses as poses_io

CENTER, HALF = np.array([0.3, -0.2, 0.1]), 1.0


def _quads(corners):
    """``(vertices, faces)`` of quads ``corners (Q, 4, 3)`` (each in cyclic order), two triangles each."""
    vertices = np.asarray(corners, np.float64).reshape(-1, 3)
    faces = [[4 * q, 4 * q + 1, 4 * q + 2] for q in range(len(corners))]
    faces += [[4 * q, 4 * q + 2, 4 * q + 3] for q in range(len(corners))]
    return vertices, np.array(faces)


def _cube():
    cycle = [(-1, -1), (1, -1), (1, 1), (-1, 1)]
    corners = []
    for axis, side in itertools.product(range(3), (-1, 1)):
        a, b = [k for k in range(3) if k != axis]
        quad = np.zeros((4, 3))
        quad[:, axis], quad[:, a], quad[:, b] = side, [c[0] for c in cycle], [c[1] for c in cycle]
        corners.append(CENTER + HALF * quad)
    return _quads(corners)


def _square(half, z, x0=0.0):
    return [[x0 - half, -half, z], [x0 + half, -half, z], [x0 + half, half, z], [x0 - half, half, z]]


def _in_mesh_frame(s):
    return s.points @ s.pose[:3, :3].T + s.pose[:3, 3]


def test_points_lie_on_the_mesh():
    vertices, faces = _cube()
    for noise, tolerance in ((0.0, 1e-9), (0.01, 0.06)):
        scans = range_scans.simulate(vertices, faces, 6, image_size=64, noise=noise)
        for s in scans:
            assert s.points.shape[1] == 3 and len(s.points) > 300 and s.points.dtype == np.float64
            off_surface = np.abs(np.abs(_in_mesh_frame(s) - CENTER).max(axis=1) - HALF)
            assert off_surface.max() < tolerance


def test_noise_is_along_the_ray_with_the_requested_std():
    vertices, faces = _cube()
    clean = range_scans.simulate(vertices, faces, 6, image_size=64, noise=0.0, seed=3)
    noisy = range_scans.simulate(vertices, faces, 6, image_size=64, noise=0.02, seed=3)
    along = []
    for c, n in zip(clean, noisy):
        np.testing.assert_array_equal(c.pose, n.pose)  # the noise moves points only
        rays = c.points / np.linalg.norm(c.points, axis=1, keepdims=True)  # the sensor sits at the origin
        diff = n.points - c.points
        assert np.abs(np.cross(diff, rays)).max() < 1e-12
        along.append(np.sum(diff * rays, axis=1))
    along = np.concatenate(along)
    assert len(along) > 5000
    assert abs(along.std() / 0.02 - 1) < 0.05 and abs(along.mean()) < 4 * 0.02 / math.sqrt(len(along))


def test_deterministic_per_seed():
    vertices, faces = _cube()
    first, again = (range_scans.simulate(vertices, faces, 4, image_size=32, noise=0.01, seed=5) for _ in range(2))
    for a, b in zip(first, again):
        np.testing.assert_array_equal(a.points, b.points)
        np.testing.assert_array_equal(a.pose, b.pose)
    other = range_scans.simulate(vertices, faces, 4, image_size=32, noise=0.01, seed=6)
    assert not np.allclose(first[0].pose, other[0].pose)


def test_cameras_look_at_the_centre_from_around_it():
    vertices, faces = _cube()
    poses = np.stack([s.pose for s in range_scans.simulate(vertices, faces, 20, image_size=16)])
    rot = poses[:, :3, :3]
    np.testing.assert_allclose(rot @ rot.transpose(0, 2, 1), np.broadcast_to(np.eye(3), rot.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(rot), 1.0)
    to_centre = CENTER - poses[:, :3, 3]
    np.testing.assert_allclose(np.sum(rot[:, :, 2] * to_centre, axis=1), np.linalg.norm(to_centre, axis=1))
    dirs = -to_centre / np.linalg.norm(to_centre, axis=1, keepdims=True)
    assert dirs[:, 2].max() > 0.8 and dirs[:, 2].min() < -0.8  # all round, not one side


def _behind(s, z, half):
    """Mask of the points of ``s`` off the plane ``z`` whose sight line from the camera crosses that plane
    within the square ``|x|, |y| < half``."""
    points, camera = _in_mesh_frame(s), s.pose[:3, 3]
    step = (z - camera[2]) / (points[:, 2] - camera[2])
    cross = camera + step[:, None] * (points - camera)
    return (np.abs(points[:, 2] - z) > 1e-9) & (step > 0) & (step < 1) & (np.abs(cross[:, :2]).max(axis=1) < half)


def test_a_surface_behind_a_nearer_one_is_never_returned():
    """Two parallel squares: no point is returned whose sight line crosses the other square, though the far
    square alone, scanned from the same poses, has many such points."""
    vertices, faces = _quads([_square(1.0, 1.0), _square(2.0, 0.0)])
    bottom_only = _quads([_square(2.0, 0.0)])
    occluded = 0
    for s in range_scans.simulate(vertices, faces, 12, image_size=64, noise=0.0):
        assert not _behind(s, 1.0, 1.0).any() and not _behind(s, 0.0, 2.0).any()
        occluded += int(_behind(range_scans.scan(*bottom_only, s.pose, image_size=64), 1.0, 1.0).sum())
    assert occluded > 100


def test_grazing_hits_are_dropped():
    """A camera at the origin looking along +z: a square facing it is kept; a wall in the plane x = 0.5 (every
    ray meets it 83-87 degrees from its normal) is dropped at 80 degrees and returned at 89."""
    facing = [[-1.0, -1.0, 5.0], [0.2, -1.0, 5.0], [0.2, 1.0, 5.0], [-1.0, 1.0, 5.0]]
    wall = [[0.5, -1.0, 4.0], [0.5, -1.0, 8.0], [0.5, 1.0, 8.0], [0.5, 1.0, 4.0]]
    vertices, faces = _quads([facing, wall])
    on_wall = {}
    for limit in (80.0, 89.0):
        s = range_scans.scan(vertices, faces, np.eye(4), image_size=64, max_incidence_deg=limit)
        wall_rows = np.abs(s.points[:, 0] - 0.5) < 1e-9
        on_wall[limit] = int(wall_rows.sum())
        assert np.sum(np.abs(s.points[:, 2] - 5.0) < 1e-9) > 500  # the facing square
        incidence = np.degrees(np.arccos(0.5 / np.linalg.norm(s.points[wall_rows], axis=1)))
        assert np.all((incidence > 82.5) & (incidence <= limit))
    assert on_wall[80.0] == 0 and on_wall[89.0] > 50


def test_noise_needs_no_generator_when_zero_and_bad_meshes_are_refused():
    vertices, faces = _cube()
    assert len(range_scans.scan(vertices, faces, range_scans.look_at(np.array([5.0, 0, 0]), CENTER),
                                image_size=16).points)
    for bad in (faces + 100, faces[:, :2], faces.astype(float)):
        with pytest.raises(ValueError, match="faces"):
            range_scans.simulate(vertices, bad, 2, image_size=16)
    with pytest.raises(ValueError, match="inside the mesh"):
        range_scans.simulate(vertices, faces, 2, image_size=16, distance=1.0)


@pytest.mark.parametrize("shuffle_seed", [None, 1])
def test_a_written_set_reads_back_with_its_true_poses(tmp_path, shuffle_seed):
    vertices, faces = _cube()
    scans = range_scans.simulate(vertices, faces, 6, image_size=32, noise=0.01)
    order = range_scans.write_set(str(tmp_path), scans, shuffle_seed=shuffle_seed)
    assert sorted(order) == list(range(6)) and (order == list(range(6))) == (shuffle_seed is None)
    truth = poses_io.read_poses(str(tmp_path / "truth.conf"))
    assert list(truth) == [f"scan{k:03d}" for k in range(6)]
    read = [clouds.read_cloud(str(tmp_path / f"{name}.ply"))[0] for name in truth]
    for k, s in enumerate(order):
        np.testing.assert_array_equal(read[k], scans[s].points)  # float64, bit for bit
        np.testing.assert_allclose(truth[f"scan{k:03d}"], scans[s].pose, atol=1e-12)
    exact = np.stack([scans[s].pose for s in order])
    errors = np.array(pose_errors.pose_errors(np.stack(list(truth.values())), exact, read))
    assert errors.max() < 1e-9  # the .conf's poses score as the truth
    range_scans.write_set(str(tmp_path), scans, shuffle_seed=shuffle_seed)  # the same set again: overwritten
    with pytest.raises(ValueError, match="other point-cloud files"):  # fewer scans: scan005.ply would stay
        range_scans.write_set(str(tmp_path), scans[:5])
