"""Multi-process training on jax.distributed: 2 processes × 2 CPU devices equal 1 process × 4 devices."""

import json
import os
import signal
import socket
import subprocess
import sys
import time

import numpy as np
import pytest

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

_WORKER = r"""
import json, sys
import jax
sys.path.insert(0, {tests!r})
from rpmnet_jax import train as training
if {processes} > 1:
    training.initialize_distributed({address!r}, {processes}, {pid})
from train_test import tiny_cfg
s = training.train_and_evaluate(tiny_cfg({workdir!r}, max_steps={steps}, val_limit=None), progress=False)
params = training.restore_params({workdir!r})  # every process reads the one checkpoint
norm = float(sum((x.astype("float64") ** 2).sum() for x in jax.tree.leaves(params)))
print(json.dumps({{"devices": s["devices"], "losses": s["losses"], "step": s["step"], "norm": norm,
                  "interrupted": s["interrupted"]}}))
"""


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("localhost", 0))
        return s.getsockname()[1]


def _start(processes: int, devices_each: int, workdir, steps: int) -> list[subprocess.Popen]:
    env = dict(os.environ, XLA_FLAGS=f"--xla_force_host_platform_device_count={devices_each}", JAX_PLATFORMS="cpu")
    address = f"localhost:{_free_port()}"
    return [subprocess.Popen([sys.executable, "-c", _WORKER.format(
        tests=os.path.dirname(__file__), processes=processes, address=address, pid=pid, workdir=str(workdir),
        steps=steps)], env=env, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        for pid in range(processes)]


def _finish(procs) -> list[dict]:
    outs = []
    for p in procs:
        out, err = p.communicate(timeout=900)
        assert p.returncode == 0, err[-3000:]
        outs.append(json.loads(out.strip().splitlines()[-1]))
    return outs


def _launch(processes: int, devices_each: int, workdir, steps: int) -> list[dict]:
    return _finish(_start(processes, devices_each, workdir, steps))


@pytest.mark.slow  # three processes that each compile training and validation
def test_two_processes_equal_one_process_with_four_devices(tmp_path):
    one = _launch(1, 4, tmp_path / "one", steps=3)[0]
    two = _launch(2, 2, tmp_path / "two", steps=3)
    assert one["devices"] == 4 and all(r["devices"] == 4 for r in two)
    for r in two:  # every process sees the same global losses
        np.testing.assert_allclose(r["losses"], one["losses"], rtol=1e-5)
    for r in two:  # the checkpoint, written once, restores the same parameters in every process
        np.testing.assert_allclose(r["norm"], one["norm"], rtol=1e-5)
    resumed = _launch(2, 2, tmp_path / "two", steps=4)  # both restore it and go on
    assert all(r["step"] == 4 and len(r["losses"]) == 1 for r in resumed)


@pytest.mark.slow  # two processes that each compile training and validation
def test_sigterm_to_one_process_stops_both_at_the_same_step(tmp_path):
    """SIGTERM reaches process 1 only: both agree on the stop step, save it once and exit cleanly."""
    procs = _start(2, 2, tmp_path / "run", steps=200)
    latest = tmp_path / "run" / "checkpoints" / "latest"
    deadline = time.time() + 600
    while time.time() < deadline and not (latest.is_dir() and any(p.isdigit() for p in os.listdir(latest))):
        assert all(p.poll() is None for p in procs), "a process ended before the signal"
        time.sleep(0.05)
    procs[1].send_signal(signal.SIGTERM)
    outs = _finish(procs)
    assert all(r["interrupted"] for r in outs) and outs[0]["step"] == outs[1]["step"] < 200
    saved = sorted(int(p) for p in os.listdir(latest) if p.isdigit())
    assert saved[-1] == outs[0]["step"]
