import dataclasses
import json
import os
import shutil
import subprocess
import sys

import jax
import numpy as np
import optax
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


def _grads(cfg, params, batch):
    return jax.tree.map(np.asarray, jax.jit(jax.grad(losses.training_loss), static_argnums=2)(params, batch, cfg.model))


def _states(tree, kind):
    """The optimizer sub-states of type ``kind`` (e.g. ``optax.ScaleByAdamState``) in ``tree``."""
    return [x for x in jax.tree.leaves(tree, is_leaf=lambda x: isinstance(x, kind)) if isinstance(x, kind)]


def test_first_step_golden_loss_adam_update_and_descent(tiny_batch):
    """The first loss is the stored value (recorded when this test was written: any change of data, init,
    network or loss moves it); Adam's moments hold the loss's gradient g, (1-b1)·g and (1-b2)·g², and the
    update is Adam's by hand from them, -lr·m̂/(sqrt(v̂)+eps); the loss then descends."""
    cfg = tiny_cfg("unused")
    state = training.create_train_state(jax.random.PRNGKey(0), cfg)
    before = jax.tree.map(np.asarray, state.params)
    grads = _grads(cfg, state.params, tiny_batch)
    step = training.make_train_step(cfg)
    state, scalars = step(state, tiny_batch)
    assert float(scalars["loss"]) == pytest.approx(0.462150455, rel=1e-5)
    (adam,) = _states(state.opt_state, optax.ScaleByAdamState)
    mu, nu = jax.tree.map(np.asarray, adam.mu), jax.tree.map(np.asarray, adam.nu)
    close = lambda a, b: np.testing.assert_allclose(a, b, rtol=1e-3, atol=1e-3 * np.abs(b).max())
    jax.tree.map(lambda m, g: close(m / 0.1, g), mu, grads)
    jax.tree.map(lambda v, g: close(v / 0.001, g * g), nu, grads)
    expected = jax.tree.map(lambda p, m, v: p - cfg.lr * (m / 0.1) / (np.sqrt(v / 0.001) + 1e-8), before, mu, nu)
    jax.tree.map(lambda a, b: np.testing.assert_allclose(a, b, rtol=0, atol=5e-7),  # ≪ lr: the step is checked
                 jax.tree.map(np.asarray, state.params), expected)
    first = float(scalars["loss"])
    for _ in range(15):
        state, scalars = step(state, tiny_batch)
    assert float(scalars["loss"]) < first
    assert int(state.step) == 16 and int(state.skipped) == 0


@pytest.mark.slow  # compiles the train step with EMA and clipping (~40 s)
def test_ema_schedule_and_clipping(tiny_batch):
    """EMA after two steps is decay·(decay·p0 + (1-decay)·p0) + (1-decay)·p (by hand); warmup starts at lr 0, so
    the first update is zero; clipping: Adam's first moment is (1-b1)·g·clip/|g| (by hand)."""
    cfg = tiny_cfg("unused", ema_decay=0.9, lr_schedule="cosine", warmup_steps=3, lr_final=1e-5, clip_norm=0.1)
    state = training.create_train_state(jax.random.PRNGKey(0), cfg, total_steps=10)
    init = jax.tree.map(np.asarray, state.params)
    grads = _grads(cfg, state.params, tiny_batch)
    norm = np.sqrt(sum(np.sum(np.asarray(g, np.float64) ** 2) for g in jax.tree.leaves(grads)))
    assert norm > 0.2  # the clip binds: unclipped moments would be more than twice as large
    step = training.make_train_step(cfg, total_steps=10)
    state, _ = step(state, tiny_batch)
    jax.tree.map(np.testing.assert_array_equal, jax.tree.map(np.asarray, state.params), init)  # lr(0) = 0
    (adam,) = _states(state.opt_state, optax.ScaleByAdamState)
    jax.tree.map(lambda m, g: np.testing.assert_allclose(m, 0.1 * g * 0.1 / norm, rtol=1e-3,
                                                         atol=1e-3 * np.abs(0.1 * g * 0.1 / norm).max()),
                 jax.tree.map(np.asarray, adam.mu), grads)
    state, _ = step(state, tiny_batch)
    params, ema = jax.tree.map(np.asarray, state.params), jax.tree.map(np.asarray, state.ema)
    expected = jax.tree.map(lambda p0, p: 0.9 * (0.9 * p0 + 0.1 * p0) + 0.1 * p, init, params)
    jax.tree.map(lambda a, b: np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-7), ema, expected)
    assert any(np.any(a != b) for a, b in zip(jax.tree.leaves(params), jax.tree.leaves(init)))
    sched = training.step.learning_rate(cfg, 10)
    assert float(sched(0)) == 0.0 and float(sched(3)) == pytest.approx(1e-3) and float(sched(10)) == pytest.approx(1e-5)


