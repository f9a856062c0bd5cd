import json
import os

import numpy as np
import pytest

from experiments import pack_training_data
from rpmnet_jax import data
from rpmnet_jax.data import pack, synthetic


@pytest.fixture(scope="module")
def source(tmp_path_factory):
    root = tmp_path_factory.mktemp("src")
    synthetic.write_dataset(root, 30, 40, seed=3, n=256)  # 40 categories: train and val keep the first 20
    return str(root)


def test_pack_keeps_the_training_shapes_as_float16_subsets_and_no_test_split_shape(source, tmp_path):
    report = pack.pack([source], tmp_path / "pack", num_points=100, val_shapes=5, seed=1)
    name = os.path.basename(source)
    packed = str(tmp_path / "pack" / name)
    for split, expected in (("train", data.ModelNet40(source, "train", "partial")),
                            ("val", data.ModelNet40(source, "val", "partial"))):
        got = data.ModelNet40(packed, split, "partial")
        n = len(expected) if split == "train" else 5
        assert len(got) == n and got.points.shape[1:] == (100, 6)
        np.testing.assert_array_equal(got.labels, expected.labels[:n])
        for g, e in zip(got.points, expected.points[:n]):
            rows = {tuple(r) for r in e.astype(np.float16).astype(np.float32)}
            assert all(tuple(r) in rows for r in g)  # each packed point is one of the shape's own
            assert len({tuple(r) for r in g}) == 100  # without repeats
    assert len(data.ModelNet40(packed, "test", "partial")) == 0  # the last 20 categories: not packed
    assert report[name]["train"] == len(data.ModelNet40(source, "train", "partial")) and report[name]["val"] == 5
    sample = data.ModelNet40(packed, "train", "partial", num_points=64, seed=0)[0]  # trains as it is
    assert sample["points_src"].shape == (45, 6) and sample["points_src"].dtype == np.float32


def test_pack_refuses_an_existing_folder_and_leaves_nothing_on_a_bad_root(source, tmp_path, capsys):
    (tmp_path / "there").mkdir()
    with pytest.raises(FileExistsError):
        pack.pack([source], tmp_path / "there")
    rc = pack_training_data.main(["--data-root", f"{source},{tmp_path / 'missing'}", "--out", str(tmp_path / "p")])
    err = capsys.readouterr().err
    assert rc == 2 and "does not exist" in err and len(err.strip().splitlines()) == 1
    assert sorted(os.listdir(tmp_path)) == ["there"]
    rc = pack_training_data.main(["--data-root", source, "--out", str(tmp_path / "p"), "--num-points", "300"])
    assert rc == 2 and "more than the 256 points" in capsys.readouterr().err
    assert sorted(os.listdir(tmp_path)) == ["there"]


def test_cli_prints_the_sizes(source, tmp_path, capsys):
    rc = pack_training_data.main(["--data-root", source, "--out", str(tmp_path / "p"), "--num-points", "64"])
    line = json.loads(capsys.readouterr().out)
    files = [os.path.join(d, f) for d, _, fs in os.walk(tmp_path / "p") for f in fs if f.endswith(".h5")]
    assert rc == 0 and line["folders"][os.path.basename(source)]["bytes"] == sum(map(os.path.getsize, files))


@pytest.mark.slow  # the GPU script's CPU test: a 3-step training run of the full-size model (~90 s)
def test_gpu_train_script_tiny_brings_back_loadable_params(source, tmp_path):
    import subprocess
    import jax
    import rpmnet_jax
    from rpmnet_jax.weights import convert
    pack.pack([source], tmp_path / "pack", num_points=200, val_shapes=4)
    init = tmp_path / "v0_step1.npz"
    np.savez(init, **convert.params_to_torch(rpmnet_jax.init_params(jax.random.PRNGKey(0))))
    script = os.path.join(os.path.dirname(__file__), "..", "experiments", "gpu_train.sh")
    env = dict(os.environ, PACK=str(tmp_path / "pack"), INIT=str(init), OUT=str(tmp_path / "out"),
               TMPDIR=str(tmp_path))
    out = subprocess.run(["bash", script, "--tiny"], env=env, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["steps"] == 3 and [s for s, _ in summary["validation_err_r_deg_mean"]] == [2, 3]
    start = rpmnet_jax.load_params(str(init))
    for name in ("params_best.npz", "params_latest.npz"):
        got = rpmnet_jax.load_params(str(tmp_path / "out" / name))
        moved = jax.tree.map(lambda a, b: float(np.abs(np.asarray(a) - np.asarray(b)).max()), got, start)
        assert max(jax.tree.leaves(moved)) > 0  # trained: not the start
    assert not any(p.startswith("rpmnet_gpu_work") for p in os.listdir(tmp_path))  # its workdir is removed
