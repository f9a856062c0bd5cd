"""Faults on a real Dask cluster (a ``dask scheduler`` and ``dask worker`` processes started here, small synthetic
scans): every worker killed mid-run stops ``rpmnet-register-scans`` with one line (exit 1) within the timeout, the
cache keeping what finished, and the same command resumes once a worker is back; a scheduler without workers stops
it the same way; a task that kills every worker running it stops it with one line naming its pair; one of two
workers killed mid-run gives the in-process poses; an embedded cluster's worker sizes Numba's,
BLAS's and XLA's threads to its one thread. Each kill happens when the first pair result is back (in the progress
callback), not after a guessed sleep."""

import collections
import json
import os
import re
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

import rpmnet_jax
from conftest import ring_scans, rotation_error_deg
from rpmnet_jax.cli import register_scans
from rpmnet_jax.io import clouds as cloud_io
from rpmnet_jax.pair_edges import pair_engine

distributed = pytest.importorskip("distributed")

OPTIONS = rpmnet_jax.ScanOptions(num_points=64, num_iters=2, batch_size=2, refine_points=500)  # small: seconds
STAGE = "classical edges"  # the pair stage of five ring scans: ten pair tasks, none of them through the network


class Cluster:
    """A ``dask scheduler`` process and the ``dask worker`` processes added to it (one thread each, sized so, no
    nanny: a SIGKILLed worker stays dead). The scheduler's memory manager, which drops the copies of data that no
    two workers need, runs every 20 ms (2 s by default): as deep into a long run, spare copies are gone when a
    worker is killed (a scattered scan's only copy could go with it)."""

    def __init__(self, folder, **scheduler_env):
        self.bin = os.path.dirname(sys.executable)
        self.env = dict(os.environ, JAX_PLATFORMS="cpu", **pair_engine.worker_environment(1))
        self.file = folder / "scheduler.json"
        self.scheduler = subprocess.Popen(
            [os.path.join(self.bin, "dask"), "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
             "--scheduler-file", str(self.file)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
            env=dict(self.env, DASK_DISTRIBUTED__SCHEDULER__ACTIVE_MEMORY_MANAGER__INTERVAL="20ms", **scheduler_env))
        self.workers = []
        try:
            deadline = time.time() + 60
            while not self.file.exists() and time.time() < deadline:
                assert self.scheduler.poll() is None, "the scheduler ended"
                time.sleep(0.1)
            time.sleep(0.2)  # the file is written whole, then read
            self.address = json.loads(self.file.read_text())["address"]
        except BaseException:
            self.close()
            raise

    def add_workers(self, count: int, nanny: bool = False, preload: str | None = None) -> list:
        """Starts ``count`` more workers (``nanny``: each restarted when it dies; ``preload``: a module each runs
        as it starts) and waits until the scheduler has them all; returns them."""
        extra = ["--nanny" if nanny else "--no-nanny"] + (["--preload", preload] if preload else [])
        new = [subprocess.Popen([os.path.join(self.bin, "dask"), "worker", "--nthreads", "1", *extra,
                                 "--no-dashboard", "--name", f"w{len(self.workers) + k}", "--scheduler-file",
                                 str(self.file)], env=self.env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                start_new_session=True)  # its own process group: a nanny's worker goes with it
               for k in range(count)]
        self.workers += new
        alive = sum(w.poll() is None for w in self.workers)
        with distributed.Client(self.address, timeout="30s") as client:
            client.wait_for_workers(alive, timeout=120)
        return new

    def close(self) -> None:  # the workers hold nothing worth a clean shutdown
        for p in self.workers:
            try:
                os.killpg(p.pid, signal.SIGKILL)
            except ProcessLookupError:  # the group is gone
                pass
        for p in [*self.workers, self.scheduler]:
            if p.poll() is None:
                p.kill()
            p.wait(timeout=30)


@pytest.fixture
def cluster(tmp_path):
    c = Cluster(tmp_path)
    try:
        yield c
    finally:
        c.close()


def _write_scans(folder, count: int = 5) -> list:
    clouds, _ = ring_scans(count)
    paths = [str(folder / f"scan{k}.npy") for k in range(count)]
    for path, cloud in zip(paths, clouds):
        cloud_io.write_cloud(path, cloud)
    return paths


def _kill(workers) -> None:
    for w in workers:
        w.send_signal(signal.SIGKILL)
    for w in workers:
        assert w.wait(timeout=30) == -signal.SIGKILL


def test_every_worker_gone_stops_in_one_line_the_cache_keeps_what_finished_and_the_command_resumes(
        cluster, tmp_path, capsys, monkeypatch, random_weights):
    monkeypatch.setattr(pair_engine, "NO_WORKERS_TIMEOUT", 3.0)  # 60 s by default
    monkeypatch.setattr(pair_engine, "RESULT_TIMEOUT", 2.0)
    workers = cluster.add_workers(2)
    cache = tmp_path / "cache"
    command = _write_scans(tmp_path) + ["--checkpoint", random_weights, "--scheduler", cluster.address, "--cache",
                                        str(cache), "--refine", "none", "--out-poses", str(tmp_path / "poses.conf")]
    reports, killed = [], []

    class KillingBars:  # the CLI's progress bars: both workers killed when the first pair result is back
        def __init__(self, quiet=False):
            pass

        def __call__(self, stage, done, total):
            reports.append((stage, done, total))
            if stage == STAGE and not killed:
                _kill(workers)
                killed.append(time.monotonic())

        def close(self):
            pass

    monkeypatch.setattr(register_scans.runtime, "ProgressBars", KillingBars)
    rc = register_scans.main(command)
    waited = time.monotonic() - killed[0]
    err = capsys.readouterr().err
    kept = [f for f in os.listdir(cache) if f.endswith(".npz")]
    first = next(r for r in reports if r[0] == STAGE)
    summary = (f"killed both workers at {first[1]} of {first[2]} pairs; stopped {waited:.1f} s later with "
               f"{len(kept)} results kept: {err.strip()}")
    assert rc == 1 and len(err.strip().splitlines()) == 1, err
    assert re.search(rf"no Dask workers at {cluster.address} for 3 s, \d of 10 pairs of this stage still to run; "
                     "the cache keeps the pairs that finished: the same command resumes", err), err
    assert 3 <= waited < 20  # the timeout, not a hang
    finished = [done for stage, done, _ in reports if stage == STAGE][-1]
    assert 1 <= len(kept) == finished < 10 and not (tmp_path / "poses.conf").exists()

    cluster.add_workers(1)  # the same command, a worker back: only the pairs left run
    monkeypatch.undo()
    rc = register_scans.main(command)
    out = capsys.readouterr().out
    print(summary)  # after capsys' last read
    assert rc == 0 and (tmp_path / "poses.conf").exists()
    assert f"{len(kept)} pair results reused, {10 - len(kept)} computed" in out, out


def test_a_scheduler_without_workers_stops_in_one_line_within_the_timeout(cluster, tmp_path, capsys, monkeypatch,
                                                                         random_weights):
    monkeypatch.setattr(pair_engine, "NO_WORKERS_TIMEOUT", 2.0)
    start = time.monotonic()
    rc = register_scans.main(_write_scans(tmp_path, 3) + ["--checkpoint", random_weights, "--scheduler",
                                                          cluster.address, "--out-poses", str(tmp_path / "p.conf")])
    waited, err = time.monotonic() - start, capsys.readouterr().err
    assert rc == 1 and len(err.strip().splitlines()) == 1, err
    assert f"no Dask workers at {cluster.address} for 2 s, 3 of 3 scans still to prepare; no cache" in err  # the
    # scans are prepared on the workers too
    assert 2 <= waited < 15  # the timeout, not a hang
    assert not (tmp_path / "p.conf").exists()


@pytest.mark.parametrize("stage", [STAGE, "joint refinement stages"])
def test_a_worker_killed_mid_run_gives_the_in_process_poses(cluster, random_weights, stage):
    """Killed when the first pair is back (nine running or queued), or after the joint refinement's first stage
    (its shares of normal equations run on the workers): the scans the worker had prepared are made again."""
    workers = cluster.add_workers(2)
    clouds, _ = ring_scans(5)
    expected = rpmnet_jax.align_scans(clouds, options=OPTIONS, checkpoint=random_weights)
    killed = []

    def progress(name, done, total):
        if name == stage and not killed:
            _kill(workers[1:])
            killed.append(done)

    result = rpmnet_jax.align_scans(clouds, options=OPTIONS, checkpoint=random_weights, scheduler=cluster.address,
                                    progress=progress)
    print(f"worker killed after {killed[0]} of {stage}")
    assert killed == [1]
    with distributed.Client(cluster.address, timeout="30s") as client:
        assert list(client.nthreads().values()) == [1]  # the run finished on the other worker
    assert np.array_equal(np.isnan(result.poses[:, 0, 0]), np.isnan(expected.poses[:, 0, 0]))
    for a, b in zip(result.poses, expected.poses):
        if np.isfinite(a[0, 0]):
            assert rotation_error_deg(a[:3, :3], b[:3, :3]) < 0.01
            assert np.linalg.norm(a[:3, 3] - b[:3, 3]) < 1e-6
    assert [(e.source, e.target) for e in result.edges] == [(e.source, e.target) for e in expected.edges]


def _thread_counts(dask_worker) -> dict:
    """In a worker (``client.run``): its threads, and the sizes of the pools its tasks use."""
    import jax
    import numba
    import threadpoolctl

    from rpmnet_jax.geometry import threads

    cpu = jax.devices("cpu")[0]
    jax.jit(lambda a: a @ a)(jax.device_put(np.ones((64, 64), np.float32), cpu)).block_until_ready()  # XLA's pool
    names = collections.Counter(open(f"/proc/self/task/{t}/comm").read().strip() for t in os.listdir("/proc/self/task"))
    return {"nthreads": dask_worker.state.nthreads, "numba": numba.config.NUMBA_NUM_THREADS,
            "numba in a task": threads.start_pool(),
            "blas": sorted({p["num_threads"] for p in threadpoolctl.threadpool_info() if p["user_api"] == "blas"}),
            "xla": sum(n for name, n in names.items() if "XLAEigen" in name)}


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="counts threads in /proc")
def test_an_embedded_cluster_s_worker_sizes_numba_blas_and_xla_to_its_thread(monkeypatch):
    for name in pair_engine.worker_environment(1):  # a shell asking for two threads a pool: the workers still get one
        monkeypatch.setenv(name, "2")
    with pair_engine.PairEngine(1) as engine:
        counts = list(engine.client.run(_thread_counts).values())
    print(f"threads in the worker: {counts}")
    assert counts == [{"nthreads": 1, "numba": 1, "numba in a task": 1, "blas": [1], "xla": 1}]


