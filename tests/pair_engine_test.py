"""The pair engine: a pair's edge does not depend on the order or the process it ran in; the cache gives the same
poses and recomputes a changed scan's pairs only; a real Dask scheduler with two worker processes gives the
in-process poses, also when one worker is killed mid-run; so does an embedded LocalCluster."""

import dataclasses
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
from rpmnet_jax.pair_edges import pair_cache, pair_engine
from rpmnet_jax.multiway import preparation, sizes

OPTIONS = rpmnet_jax.ScanOptions(num_points=64, num_iters=2, batch_size=2, refine_points=500)  # small: seconds
NETWORK_OPTIONS = dataclasses.replace(OPTIONS, classical=False)  # every candidate pair through the network


def _close(a, b, degrees=0.01, distance=1e-6):
    """Every pose of ``a`` within ``degrees`` and ``distance`` of ``b`` ``(S, 4, 4)`` (NaN where both are)."""
    assert np.array_equal(np.isnan(a[:, 0, 0]), np.isnan(b[:, 0, 0]))
    for pa, pb in zip(a, b):
        if np.isfinite(pa[0, 0]):
            assert rotation_error_deg(pa[:3, :3], pb[:3, :3]) < degrees
            assert np.linalg.norm(pa[:3, 3] - pb[:3, 3]) < distance


def test_scheduler_values():
    assert pair_engine.check_scheduler(None) is None
    assert pair_engine.check_scheduler("local") == "local" and pair_engine.check_scheduler("3") == 3
    assert pair_engine.check_scheduler("tcp://10.0.0.5:8786") == "tcp://10.0.0.5:8786"
    for bad in (0, "0", "cluster", "tcp://", True, 2.5):
        with pytest.raises(ValueError, match="scheduler"):
            pair_engine.check_scheduler(bad)