@pytest.mark.slow  # compiles a train step at lr 0 (~30 s)
def test_init_from_npz_starts_from_those_params(tmp_path):
    from rpmnet_jax.weights import convert
    params = training.create_train_state(jax.random.PRNGKey(7), tiny_cfg("unused")).params
    np.savez(tmp_path / "w.npz", **convert.params_to_torch(params))
    cfg = tiny_cfg(tmp_path / "run", max_steps=1, init_from=str(tmp_path / "w.npz"), lr=0.0)
    training.train_and_evaluate(cfg, progress=False)
    got = training.restore_params(str(tmp_path / "run"))
    jax.tree.map(lambda a, b: np.testing.assert_allclose(np.asarray(a), np.asarray(b), atol=1e-7), got, params)


def test_nonfinite_update_is_skipped_and_the_schedule_follows_the_step(tiny_batch):
    cfg = tiny_cfg("unused", lr_schedule="cosine", warmup_steps=3)
    state = training.create_train_state(jax.random.PRNGKey(0), cfg, total_steps=10)
    before = jax.tree.map(np.asarray, state.params)
    bad = dict(tiny_batch, transform_gt=np.full_like(tiny_batch["transform_gt"], np.nan))
    step = training.make_train_step(cfg, total_steps=10)
    state, scalars = step(state, bad)
    assert not bool(scalars["finite"]) and int(state.skipped) == 1 and int(state.nonfinite) == 1
    jax.tree.map(np.testing.assert_array_equal, jax.tree.map(np.asarray, state.params), before)
    (schedule,) = _states(state.opt_state, optax.ScaleByScheduleState)
    (adam,) = _states(state.opt_state, optax.ScaleByAdamState)
    assert int(schedule.count) == int(state.step) == 1  # the learning rate is that of step 1
    assert int(adam.count) == 0 and all(not np.any(np.asarray(m)) for m in jax.tree.leaves(adam.mu))  # no update
    state, scalars = step(state, tiny_batch)
    (schedule,) = _states(state.opt_state, optax.ScaleByScheduleState)
    assert bool(scalars["finite"]) and int(schedule.count) == int(state.step) == 2 and int(state.nonfinite) == 0


@pytest.mark.slow  # three short training runs (~60 s)
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


def _damage(step_dir, how):
    for item in (step_dir / "default").iterdir():
        if item.is_dir():
            shutil.rmtree(item)
        elif how == "garbage":
            item.write_bytes(b"garbage")
        else:
            item.unlink()


def _restore(workdir, cfg):
    ckpt = training.Checkpoints(str(workdir), 3)
    try:
        return ckpt.restore_latest(training.create_train_state(jax.random.PRNGKey(0), cfg))
    finally:
        ckpt.close()


def _save_steps(workdir, cfg, steps, best=None):
    """Checkpoints of a fresh state at ``steps`` (no training: nothing to compile)."""
    state = training.create_train_state(jax.random.PRNGKey(0), cfg)
    ckpt = training.Checkpoints(str(workdir), 3)
    try:
        for step in steps:
            ckpt.save(state._replace(step=np.int32(step)), best_metric=best)
    finally:
        ckpt.close()


