"""geometry.threads: BLAS runs on one thread inside one_blas_thread (and inside align), the caller's setting comes
back on leaving; the parallel FPFH loops give the serial loops' values."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest
from threadpoolctl import threadpool_info

from rpmnet_jax.geometry import fpfh, threads

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _blas_threads():
    return [p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"]


def test_one_blas_thread_limits_blas_and_restores_it():
    before = _blas_threads()
    if not before:
        pytest.fail("no BLAS library found: NumPy always loads one")
    with threads.one_blas_thread():
        assert _blas_threads() == [1] * len(before)
    assert _blas_threads() == before


OVERLAP = """
import json, threading
import numpy
from threadpoolctl import threadpool_info
from rpmnet_jax.geometry import threads
blas = lambda: [p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"]
before, seen = blas(), {}
inside, first_left = threading.Event(), threading.Event()
def first():
    with threads.one_blas_thread():
        inside.set()
    first_left.set()
def second():
    inside.wait(10)
    with threads.one_blas_thread():
        first_left.wait(10)
        seen["second, after the first left"] = blas()
workers = [threading.Thread(target=second), threading.Thread(target=first)]
[w.start() for w in workers]
[w.join(20) for w in workers]
print(json.dumps({"before": before, "seen": seen, "after": blas()}))
"""


def test_worker_threads_are_limited_inside_and_the_setting_is_back_after():
    """Two worker threads (as a Dask worker's tasks; a fresh process whose main thread never set a limit), the first
    leaving while the second is inside: the second still runs BLAS on one thread, and afterwards the process's
    setting is the one from before."""
    out = subprocess.run([sys.executable, "-c", OVERLAP], capture_output=True, text=True, timeout=120,
                         env={**os.environ, "PYTHONPATH": REPO})
    assert out.returncode == 0, out.stderr[-2000:]
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got["before"] and got["seen"] == {"second, after the first left": [1] * len(got["before"])}
    assert got["after"] == got["before"]


def test_two_threads_calling_align_give_the_serial_answers():
    import threading

    from rpmnet_jax.pairwise import alignment

    rng = np.random.default_rng(0)
    pts = rng.normal(size=(3000, 3))
    ref = pts @ np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]).T + 0.01
    serial = alignment.align(pts, ref, init="classical").transform
    import numba
    if numba.threading_layer() == "workqueue":  # not safe for concurrent callers: aborts the process (issue 52)
        pytest.skip("Numba's workqueue layer cannot run parallel loops from two threads at once")
    got = {}
    workers = [threading.Thread(target=lambda k=k: got.update({k: alignment.align(pts, ref, init="classical")
                                                                .transform})) for k in range(2)]
    [w.start() for w in workers]
    [w.join(120) for w in workers]
    assert sorted(got) == [0, 1] and all(np.array_equal(t, serial) for t in got.values())


def test_align_runs_with_one_blas_thread(monkeypatch):
    """align's BLAS calls (FPFH's feature matching) see one thread; afterwards the caller's setting is back."""
    from rpmnet_jax.geometry import feature_ransac
    from rpmnet_jax.pairwise import alignment

    seen = []
    nearest = feature_ransac.nearest_rows
    monkeypatch.setattr(feature_ransac, "nearest_rows", lambda *a, **k: (seen.append(_blas_threads()), nearest(*a, **k))[1])
    before = _blas_threads()
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(400, 3))
    alignment.align(pts, pts + 0.01, init="classical")
    assert seen and all(s == [1] * len(before) for s in seen)
    assert _blas_threads() == before


def _spfh_serial(points, normals, idx, valid):
    """The SPFH as one plain loop over the rows (the parallel loop's oracle), from the same pair features."""
    n, k = idx.shape
    hist = np.zeros((n, 3 * fpfh.BINS))
    for i in range(n):
        count = int(valid[i, 1:].sum())
        for j in range(1, k):
            if valid[i, j]:
                f1, f2, f3, _ = fpfh.pair_features(points[i], normals[i], points[idx[i, j]], normals[idx[i, j]])
                for block, (value, low, high) in enumerate(((f1, -np.pi, np.pi), (f2, -1, 1), (f3, -1, 1))):
                    b = fpfh._bin(fpfh.BINS * (value - low) / (high - low))
                    hist[i, block * fpfh.BINS + b] += 100.0 / count
    return hist


def test_parallel_spfh_matches_a_serial_loop():
    rng = np.random.default_rng(1)
    points = rng.normal(size=(150, 3))
    normals = rng.normal(size=(150, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    idx, _, valid = fpfh.neighbours(points, 0.8, 20)
    np.testing.assert_allclose(fpfh.spfh(points, normals, idx, valid), _spfh_serial(points, normals, idx, valid),
                               rtol=0, atol=1e-9)