def test_in_process_imports_no_dask():
    code = ("import sys; from rpmnet_jax.pair_edges import pair_engine\n"
            "from rpmnet_jax.multiway import scan_alignment\n"
            "with pair_engine.PairEngine(None): pass\n"
            "print(sorted(m for m in ('dask', 'distributed') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and out.stdout.strip() == "[]", out.stderr[-2000:]


@pytest.mark.parametrize("scheduler", [None, 1], ids=["in process", "embedded cluster"])
def test_a_voxel_too_coarse_names_the_first_such_scan_in_one_line(scheduler, capfd):
    """Wherever the scans are prepared: the error is raised by the caller (a worker logs no failed task)."""
    clouds, _ = ring_scans(3)
    with pytest.raises(ValueError) as e:
        rpmnet_jax.align_scans(clouds, options=rpmnet_jax.ScanOptions(voxel_size=0.5), scheduler=scheduler)
    assert re.fullmatch(r"scan 0: \d+ points after voxel downsampling at 0.5; a smaller voxel size is needed",
                        str(e.value)), e.value
    assert "Compute Failed" not in capfd.readouterr().err


def test_a_pair_s_edge_does_not_depend_on_the_order():
    clouds, _ = ring_scans(4)
    scans, voxel = preparation.prepare_scans(clouds, None, None)[:2]
    settings = pair_engine.Settings(sizes.DISTANCE_VOXELS * voxel, 64, 2, 2, 300, 300, 0,
                                    sizes.RANSAC_VOXELS * voxel)
    pairs = [(0, 1), (1, 2), (0, 3), (2, 3)]
    starts = [np.eye(4)] * len(pairs)
    with pair_engine.PairEngine() as engine:
        engine.bind(scans, None, None, settings)
        forward = engine.refine_edges(pairs, starts, 0)
        backward = engine.refine_edges(pairs[::-1], starts, 0)[::-1]
        again = engine.refine_edges(pairs[2:3], starts[2:3], 0)
    for a, b in zip(forward, backward):
        assert np.array_equal(a.transform, b.transform) and a.fitness == b.fitness
    assert np.array_equal(again[0].transform, forward[2].transform)
    assert not np.array_equal(forward[0].transform, np.eye(4))  # the ICP moved: the comparison means something


def test_cached_pairs_are_reused_and_a_changed_scan_s_pairs_computed_again(tmp_path):
    clouds, _ = ring_scans(4)
    scans, voxel = preparation.prepare_scans(clouds, None, 0.004)[:2]
    settings = pair_engine.Settings(sizes.DISTANCE_VOXELS * voxel, 64, 2, 2, 300, 300, 0,
                                    sizes.RANSAC_VOXELS * voxel)
    pairs, starts = [(0, 1), (1, 2), (0, 3), (2, 3)], [np.eye(4)] * 4

    def run(scans):
        cache = pair_cache.PairCache(tmp_path)
        with pair_engine.PairEngine(cache=cache) as engine:
            engine.bind(scans, None, None, settings)
            return engine.refine_edges(pairs, starts, 0), cache

    first, cache = run(scans)
    assert (cache.reused, cache.written) == (0, 4) and len(os.listdir(tmp_path)) == 4
    again, cache = run(scans)
    assert (cache.reused, cache.written) == (4, 0)
    assert all(np.array_equal(a.transform, b.transform) and a.information.tobytes() == b.information.tobytes()
               for a, b in zip(first, again))
    changed = list(scans)
    changed[3] = scans[3]._replace(points=scans[3].points + 1e-9)
    _, cache = run(changed)
    assert (cache.reused, cache.written) == (2, 2) and len(os.listdir(tmp_path)) == 6  # (0, 3) and (2, 3) again


@pytest.mark.slow  # three runs of align_scans, the network compiled once
def test_the_cache_gives_the_same_poses_and_a_changed_scan_recomputes_its_pairs(tmp_path, random_weights):
    clouds, _ = ring_scans(4)
    options = dataclasses.replace(NETWORK_OPTIONS, voxel_size=0.004,  # sizes not from the scans
                                  max_correspondence_distance=0.006, refine="icp", refine_rounds=1)
    first_cache = pair_cache.PairCache(tmp_path / "c")
    first = rpmnet_jax.align_scans(clouds, options=options, checkpoint=random_weights, cache=first_cache)
    files = set(os.listdir(tmp_path / "c"))
    assert first_cache.reused == 0 and first_cache.written == len(files)
    assert sum(f.startswith("network-") for f in files) == 6 and any(f.startswith("refine0-") for f in files)

    again_cache = pair_cache.PairCache(tmp_path / "c")
    again = rpmnet_jax.align_scans(clouds, options=options, checkpoint=random_weights, cache=again_cache)
    assert again_cache.reused == len(files) and again_cache.written == 0
    assert np.array_equal(again.poses, first.poses, equal_nan=True)

    changed = list(clouds)
    changed[3] = clouds[3][::2]  # a scan file that changed: half its points
    changed_cache = pair_cache.PairCache(tmp_path / "c")
    rpmnet_jax.align_scans(changed, options=options, checkpoint=random_weights, cache=changed_cache)
    new = set(os.listdir(tmp_path / "c")) - files
    assert sorted(tuple(map(int, f.split("-")[1:3])) for f in new if f.startswith("network-")) == [
        (0, 3), (1, 3), (2, 3)]  # its pairs only; the refinement edges start from the new poses
    assert changed_cache.reused >= 3


_SCHEDULER = ["dask", "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard"]
_WORKER = ["dask", "worker", "--nthreads", "1", "--no-nanny", "--no-dashboard"]


@pytest.fixture
def dask_cluster(tmp_path):
    """A real ``dask scheduler`` and two ``dask worker`` processes (no nanny: a SIGKILL ends a worker for good):
    ``(address, worker processes)``."""
    distributed = pytest.importorskip("distributed")
    bin_dir = os.path.dirname(sys.executable)
    env = dict(os.environ, JAX_PLATFORMS="cpu")
    file = tmp_path / "scheduler.json"
    procs = [subprocess.Popen([os.path.join(bin_dir, _SCHEDULER[0]), *_SCHEDULER[1:], "--scheduler-file", str(file)],
                              env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
    try:
        deadline = time.time() + 60
        while not file.exists() and time.time() < deadline:
            assert procs[0].poll() is None, "the scheduler ended"
            time.sleep(0.1)
        time.sleep(0.2)  # the file is written whole, then read
        address = json.loads(file.read_text())["address"]
        workers = [subprocess.Popen([os.path.join(bin_dir, _WORKER[0]), *_WORKER[1:], "--name", f"w{k}",
                                     "--scheduler-file", str(file)], env=env, stdout=subprocess.DEVNULL,
                                    stderr=subprocess.DEVNULL) for k in range(2)]
        procs += workers
        with distributed.Client(address, timeout="30s") as client:
            client.wait_for_workers(2, timeout=120)
        yield address, workers
    finally:  # the workers hold nothing worth a clean shutdown
        for p in reversed(procs):
            if p.poll() is None:
                p.kill()
            p.wait(timeout=30)


@pytest.fixture(scope="module")
def in_process(random_weights):
    clouds, _ = ring_scans(5)
    return clouds, {o.classical: rpmnet_jax.align_scans(clouds, options=o, checkpoint=random_weights)
                    for o in (OPTIONS, NETWORK_OPTIONS)}


@pytest.mark.slow  # three processes that start Dask and JAX
@pytest.mark.parametrize("options", [OPTIONS, NETWORK_OPTIONS], ids=["classical", "network"])
def test_a_dask_scheduler_with_two_workers_gives_the_in_process_poses(dask_cluster, in_process, random_weights,
                                                                      options):
    address, _ = dask_cluster
    clouds, expected = in_process[0], in_process[1][options.classical]
    reports = []
    result = rpmnet_jax.align_scans(clouds, options=options, checkpoint=random_weights, scheduler=address,
                                    progress=lambda *r: reports.append(r))
    _close(result.poses, expected.poses)
    assert [(e.source, e.target) for e in result.edges] == [(e.source, e.target) for e in expected.edges]
    stage = "classical edges" if options.classical else "network edges"  # classical: a pair a task; network:
    ticks = [r for r in reports if r[0] == stage]  # chunks of 2 pairs; reported as they finish
    assert ticks[-1] == (stage, 10, 10) and len(ticks) >= 2


@pytest.mark.slow  # the scans prepared twice on the workers
def test_the_refinement_at_a_finer_voxel_on_two_workers_gives_the_in_process_poses(dask_cluster, in_process,
                                                                                    random_weights):
    """With ``refine_voxel_size`` the engine lets the coarse scans go (here and on the workers) and prepares the
    finer ones as tasks: the same poses as in process, refined at that voxel."""
    address, _ = dask_cluster
    clouds, coarse = in_process[0], in_process[1][True]
    options = dataclasses.replace(OPTIONS, refine_voxel_size=coarse.voxel_size / 2)
    expected = rpmnet_jax.align_scans(clouds, options=options, checkpoint=random_weights)
    result = rpmnet_jax.align_scans(clouds, options=options, checkpoint=random_weights, scheduler=address)
    assert result.voxel_size == expected.voxel_size == coarse.voxel_size / 2
    _close(result.poses, expected.poses)


@pytest.mark.slow
def test_a_worker_killed_mid_run_still_gives_the_same_poses(dask_cluster, in_process, random_weights):
    import distributed

    address, workers = dask_cluster
    clouds, expected = in_process
    killed = []

    def progress(stage, done, total):  # the first chunk is back, four are still running or queued
        if stage == "network edges" and not killed:
            assert done < total
            workers[1].send_signal(signal.SIGKILL)
            killed.append(done)

    result = rpmnet_jax.align_scans(clouds, options=NETWORK_OPTIONS, checkpoint=random_weights, scheduler=address,
                                    progress=progress)
    print(f"worker killed after {killed[0]} of 10 network edges")
    assert killed and workers[1].wait(timeout=10) == -signal.SIGKILL
    with distributed.Client(address, timeout="30s") as client:
        assert len(client.scheduler_info()["workers"]) == 1  # the run finished on the other worker
    _close(result.poses, expected[False].poses)


@pytest.mark.slow  # starts two worker processes
def test_an_embedded_local_cluster_gives_the_in_process_poses(in_process, random_weights):
    clouds, expected = in_process
    result = rpmnet_jax.align_scans(clouds, options=OPTIONS, checkpoint=random_weights, scheduler=2)
    _close(result.poses, expected[True].poses)
