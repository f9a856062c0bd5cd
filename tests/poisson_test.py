"""Poisson meshes of sampled shapes: a sampled ellipsoid (normals half flipped, as a dataset's may be) comes back as
a closed ellipsoid of the asked size, centred, wound outward; a row of a PointNet-layout file comes back as a mesh."""

import numpy as np
import pytest

from rpmnet_jax.data import modelnet40, poisson

pytest.importorskip("open3d")


AXES = np.array([1.0, 0.8, 0.6])


def _ellipsoid(n=2048, seed=0):
    rng = np.random.default_rng(seed)
    unit = rng.normal(size=(n, 3))
    unit /= np.linalg.norm(unit, axis=1, keepdims=True)
    normals = unit / AXES
    normals *= np.where(rng.uniform(size=(n, 1)) < 0.5, -1.0, 1.0) / np.linalg.norm(normals, axis=1, keepdims=True)
    return unit * AXES + [0.3, -0.2, 0.1], normals  # half of the normals inward


def test_a_sampled_ellipsoid_becomes_the_ellipsoid_at_the_asked_size():
    pts, normals = _ellipsoid()
    vertices, faces = poisson.reconstruct(pts, normals, 0.2, depth=6)
    assert faces.dtype == np.int64 and faces.shape[1] == 3 and faces.max() < len(vertices)
    low, high = vertices.min(0), vertices.max(0)
    assert np.linalg.norm(high - low) == pytest.approx(0.2)
    np.testing.assert_allclose(0.5 * (low + high), 0.0, atol=1e-12)
    semi = AXES * 0.1 / np.linalg.norm(AXES)  # the box of the ellipsoid has diagonal 0.2
    level = np.linalg.norm(vertices / semi, axis=1)  # 1 on the ellipsoid's surface
    assert np.all(np.abs(level - 1) < 0.1)
    # outward normals: the triangles' winding puts the centre inside (positive signed volume)
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    assert np.sum(np.einsum("ij,ij->i", a, np.cross(b, c))) > 0


def test_shape_meshes_reads_rows_of_a_file(tmp_path):
    pts, normals = _ellipsoid(512, seed=1)
    data = np.stack([np.c_[pts, normals], np.c_[pts * [1.0, 0.5, 0.5], normals]]).astype(np.float32)
    modelnet40.write_split(tmp_path, "train", data, np.zeros(2, np.int64))
    (tmp_path / "shape_names.txt").write_text("blob\n")
    meshes = poisson.shape_meshes(tmp_path, "train", [0], [0.3])
    assert len(meshes) == 1
    vertices, _ = meshes[0]
    assert np.linalg.norm(np.ptp(vertices, axis=0)) == pytest.approx(0.3)


def test_the_reconstruction_is_the_same_on_every_run():
    """Open3D's threaded Poisson solve differs run to run; ``reconstruct`` runs it on one thread."""
    pts, normals = _ellipsoid(1500, seed=3)
    first = poisson.reconstruct(pts, normals, 0.5)
    for _ in range(3):
        again = poisson.reconstruct(pts, normals, 0.5)
        np.testing.assert_array_equal(again[0], first[0])
        np.testing.assert_array_equal(again[1], first[1])