def test_restore_says_what_failed_and_sets_damaged_steps_aside(tmp_path, caplog):
    cfg = tiny_cfg(tmp_path / "run")
    _save_steps(tmp_path / "run", cfg, [1, 2, 3])
    root = tmp_path / "run" / "checkpoints"
    steps = lambda: sorted(int(p.name) for p in (root / "latest").iterdir() if p.name.isdigit())
    assert steps() == [1, 2, 3]
    other = tiny_cfg(tmp_path / "run", model=config_lib.RPMNetConfig(num_neighbors=8, feature_dim=32, num_reg_iters=2))
    with pytest.raises(training.CheckpointError, match=r"step 3 .* does not fit this run: .*float32\[32"):
        _restore(tmp_path / "run", other)  # a different network: shapes differ
    with pytest.raises(training.CheckpointError, match="does not fit this run: it has (no )?opt_state/"):
        _restore(tmp_path / "run", tiny_cfg(tmp_path / "run", clip_norm=1.0))  # a different optimizer
    assert steps() == [1, 2, 3]  # a mismatch damages nothing
    _damage(root / "latest" / "3", "garbage")
    _damage(root / "latest" / "2", "missing")
    assert int(_restore(tmp_path / "run", cfg).step) == 1
    assert "step 3 is damaged" in caplog.text and "step 2 has files missing" in caplog.text
    assert steps() == [1] and sorted(p.name for p in (root / "damaged").iterdir()) == ["2", "3"]  # for good
    _damage(root / "latest" / "1", "garbage")
    with pytest.raises(training.CheckpointError, match="no usable checkpoint.*step 1 is damaged"):
        _restore(tmp_path / "run", cfg)
    assert steps() == [] and _restore(tmp_path / "run", cfg) is None  # the next run starts afresh


def test_restore_params_reports_missing_and_damaged(tmp_path):
    with pytest.raises(FileNotFoundError, match="no orbax checkpoint"):
        (tmp_path / "empty").mkdir()
        training.restore_params(str(tmp_path / "empty"))
    _save_steps(tmp_path / "run", tiny_cfg(tmp_path / "run"), [1], best=0.5)
    best = tmp_path / "run" / "checkpoints" / "best" / "1"
    _damage(best, "garbage")
    with pytest.raises(ValueError, match="step 1 in .*best is damaged"):
        training.restore_params(str(tmp_path / "run"))


def test_resume_refuses_a_changed_schedule_or_data_order(tmp_path):
    from rpmnet_jax.train import config as train_config
    train_config.check_and_save(tiny_cfg(tmp_path / "const", max_steps=4))
    train_config.check_and_save(tiny_cfg(tmp_path / "const", max_steps=8, epochs=7))  # a constant lr: extendable
    cosine = dict(lr_schedule="cosine", warmup_steps=2, max_steps=4)
    train_config.check_and_save(tiny_cfg(tmp_path / "cos", **cosine))
    for change, named in ((dict(max_steps=8), "max_steps"), (dict(epochs=7), "epochs"), (dict(batch_size=8), "batch_size"),
                          (dict(warmup_steps=0), "warmup_steps"), (dict(lr_final=1e-6), "lr_final"),
                          (dict(lr_schedule="constant"), "lr_schedule"), (dict(lr=5e-4), "lr")):
        with pytest.raises(training.ConfigMismatchError, match=f"different {named}: {named} ") as e:
            train_config.check_and_save(tiny_cfg(tmp_path / "cos", **{**cosine, **change}))
        assert e.value.settings == (named,) and "\n" not in str(e.value)
    faster = dataclasses.replace(TINY_MODEL, fused_prepool=not TINY_MODEL.fused_prepool)  # speed only: allowed
    train_config.check_and_save(tiny_cfg(tmp_path / "cos", **cosine, model=faster))
    train_config.check_and_save(tiny_cfg(tmp_path / "default_bs", batch_size=None))  # partial: 8
    train_config.check_and_save(tiny_cfg(tmp_path / "default_bs", batch_size=8))


