"""geometry.threads: BLAS set to one thread once for the process (never toggled per call), two threads calling
``align`` at once get the serial answers under every Numba threading layer; the parallel FPFH loops give the
serial loops' values."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest
from threadpoolctl import threadpool_info

from rpmnet_jax.classical import fpfh
from rpmnet_jax.geometry import threads

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

TWO_THREADS = """
import json, sys, threading
import numpy as np
from threadpoolctl import threadpool_info
blas = lambda: [p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"]
from rpmnet_jax.pairwise import alignment
import numba
before = blas()
rng = np.random.default_rng(0)
pts = rng.normal(size=(3000, 3))
ref = pts @ np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]).T + 0.01
got, seen, start = {}, {}, threading.Barrier(2)
def run(k):
    start.wait(10)  # both threads inside align at once
    got[k] = alignment.align(pts, ref, init="classical").transform
    seen[k] = blas()
workers = [threading.Thread(target=run, args=(k,)) for k in range(2)]
[w.start() for w in workers]
[w.join(300) for w in workers]
serial = alignment.align(pts, ref, init="classical").transform
print(json.dumps({"layer": numba.threading_layer(), "before": before, "seen": [seen.get(k) for k in range(2)],
                  "after": blas(), "same": [bool(np.array_equal(got.get(k), serial)) for k in range(2)]}))
"""


@pytest.mark.parametrize("layer", ["omp", "tbb", "workqueue"])
def test_two_threads_calling_align_at_once_get_the_serial_answers(layer):
    """A fresh process (as a Dask worker with two threads): both threads inside ``align`` at once, under each of
    Numba's threading layers (workqueue cannot run two parallel loops at once: it aborted the process before
    ``compiled_loops`` took one caller at a time there); BLAS stays on one thread after."""
    env = {**os.environ, "PYTHONPATH": REPO, "NUMBA_THREADING_LAYER": layer}
    out = subprocess.run([sys.executable, "-c", TWO_THREADS], capture_output=True, text=True, timeout=600, env=env)
    if layer != "workqueue" and out.returncode != 0 and "No threading layer could be loaded" in out.stderr:
        pytest.skip(f"Numba's {layer} layer is not installed here")
    assert out.returncode == 0, out.stderr[-2000:]
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got["layer"] == layer
    assert got["same"] == [True, True]
    assert got["before"] and got["seen"] == [[1] * len(got["before"])] * 2 and got["after"] == [1] * len(got["before"])


def test_blas_is_limited_once_and_again_for_a_library_loaded_later(monkeypatch):
    calls = []
    monkeypatch.setattr(threads, "_limited", None)
    real = threads._controller()
    monkeypatch.setattr(type(real), "limit", lambda self, **kw: calls.append(kw))
    threads.limit_blas()
    threads.limit_blas()
    assert calls == [{"limits": 1, "user_api": "blas"}]  # once
    monkeypatch.setattr(threads, "_found", (-1, None))  # as after an import: the libraries are looked up again
    threads.limit_blas()
    assert len(calls) == 2


def test_align_runs_with_one_blas_thread(monkeypatch):
    """align's BLAS calls (FPFH's feature matching) see one thread."""
    from rpmnet_jax.classical import feature_ransac
    from rpmnet_jax.pairwise import alignment

    seen = []
    nearest = feature_ransac.nearest_rows
    monkeypatch.setattr(feature_ransac, "nearest_rows", lambda *a, **k: (seen.append(_blas_threads()), nearest(*a, **k))[1])
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(400, 3))
    alignment.align(pts, pts + 0.01, init="classical")
    assert seen and all(s == [1] * len(s) for s in seen)


def _blas_threads():
    return [p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"]


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
