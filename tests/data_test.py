import os
import shutil
import subprocess
import sys

import h5py
import numpy as np
import pytest

from rpmnet_jax import data
from rpmnet_jax.data import loader
from rpmnet_jax.data import synthetic

from conftest import require, require_fixtures

KEYS = ("points_src", "points_ref", "transform_gt", "points_raw")


@pytest.fixture(scope="module")
def protocol_root():
    return require_fixtures() / "data_protocol" / "modelnet40_ply_hdf5_2048"


@pytest.fixture(scope="module")
def synthetic_root(tmp_path_factory):
    return synthetic.write_dataset(tmp_path_factory.mktemp("syn"), num_train=60, num_test=40, seed=1)


@pytest.mark.parametrize("protocol", data.PROTOCOLS)
def test_official_test_samples_bit_exact(protocol_root, protocol):
    with np.load(protocol_root.parent / "expected_test_samples.npz") as expected:
        ds = data.ModelNet40(protocol_root, "test", protocol)
        np.testing.assert_array_equal(ds.labels, expected["labels"])
        for i in range(8):
            sample = ds[i]
            for key in KEYS:
                np.testing.assert_array_equal(sample[key], expected[f"{protocol}/{i}/{key}"], err_msg=f"{i} {key}")


def test_global_numpy_state_untouched(protocol_root):
    np.random.seed(123)
    before = np.random.get_state()[1].copy()
    data.ModelNet40(protocol_root, "test", "partial")[0]
    np.testing.assert_array_equal(np.random.get_state()[1], before)


def test_split_sizes_and_category_filter(protocol_root):
    names = (protocol_root / "shape_names.txt").read_text().split()
    with h5py.File(protocol_root / "ply_data_train0.h5") as f:
        train_labels = f["label"][:].ravel()
    test_labels = np.concatenate([h5py.File(protocol_root / f"ply_data_test{i}.h5")["label"][:].ravel() for i in (0, 1)])
    for split, labels, half in (("train", train_labels, slice(0, 20)), ("val", test_labels, slice(0, 20)),
                                ("test", test_labels, slice(20, 40))):
        ds = data.ModelNet40(protocol_root, split, "clean")
        keep = np.isin(labels, np.arange(40)[half])
        assert len(ds) == keep.sum()
        np.testing.assert_array_equal(ds.labels, labels[keep])  # file order preserved
        assert ds.categories == names[half]


def test_val_test_deterministic_across_processes(protocol_root):
    ds = data.ModelNet40(protocol_root, "val", "partial")
    a, b = ds[3], ds[3]
    for key in KEYS:
        np.testing.assert_array_equal(a[key], b[key])
    code = ("import sys, numpy as np; from rpmnet_jax import data; "
            f"s = data.ModelNet40({str(protocol_root)!r}, 'val', 'partial')[3]; "
            "sys.stdout.write(str(float(np.sum(s['points_src'].astype(np.float64)))))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert float(out) == float(np.sum(a["points_src"].astype(np.float64)))


def test_train_random_per_epoch_reproducible_per_seed(synthetic_root):
    ds = data.ModelNet40(synthetic_root, "train", "noisy", seed=5)
    again = data.ModelNet40(synthetic_root, "train", "noisy", seed=5)
    other = data.ModelNet40(synthetic_root, "train", "noisy", seed=6)
    e0, e1 = ds.get(2, epoch=0), ds.get(2, epoch=1)
    assert not np.array_equal(e0["transform_gt"], e1["transform_gt"])
    np.testing.assert_array_equal(again.get(2, epoch=1)["points_src"], e1["points_src"])
    assert not np.array_equal(other.get(2, epoch=1)["transform_gt"], e1["transform_gt"])


@pytest.mark.parametrize("protocol", data.PROTOCOLS)
def test_transform_maps_clean_source_onto_reference(synthetic_root, protocol):
    ds = data.ModelNet40(synthetic_root, "test", protocol, seed=0)
    s = ds[1]
    gt = s["transform_gt"]
    src_back = s["points_src"][:, :3] @ gt[:, :3].T + gt[:, 3]
    raw = s["points_raw"][:, :3]
    # every aligned source point lies on the clean cloud (exactly for clean, within the jitter otherwise)
    d = np.sqrt(((src_back[:, None] - raw[None]) ** 2).sum(-1)).min(1)
    assert d.max() < (1e-5 if protocol == "clean" else 0.05 * np.sqrt(3) + 1e-5)
    normals_back = s["points_src"][:, 3:] @ gt[:, :3].T
    np.testing.assert_allclose(np.linalg.norm(normals_back, axis=1), 1, atol=1e-5)
    np.testing.assert_allclose(np.linalg.norm(s["points_ref"][:, 3:], axis=1), 1, atol=1e-5)
    if protocol == "partial":
        assert s["points_src"].shape == s["points_ref"].shape == (717, 6)


def test_crop_keeps_about_seventy_percent():
    rng = np.random.RandomState(0)
    pts = np.random.default_rng(0).normal(size=(2048, 6)).astype(np.float32)
    kept = [data.crop(rng, pts, np.float32(0.7)).shape[0] / 2048 for _ in range(20)]
    assert all(0.69 <= k <= 0.71 for k in kept)


def test_synthetic_normals_agree_with_estimated():
    """Analytic normals vs PCA normals of 10 nearest neighbours on dense (8192-point) samples, every family."""
    from scipy.spatial import cKDTree

    for label in range(10):
        cloud = synthetic.sample_shape(np.random.default_rng(label), label, 8192)
        xyz, normals = cloud[:, :3].astype(np.float64), cloud[:, 3:]
        _, nbrs = cKDTree(xyz).query(xyz, 10)
        local = xyz[nbrs] - xyz[nbrs].mean(1, keepdims=True)
        estimated = np.linalg.svd(local)[2][:, -1]
        angles = np.degrees(np.arccos(np.clip(np.abs((estimated * normals).sum(-1)), 0, 1)))
        assert np.median(angles) < 3.0, synthetic.CATEGORY_NAMES[label]
        np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1, atol=1e-5)
        assert np.linalg.norm(xyz, axis=1).max() <= 1 + 1e-5


