"""The scan-pose convention, checked against the real Stanford bunny ``bun.conf`` and its reconstruction."""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from conftest import DATA, require
from rpmnet_jax.io import poses as scan_poses
from rpmnet_jax.io import clouds as cloud_io

BUNNY = DATA / "stanford_bunny"


@pytest.fixture(scope="module")
def bunny():
    require(BUNNY / "bun.conf", "Stanford bunny scans")
    mesh, _ = cloud_io.read_cloud(str(BUNNY / "bun_zipper_res2.ply"))
    return scan_poses.read_poses(str(BUNNY / "bun.conf")), cKDTree(mesh)


@pytest.mark.parametrize("name", ["bun045", "bun090", "bun315"])
def test_posed_scans_lie_on_the_reconstruction(bunny, name):
    poses, mesh = bunny
    points, _ = cloud_io.read_cloud(str(BUNNY / f"{name}.ply"))
    pose = poses[name]
    dist, _ = mesh.query(points @ pose[:3, :3].T + pose[:3, 3])
    assert np.mean(dist < 0.002) > 0.98  # within 2 mm of a vertex of the 8k-vertex reconstruction
    # the other reading of the quaternion (R instead of R^T) puts most of the scan off the surface
    dist_t, _ = mesh.query(points @ pose[:3, :3] + pose[:3, 3])
    assert np.mean(dist_t < 0.002) < 0.2


def test_relative_motion_maps_one_scan_onto_the_other(bunny):
    poses, mesh = bunny
    src, _ = cloud_io.read_cloud(str(BUNNY / "bun045.ply"))
    motion = scan_poses.relative_motion(poses, "bun045", "bun000")
    moved = src @ motion[:3, :3].T + motion[:3, 3]  # in bun000's frame
    world = moved @ poses["bun000"][:3, :3].T + poses["bun000"][:3, 3]
    dist, _ = mesh.query(world)
    assert np.mean(dist < 0.002) > 0.98