def _pools_in_a_task() -> dict:
    """A pair task's view (run through ``pair_engine._logged``, as every task is) of the pools its code uses."""
    import jax
    import numba
    import threadpoolctl

    cpu = jax.devices("cpu")[0]
    jax.jit(lambda a: a @ a)(jax.device_put(np.ones((64, 64), np.float32), cpu)).block_until_ready()  # XLA's pool
    names = collections.Counter(open(f"/proc/self/task/{t}/comm").read().strip() for t in os.listdir("/proc/self/task"))
    return {"numba": numba.get_num_threads(),
            "blas": sorted({p["num_threads"] for p in threadpoolctl.threadpool_info() if p["user_api"] == "blas"}),
            "xla": sum(n for name, n in names.items() if "XLAEigen" in name)}


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="counts threads in /proc")
def test_a_worker_started_without_the_environment_still_sizes_its_pools_to_its_thread(monkeypatch):
    """As a worker from ``dask ssh``, a job queue or Kubernetes: none of ``worker_environment``'s variables set, no
    preload; each task sizes the pools to the worker's one thread before it runs (on two cores or more, each pool
    would otherwise have a thread per core)."""
    for name in pair_engine.worker_environment(1):
        monkeypatch.delenv(name, raising=False)
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None) as c, \
            distributed.Client(c) as client:
        cores = client.run(os.cpu_count)
        pools = client.submit(pair_engine._logged, _pools_in_a_task, pure=False).result(timeout=120)
    print(f"a task on a worker of one thread, {list(cores.values())[0]} cores: {pools}")
    assert pools == {"numba": 1, "blas": [1], "xla": 1}