def test_ring_views_are_partial_sides_each_in_its_own_frame():
    world = synthetic.sample_shape(np.random.default_rng(1), 2, 3000)[:, :3].astype(np.float64) * 0.1
    world -= world.mean(0)
    clouds, poses = synthetic.ring_views(world, 5)
    assert poses.shape == (5, 4, 4) and np.allclose(poses[0], np.eye(4)) and len(clouds) == 5
    for k, (c, pose) in enumerate(zip(clouds, poses)):
        back = c @ pose[:3, :3].T + pose[:3, 3]  # into the world frame: exactly the world's points of that side
        side = world[world[:, :2] @ [np.cos(2 * np.pi * k / 5), np.sin(2 * np.pi * k / 5)] > -0.01]
        np.testing.assert_allclose(back, side, atol=1e-12)
        assert 0.3 * len(world) < len(c) < 0.8 * len(world)
        if k:
            assert not np.allclose(c, side)  # moved out of the world frame
        np.testing.assert_allclose(pose[:3, :3] @ pose[:3, :3].T, np.eye(3), atol=1e-12)


def test_make_synthetic_cli(tmp_path):
    subprocess.run([sys.executable, "-m", "experiments.make_synthetic", "--out", str(tmp_path), "--num-train", "4",
                    "--num-test", "3"], check=True, capture_output=True, cwd=os.path.dirname(os.path.dirname(__file__)))
    points, labels, names = data.read_split(tmp_path, "test")
    assert points.shape == (3, 2048, 6) and len(names) == 40


def test_batches_fixed_shapes_shuffle_and_drop_remainder(synthetic_root):
    ds = data.ModelNet40(synthetic_root, "train", "partial", seed=0)  # 30 shapes in the first 20 categories
    epoch0 = list(loader.batches(ds, 8, shuffle=True, drop_remainder=True, epoch=0))
    assert len(epoch0) == len(ds) // 8
    assert all(b["points_src"].shape == (8, 717, 6) for b in epoch0)
    again = list(loader.batches(ds, 8, shuffle=True, drop_remainder=True, epoch=0, prefetch=0))
    for a, b in zip(epoch0, again):
        np.testing.assert_array_equal(a["points_src"], b["points_src"])
    epoch1 = next(loader.batches(ds, 8, shuffle=True, drop_remainder=True, epoch=1))
    assert not np.array_equal(epoch1["idx"], epoch0[0]["idx"])
    resumed = next(loader.batches(ds, 8, shuffle=True, drop_remainder=True, epoch=0, start_batch=2))
    np.testing.assert_array_equal(resumed["points_src"], epoch0[2]["points_src"])

