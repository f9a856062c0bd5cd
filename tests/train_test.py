import json
import os
import shutil
import subprocess
import sys

import jax
import numpy as np
import pytest

from rpmnet_jax import config as config_lib
from rpmnet_jax import data, losses
from rpmnet_jax import train as training
from rpmnet_jax.data import synthetic

TINY_MODEL = config_lib.RPMNetConfig(num_neighbors=8, feature_dim=16, num_reg_iters=2)
REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def tiny_cfg(workdir, **kw):
    base = dict(dataset="partial", synthetic=True, synthetic_train=40, synthetic_test=20, workdir=str(workdir),
                batch_size=4, num_points=64, val_limit=4, save_every=1, model=TINY_MODEL, lr=1e-3)
    base.update(kw)
    return training.TrainConfig(**base)


@pytest.fixture(scope="module")
def tiny_batch(tmp_path_factory):
    root = synthetic.write_dataset(tmp_path_factory.mktemp("syn"), 12, 4, seed=0)
    ds = data.ModelNet40(root, "train", "partial", num_points=64, seed=0)
    samples = [ds[i] for i in range(4)]
    return {k: np.stack([s[k] for s in samples]) for k in training.DEVICE_KEYS}


def test_first_step_loss_equals_the_training_loss_and_descends(tiny_batch):
    cfg = tiny_cfg("unused")
    state = training.create_train_state(jax.random.PRNGKey(0), cfg)
    expected = float(jax.jit(losses.training_loss, static_argnums=2)(state.params, tiny_batch, cfg.model))
    step = training.make_train_step(cfg)
    state, scalars = step(state, tiny_batch)
    np.testing.assert_allclose(scalars["loss"], expected, rtol=1e-5)
    first = float(scalars["loss"])
    for _ in range(15):
        state, scalars = step(state, tiny_batch)
    assert float(scalars["loss"]) < first
    assert int(state.step) == 16 and int(state.skipped) == 0


def test_ema_schedule_and_clipping(tiny_batch):
    """EMA after one step is decay·init + (1-decay)·params (by hand); warmup starts at lr 0, so the first
    update of a warmed-up run is zero; clipping keeps the step finite and the loss the same."""
    cfg = tiny_cfg("unused", ema_decay=0.9, lr_schedule="cosine", warmup_steps=3, lr_final=1e-5, clip_norm=0.1)
    state = training.create_train_state(jax.random.PRNGKey(0), cfg, total_steps=10)
    init = jax.tree.map(np.asarray, state.params)
    step = training.make_train_step(cfg, total_steps=10)
    state, _ = step(state, tiny_batch)
    jax.tree.map(np.testing.assert_array_equal, jax.tree.map(np.asarray, state.params), init)  # lr(0) = 0
    state, _ = step(state, tiny_batch)
    params, ema = jax.tree.map(np.asarray, state.params), jax.tree.map(np.asarray, state.ema)
    expected = jax.tree.map(lambda p0, p: 0.9 * (0.9 * p0 + 0.1 * p0) + 0.1 * p, init, params)
    jax.tree.map(lambda a, b: np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-7), ema, expected)
    assert any(np.any(a != b) for a, b in zip(jax.tree.leaves(params), jax.tree.leaves(init)))
    sched = training.step.learning_rate(cfg, 10)
    assert float(sched(0)) == 0.0 and float(sched(3)) == pytest.approx(1e-3) and float(sched(10)) == pytest.approx(1e-5)


def test_init_from_npz_starts_from_those_params(tmp_path):
    from rpmnet_jax.weights import convert
    params = training.create_train_state(jax.random.PRNGKey(7), tiny_cfg("unused")).params
    np.savez(tmp_path / "w.npz", **convert.params_to_torch(params))
    cfg = tiny_cfg(tmp_path / "run", max_steps=1, init_from=str(tmp_path / "w.npz"), lr=0.0)
    training.train_and_evaluate(cfg, progress=False)
    got = training.restore_params(str(tmp_path / "run"))
    jax.tree.map(lambda a, b: np.testing.assert_allclose(np.asarray(a), np.asarray(b), atol=1e-7), got, params)