KILLER = """# preloaded into a dask worker: the classical task of pair (0, 1) ends the worker's process, a moment
# after it starts (as a crash or the kernel's out-of-memory killer would)
import os
import time
from rpmnet_jax.pair_edges import pair_engine

_classical_pair = pair_engine.classical_pair


def classical_pair(scans, i, j, settings):
    if (i, j) == (0, 1):
        time.sleep(0.5)
        os._exit(1)
    return _classical_pair(scans, i, j, settings)


pair_engine.classical_pair = classical_pair  # a task's function is found by its name as it is unpickled
"""


def test_a_task_that_kills_every_worker_running_it_stops_in_one_line_naming_its_pair(tmp_path, capsys,
                                                                                     random_weights):
    (tmp_path / "killer.py").write_text(KILLER)
    cluster = Cluster(tmp_path, DASK_DISTRIBUTED__SCHEDULER__ALLOWED_FAILURES="1")  # 3 by default
    try:  # with a nanny a killed worker comes back, and takes the task again: two deaths, then KilledWorker
        cluster.add_workers(1, nanny=True, preload=str(tmp_path / "killer.py"))
        start = time.monotonic()
        rc = register_scans.main(_write_scans(tmp_path, 3) + ["--checkpoint", random_weights, "--scheduler",
                                                              cluster.address, "--cache", str(tmp_path / "cache"),
                                                              "--out-poses", str(tmp_path / "p.conf")])
        waited, err = time.monotonic() - start, capsys.readouterr().err
    finally:
        cluster.close()
    print(f"stopped after {waited:.1f} s: {err.strip()}")
    assert rc == 1 and len(err.strip().splitlines()) == 1, err
    assert "the task of pairs [(0, 1)] killed the Dask workers that ran it 2 times" in err, err
    assert not (tmp_path / "p.conf").exists()


