import numpy as np
import pytest

from rpmnet_jax import data
from rpmnet_jax.data import synthetic
from rpmnet_jax.data import views


def _sphere(n, seed=0):
    xyz = np.random.default_rng(seed).normal(size=(n, 3))
    return xyz / np.linalg.norm(xyz, axis=1, keepdims=True)


def test_a_sphere_shows_the_cap_facing_the_camera():
    xyz = _sphere(2000)
    camera = np.array([0.0, 0.0, 3.0])
    seen = views.visible(xyz, camera)
    # the cap a camera at distance 3 sees is z > 1/3 (tangent cone); hidden point removal is loose near that
    # horizon on a sampled surface, never on the far side
    assert not seen[xyz[:, 2] < 0.15].any()
    assert seen[xyz[:, 2] > 0.4].mean() > 0.97


def test_a_near_plate_hides_the_far_one():
    rng = np.random.default_rng(1)
    near = np.c_[rng.uniform(-1, 1, (400, 2)), np.full(400, 0.5)]
    far = np.c_[rng.uniform(-0.5, 0.5, (400, 2)), np.full(400, -0.5)]  # right behind the near plate
    seen = views.visible(np.concatenate([near, far]), np.array([0.0, 0.0, 4.0]))
    assert seen[400:].mean() < 0.05
    assert seen[:400].mean() > 0.9


def test_a_flat_cloud_does_not_fail():
    flat = np.c_[np.random.default_rng(2).uniform(-1, 1, (300, 2)), np.zeros(300)]
    assert views.visible(flat, np.array([0.0, 0.0, 2.0])).any()


@pytest.mark.parametrize("max_angle", [0.0, 30.0, 90.0])
def test_view_directions_are_unit_and_at_most_max_angle_apart(max_angle):
    rng = np.random.RandomState(3)
    for _ in range(50):
        a, b = views.view_directions(rng, max_angle)
        np.testing.assert_allclose([np.linalg.norm(a), np.linalg.norm(b)], 1.0, atol=1e-12)
        assert np.degrees(np.arccos(np.clip(a @ b, -1, 1))) <= max_angle + 1e-5


@pytest.fixture(scope="module")
def synthetic_root(tmp_path_factory):
    return synthetic.write_dataset(tmp_path_factory.mktemp("syn"), num_train=30, num_test=4, seed=1)


def test_view_pairs_keep_shapes_and_the_ground_truth(synthetic_root):
    ds = data.ModelNet40(synthetic_root, "train", "partial", seed=0, views_share=1.0)
    plain = data.ModelNet40(synthetic_root, "train", "partial", seed=0)
    for i in range(4):
        s = ds.get(i)
        assert s["points_src"].shape == (717, 6) and s["points_ref"].shape == (717, 6)
        # the ground truth maps every source point onto the clean shape, within the jitter's clip
        moved = data.apply_transform(s["transform_gt"], s["points_src"])
        gap = np.linalg.norm(moved[:, None, :3] - s["points_raw"][None, :, :3], axis=-1).min(axis=1)
        assert gap.max() < 0.05 * np.sqrt(3) + 1e-5
        # the draw is cut as a view, not as the paper's crop
        assert not np.array_equal(s["points_src"], plain.get(i)["points_src"])


def test_view_share_mixes_and_is_reproducible(synthetic_root, monkeypatch):
    ds = data.ModelNet40(synthetic_root, "train", "partial", seed=0, views_share=0.5)
    again = data.ModelNet40(synthetic_root, "train", "partial", seed=0, views_share=0.5)
    for i in range(3):
        np.testing.assert_array_equal(ds.get(i, epoch=2)["points_src"], again.get(i, epoch=2)["points_src"])
    cut = []
    monkeypatch.setattr(views, "view_pair", lambda rng, src, ref: cut.append(1) or (src, ref))
    for i in range(len(ds)):
        ds.get(i, epoch=1)
    assert 0.25 * len(ds) <= len(cut) <= 0.75 * len(ds)  # about half the pairs are views, the rest crops


def test_view_share_is_for_partial_training_pairs_only(synthetic_root):
    with pytest.raises(ValueError, match="partial training pairs only"):
        data.ModelNet40(synthetic_root, "val", "partial", views_share=0.5)
    with pytest.raises(ValueError, match="partial training pairs only"):
        data.ModelNet40(synthetic_root, "train", "noisy", views_share=0.5)
    with pytest.raises(ValueError, match=r"views_share must be in \[0, 1\]"):
        data.ModelNet40(synthetic_root, "train", "partial", views_share=1.5)