def test_nonfinite_update_is_skipped(tiny_batch):
    cfg = tiny_cfg("unused")
    state = training.create_train_state(jax.random.PRNGKey(0), cfg)
    before = jax.tree.map(np.asarray, state.params)
    bad = dict(tiny_batch, transform_gt=np.full_like(tiny_batch["transform_gt"], np.nan))
    state, scalars = training.make_train_step(cfg)(state, bad)
    assert not bool(scalars["finite"]) and int(state.skipped) == 1 and int(state.nonfinite) == 1
    jax.tree.map(np.testing.assert_array_equal, jax.tree.map(np.asarray, state.params), before)


def test_resume_matches_uninterrupted_run(tmp_path):
    full = training.train_and_evaluate(tiny_cfg(tmp_path / "full", max_steps=4), progress=False)
    first = training.train_and_evaluate(tiny_cfg(tmp_path / "split", max_steps=2), progress=False)
    second = training.train_and_evaluate(tiny_cfg(tmp_path / "split", max_steps=4), progress=False)
    assert len(full["losses"]) == 4 and len(first["losses"]) == 2 and len(second["losses"]) == 2
    np.testing.assert_allclose(first["losses"] + second["losses"], full["losses"], rtol=1e-6)
    assert second["step"] == 4 and full["validation"] is not None
    saved = json.load(open(tmp_path / "split" / "config.json"))
    assert saved["model"]["feature_dim"] == 16
    params = training.restore_params(str(tmp_path / "split"))
    assert params["feat_extractor"]["postpool_6"]["kernel"].shape == (16, 16)


def test_corrupt_checkpoint_falls_back(tmp_path, caplog):
    cfg = tiny_cfg(tmp_path / "run", max_steps=2)
    training.train_and_evaluate(cfg, progress=False)
    latest = tmp_path / "run" / "checkpoints" / "latest"
    steps = sorted(int(p.name) for p in latest.iterdir() if p.name.isdigit())
    assert steps[-1] == 2 and 1 in steps
    for item in (latest / "2" / "default").iterdir():  # damage the newest checkpoint
        if item.is_dir():
            shutil.rmtree(item)
        else:
            item.write_bytes(b"garbage")
    ckpt = training.Checkpoints(str(tmp_path / "run"), 3)
    template = training.create_train_state(jax.random.PRNGKey(0), cfg)
    restored = ckpt.restore_latest(template)
    ckpt.close()
    assert int(restored.step) == 1
    assert "unreadable" in caplog.text
    for step in steps:  # nothing readable: a clear error
        for item in (latest / str(step) / "default").iterdir():
            if item.is_file():
                item.write_bytes(b"garbage")
            else:
                shutil.rmtree(item)
    ckpt = training.Checkpoints(str(tmp_path / "run"), 3)
    with pytest.raises(RuntimeError, match="no readable checkpoint"):
        ckpt.restore_latest(template)
    ckpt.close()


def test_resume_refuses_a_different_config(tmp_path):
    training.train_and_evaluate(tiny_cfg(tmp_path / "run", max_steps=1), progress=False)
    with pytest.raises(ValueError, match="different configuration"):
        training.train_and_evaluate(tiny_cfg(tmp_path / "run", max_steps=2, lr=5e-4), progress=False)


_MULTI = r"""
import json, sys, jax, numpy as np
sys.path.insert(0, {tests!r})
from train_test import tiny_cfg
from rpmnet_jax import train as training
s = training.train_and_evaluate(tiny_cfg({workdir!r}, max_steps=3, val_limit=None), progress=False)
params = training.restore_params({workdir!r})
print(json.dumps({{"devices": s["devices"], "losses": s["losses"],
                  "norm": float(sum(np.sum(np.asarray(x, np.float64) ** 2) for x in jax.tree.leaves(params)))}}))
"""