def test_a_scheduler_that_dies_mid_run_stops_in_one_line(cluster, tmp_path, capsys, monkeypatch, random_weights):
    monkeypatch.setattr(pair_engine, "NO_WORKERS_TIMEOUT", 3.0)
    cluster.add_workers(1)
    killed = []

    class KillingBars:  # the scheduler killed when the first pair result is back
        def __init__(self, quiet=False):
            pass

        def __call__(self, stage, done, total):
            if stage == STAGE and not killed:
                cluster.scheduler.send_signal(signal.SIGKILL)
                cluster.scheduler.wait(timeout=30)
                killed.append(time.monotonic())

        def close(self):
            pass

    monkeypatch.setattr(register_scans.runtime, "ProgressBars", KillingBars)
    rc = register_scans.main(_write_scans(tmp_path) + ["--checkpoint", random_weights, "--scheduler", cluster.address,
                                                       "--cache", str(tmp_path / "cache"), "--refine", "none",
                                                       "--out-poses", str(tmp_path / "p.conf")])
    waited, err = time.monotonic() - killed[0], capsys.readouterr().err
    print(f"stopped {waited:.1f} s after the scheduler was killed: {err.strip()}")
    assert rc == 1 and len(err.strip().splitlines()) == 1, err
    assert re.search(rf"the Dask scheduler at {cluster.address} stopped answering with \d of 10 pairs of this stage "
                     "still to run; the cache keeps the pairs that finished: the same command resumes from them once "
                     "the scheduler is back", err), err
    assert waited < 60 and not (tmp_path / "p.conf").exists()  # the client's reconnection timeout, not a hang
    assert len([f for f in os.listdir(tmp_path / "cache") if f.endswith(".npz")]) >= 1