def test_cli_names_the_setting_a_resume_may_not_change(tmp_path, capsys):
    from rpmnet_jax.cli import train as train_cli
    from rpmnet_jax.train import config as train_config
    train_config.check_and_save(tiny_cfg(tmp_path / "run", batch_size=4))
    code = train_cli.main(["--dataset=partial", "--synthetic", "--batch-size", "8", "--workdir", str(tmp_path / "run")])
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert "batch_size 4 there, 8 now" in err and "--batch-size" in err


def test_cli_refuses_a_crafted_init_from_checkpoint(tmp_path, capsys):
    pytest.importorskip("torch")
    from conftest import crafted_checkpoint
    from rpmnet_jax.cli import train as train_cli
    marker = tmp_path / "ran"
    evil = crafted_checkpoint(tmp_path / "evil.pth", marker)
    code = train_cli.main(["--synthetic", "--init-from", evil, "--workdir", str(tmp_path / "run"), "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("rpmnet-train: error:") and "refused" in err
    assert len(err.strip().splitlines()) == 1, err
    assert not marker.exists() and not (tmp_path / "run" / "checkpoints").exists()


def _send_once(monkeypatch, owner, name, signum, when=lambda *a: True):
    """Wraps ``owner.name`` to send ``signum`` to this process the first time ``when(*args)`` holds."""
    original, sent = getattr(owner, name), []

    def wrapper(*args, **kw):
        out = original(*args, **kw)
        if not sent and when(*args):
            sent.append(True)
            os.kill(os.getpid(), signum)
        return out

    monkeypatch.setattr(owner, name, wrapper)


def _saved_steps(workdir, which="latest"):
    folder = workdir / "checkpoints" / which
    return sorted(int(p.name) for p in folder.iterdir() if p.name.isdigit()) if folder.is_dir() else []


@pytest.mark.slow  # a short training run, interrupted twice (~20 s)
def test_sigint_saves_once_and_each_step_is_validated_once(tmp_path, monkeypatch, caplog):
    """--val-every-steps equal to the epoch (5 steps): step 5 is validated once; Ctrl-C at step 6 saves step 6
    (once) and returns, with the SIGINT handler restored."""
    import logging
    import signal
    caplog.set_level(logging.INFO, logger="rpmnet_jax")
    handler = signal.getsignal(signal.SIGINT)
    cfg = tiny_cfg(tmp_path / "run", max_steps=9, save_every=100, val_every_steps=5)
    _send_once(monkeypatch, training.loop, "_log_scalars", signal.SIGINT, lambda w, step, sc: step == 6)
    s = training.train_and_evaluate(cfg, progress=False)
    assert s["interrupted"] and s["step"] == 6 and len(s["losses"]) == 6
    validated = [int(r.getMessage().split()[1]) for r in caplog.records if " validation {" in r.getMessage()]
    assert validated == [5] and _saved_steps(tmp_path / "run") == [5, 6]
    assert signal.getsignal(signal.SIGINT) is handler


def test_sigterm_during_validation_stops_it_and_saves(tmp_path, monkeypatch):
    import signal
    from rpmnet_jax import metrics
    cfg = tiny_cfg(tmp_path / "run", max_steps=6, save_every=100, val_every_steps=2, val_limit=8)  # 2 val batches
    _send_once(monkeypatch, metrics, "registration_metrics", signal.SIGTERM)
    s = training.train_and_evaluate(cfg, progress=False)
    assert s["interrupted"] and s["step"] == 2 and s["validation"] is None
    assert _saved_steps(tmp_path / "run") == [2] and _saved_steps(tmp_path / "run", "best") == []


def test_due_validates_each_step_once():
    cfg = tiny_cfg("unused", val_every_steps=5, save_every=3, val_every=2)
    plan = {s: training.loop.due(s, 5, 23, cfg) for s in range(1, 24)}
    assert [s for s, (v, _) in plan.items() if v] == [5, 10, 15, 20, 23]
    assert [s for s, (v, save) in plan.items() if save and not v] == [3, 6, 9, 12, 18, 21]
    cfg = tiny_cfg("unused", val_every_steps=None, save_every=100, val_every=2)
    assert [s for s in range(1, 24) if training.loop.due(s, 5, 23, cfg)[0]] == [10, 20, 23]
    assert [s for s in range(1, 24) if training.loop.due(s, 5, 23, cfg)[1]] == [5, 10, 15, 20, 23]


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


def test_cli_help_and_bad_flags(capsys):
    from rpmnet_jax.cli import train as train_cli
    out = subprocess.run([sys.executable, "-m", "experiments.train", "--help"], capture_output=True, text=True,
                         cwd=REPO)
    assert out.returncode == 0 and "--max-steps" in out.stdout and "--anneal" in out.stdout

    def refused(*argv):
        with pytest.raises(SystemExit) as e:
            train_cli.parse_args(list(argv))
        assert e.value.code == 2
        return capsys.readouterr().err

    err = refused("--dataset=noisy")
    assert "--data-root" in err and "--synthetic" in err
    assert "invalid choice" in refused("--dataset=jitter", "--synthetic")
    assert "features" in refused("--synthetic", "--features", "xyz,normals")
    assert "does not exist" in refused("--data-root", "/nonexistent/modelnet")
    assert "--views-share needs --dataset=partial" in refused("--synthetic", "--views-share", "0.5")
    assert "--views-share must be in [0, 1]" in refused("--synthetic", "--dataset=partial", "--views-share", "2")


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


def test_rot_mag_sets_the_training_rotations_only_and_is_kept_on_resume(tmp_path):
    import json
    from rpmnet_jax.ops import se3
    from rpmnet_jax.train import config as train_config
    from rpmnet_jax.train import loop as train_loop
    cfg = tiny_cfg(tmp_path / "run", rot_mag=180.0)
    train_config.check_and_save(cfg)
    train_set, val_set = train_loop.datasets(cfg)
    angle = lambda s: float(se3.rotation_angle_deg(s["transform_gt"][:, :3]))
    train_angles = [angle(train_set.get(i)) for i in range(len(train_set))]
    val_angles = [angle(val_set.get(i)) for i in range(len(val_set))]
    assert max(train_angles) > 100.0  # beyond what 45 degrees per Euler axis give (< 84 in 20,000 draws)
    assert max(val_angles) < 90.0  # validation stays at the paper's 45 degrees per axis
    with pytest.raises(training.ConfigMismatchError, match="rot_mag 180.0 there, 45.0 now"):
        train_config.check_and_save(tiny_cfg(tmp_path / "run"))
    saved = json.loads((tmp_path / "run" / "config.json").read_text())
    del saved["rot_mag"]  # a run saved before the setting existed trained at 45 degrees
    (tmp_path / "run" / "config.json").write_text(json.dumps(saved))
    train_config.check_and_save(tiny_cfg(tmp_path / "run"))


def test_views_share_cuts_training_pairs_only_and_is_kept_on_resume(tmp_path):
    import json
    from rpmnet_jax.train import config as train_config
    from rpmnet_jax.train import loop as train_loop
    cfg = tiny_cfg(tmp_path / "run", views_share=1.0)
    train_config.check_and_save(cfg)
    train_set, val_set = train_loop.datasets(cfg)
    plain_train, plain_val = train_loop.datasets(tiny_cfg(tmp_path / "plain"))
    assert not np.array_equal(train_set.get(0)["points_src"], plain_train.get(0)["points_src"])
    np.testing.assert_array_equal(val_set.get(0)["points_src"], plain_val.get(0)["points_src"])  # the paper's crops
    with pytest.raises(training.ConfigMismatchError, match="views_share 1.0 there, 0.0 now"):
        train_config.check_and_save(tiny_cfg(tmp_path / "run"))
    saved = json.loads((tmp_path / "run" / "config.json").read_text())
    del saved["views_share"]  # a run saved before the setting existed used the paper's crops only
    (tmp_path / "run" / "config.json").write_text(json.dumps(saved))
    train_config.check_and_save(tiny_cfg(tmp_path / "run"))