def _run_with_devices(n, workdir):
    env = dict(os.environ, XLA_FLAGS=f"--xla_force_host_platform_device_count={n}", JAX_PLATFORMS="cpu")
    code = _MULTI.format(tests=os.path.dirname(__file__), workdir=str(workdir))
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, cwd=REPO)
    assert out.returncode == 0, out.stderr[-3000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.mark.slow  # two subprocesses that each compile training and validation (~100 s)
def test_four_devices_match_one(tmp_path):
    one = _run_with_devices(1, tmp_path / "one")
    four = _run_with_devices(4, tmp_path / "four")
    assert one["devices"] == 1 and four["devices"] == 4
    np.testing.assert_allclose(four["losses"], one["losses"], rtol=1e-4)
    np.testing.assert_allclose(four["norm"], one["norm"], rtol=1e-4)


def test_cli_help_and_bad_flags():
    run = lambda *a: subprocess.run([sys.executable, "-m", "experiments.train", *a], capture_output=True, text=True,
                                    cwd=REPO)
    out = run("--help")
    assert out.returncode == 0 and "--max-steps" in out.stdout and "--anneal" in out.stdout
    out = run("--dataset=noisy")
    assert out.returncode == 2 and "--data-root" in out.stderr and "--synthetic" in out.stderr
    out = run("--dataset=jitter", "--synthetic")
    assert out.returncode == 2 and "invalid choice" in out.stderr
    out = run("--synthetic", "--features", "xyz,normals")
    assert out.returncode == 2 and "features" in out.stderr
    out = run("--data-root", "/nonexistent/modelnet")
    assert out.returncode == 2 and "does not exist" in out.stderr


_KILLABLE = r"""
import sys
sys.path.insert(0, {tests!r})
from train_test import tiny_cfg
from rpmnet_jax import train as training
training.train_and_evaluate(tiny_cfg({workdir!r}, max_steps={steps}, val_limit=None), progress=False)
"""


def _train_script(workdir, steps):
    code = _KILLABLE.format(tests=os.path.dirname(__file__), workdir=str(workdir), steps=steps)
    return [sys.executable, "-c", code]


def _params_of(workdir):
    ckpt = training.Checkpoints(str(workdir), 3)
    try:
        template = training.create_train_state(jax.random.PRNGKey(0), tiny_cfg(workdir))
        state = ckpt.restore_latest(template)
    finally:
        ckpt.close()
    return int(state.step), jax.tree.leaves(state.params)


@pytest.mark.slow  # three training processes, each compiling (~1 min)
@pytest.mark.parametrize("moment", ["training", "checkpoint_write"])
def test_sigkill_then_resume_is_bit_identical(tmp_path, moment):
    """SIGKILL (no handler runs) while training, or as a checkpoint write begins; the resumed run ends with
    exactly the parameters of an uninterrupted one."""
    import time

    steps = 6
    subprocess.run(_train_script(tmp_path / "full", steps), check=True, cwd=REPO, capture_output=True)
    latest = tmp_path / "killed" / "checkpoints" / "latest"
    proc = subprocess.Popen(_train_script(tmp_path / "killed", steps), cwd=REPO, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    deadline = time.time() + 300
    while time.time() < deadline and proc.poll() is None:
        entries = os.listdir(latest) if latest.is_dir() else []
        done = [e for e in entries if e.isdigit()]
        if moment == "checkpoint_write" and len(entries) > len(done) and done:
            break  # a temporary folder of a write in progress, after at least one finished checkpoint
        if moment == "training" and len(done) >= 2:
            time.sleep(0.3)  # mid-step
            break
        time.sleep(0.005)
    assert proc.poll() is None, "the run ended before it could be killed"
    proc.kill()
    proc.wait()
    killed_at, _ = _params_of(tmp_path / "killed")
    assert 0 < killed_at < steps
    subprocess.run(_train_script(tmp_path / "killed", steps), check=True, cwd=REPO, capture_output=True)
    step_a, full = _params_of(tmp_path / "full")
    step_b, resumed = _params_of(tmp_path / "killed")
    assert step_a == step_b == steps
    for a, b in zip(full, resumed):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


@pytest.mark.slow  # two CLI runs of the full-size model (~1 min)
def test_cli_prints_resume_and_validation_lines(tmp_path):
    args = [sys.executable, "-m", "experiments.train", "--dataset=partial", "--synthetic", "--synthetic-train", "8",
            "--synthetic-test", "4", "--num-points", "32", "--batch-size", "2", "--val-limit", "2", "--no-progress",
            "--workdir", str(tmp_path / "run")]
    first = subprocess.run(args + ["--max-steps", "1"], capture_output=True, text=True, cwd=REPO)
    assert first.returncode == 0, first.stderr[-2000:]
    assert "validation" in first.stderr and "summary" in first.stdout
    second = subprocess.run(args + ["--max-steps", "2"], capture_output=True, text=True, cwd=REPO)
    assert second.returncode == 0, second.stderr[-2000:]
    assert "resumed from step 1" in second.stderr and "step 2 validation" in second.stderr