def test_drop_remainder_drops_only_the_short_last_batch():
    sizes = lambda n, drop: [len(b) for b in loader.batch_indices(n, 8, shuffle=True, drop_remainder=drop)]
    assert sizes(43, True) == [8] * 5 and sizes(43, False) == [8] * 5 + [3]
    assert sizes(40, True) == sizes(40, False) == [8] * 5
    kept = np.concatenate(loader.batch_indices(43, 8, shuffle=True, drop_remainder=False, seed=2, epoch=1))
    np.testing.assert_array_equal(np.sort(kept), np.arange(43))  # a permutation: every sample once


def test_concat_draws_each_sample_by_its_global_index(synthetic_root):
    train = data.ModelNet40(synthetic_root, "train", "partial", num_points=64, seed=0)
    both = data.Concat([train, train])  # the same shapes twice: only the seeding can tell the halves apart
    n = len(train)
    for i in (0, 3):
        a, b = both.get(i, epoch=2), both.get(n + i, epoch=2)
        assert not np.array_equal(a["transform_gt"], b["transform_gt"])
        assert not np.array_equal(a["points_src"], b["points_src"])
        np.testing.assert_array_equal(a["points_src"], train.get(i, epoch=2)["points_src"])  # first source unchanged
        np.testing.assert_array_equal(b["points_src"], train.get(i, epoch=2, draw=n + i)["points_src"])
    val = data.ModelNet40(synthetic_root, "val", "partial", num_points=64)
    vals = data.Concat([val, val])  # the deterministic sets stay the official ones of each source
    np.testing.assert_array_equal(vals[len(val) + 1]["points_src"], val[1]["points_src"])


def test_loader_propagates_errors():
    class Broken:
        def __len__(self):
            return 4

        def __getitem__(self, i):
            raise RuntimeError("boom")

    with pytest.raises(RuntimeError, match="boom"):
        list(loader.batches(Broken(), 2))


def test_errors(tmp_path, synthetic_root):
    with pytest.raises(FileNotFoundError, match="modelnet40_ply_hdf5_2048.*make_synthetic"):
        data.ModelNet40(tmp_path / "nowhere", "test", "clean")
    (tmp_path / "empty").mkdir()
    with pytest.raises(FileNotFoundError, match="shape_names.txt"):
        data.ModelNet40(tmp_path / "empty", "test", "clean")
    with pytest.raises(ValueError, match="protocol"):
        data.ModelNet40(synthetic_root, "test", "jitter")
    with pytest.raises(ValueError, match="split"):
        data.ModelNet40(synthetic_root, "testing", "clean")
    broken = tmp_path / "broken"
    shutil.copytree(synthetic_root, broken)
    os.remove(broken / "ply_data_test0.h5")
    with pytest.raises(FileNotFoundError, match="ply_data_test0.h5"):
        data.ModelNet40(broken, "test", "clean")
    with h5py.File(broken / "ply_data_test0.h5", "w") as f:
        f["data"] = np.zeros((2, 2048, 3), np.float32)
        f["label"] = np.zeros((2, 1), np.uint8)
    with pytest.raises(ValueError, match="normal"):
        data.ModelNet40(broken, "test", "clean")
    with h5py.File(broken / "ply_data_test0.h5", "w") as f:
        f["data"] = np.zeros((2, 2048, 3), np.float32)
    with pytest.raises(KeyError, match="'label'"):
        data.ModelNet40(broken, "test", "clean")
    ds = data.ModelNet40(synthetic_root, "test", "clean")
    with pytest.raises(IndexError):
        ds[len(ds)]


def test_missing_test_data_fails_under_ci_and_skips_elsewhere(monkeypatch, tmp_path):
    monkeypatch.setenv("CI", "true")
    with pytest.raises(pytest.fail.Exception, match="CI=true"):
        require(tmp_path / "nowhere", "test data")
    monkeypatch.setenv("CI", "")
    with pytest.raises(pytest.skip.Exception):
        require(tmp_path / "nowhere", "test data")
    assert require(tmp_path, "test data") == tmp_path
