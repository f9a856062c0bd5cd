"""The two thread pools the geometry runs beside: Numba's, for the compiled loops that run on every core (the k-d
tree's queries, FPFH), and BLAS's, which NumPy calls for its larger products.

They must not run at once. OpenBLAS keeps its threads spinning for a while after each call, so a Numba loop
that follows a product (FPFH's feature matching is one) shares the cores with threads that do nothing. On two
cores the parallel loops then ran at half speed or worse: on the 150 partial test pairs of the real ModelNet40
subset at any orientation, the default ``align`` took 65 ms a pair serial, 94 ms with the parallel loops, and
52 ms with them and BLAS on one thread (:func:`one_blas_thread`), the same answers. NumPy's products here are small
(33-dimensional features, 3 × 3 frames), so one BLAS thread costs them nothing measurable.
"""

from __future__ import annotations

import contextlib
import sys

import numba


def start_pool() -> int:
    """Starts Numba's thread pool (when it has not started yet) and returns its size. Call it before code that
    holds a parallel loop: compiled code loaded from Numba's on-disk cache into a fresh process calls the pool's
    functions through addresses bound only once it has started (before, an ICP in a new process, such as a Dask
    worker, jumped to address 0)."""
    return numba.get_num_threads()


CHUNKS_PER_THREAD = 8  # a parallel loop over rows runs in this many pieces per thread: uneven rows even out


def chunks() -> int:
    """How many pieces a parallel loop over rows splits them into (:data:`CHUNKS_PER_THREAD` per thread of the
    pool, which this starts: :func:`start_pool`)."""
    return CHUNKS_PER_THREAD * start_pool()


_found = (-1, None)  # (how many modules were imported, the BLAS libraries found then)


def _controller():
    """threadpoolctl's view of the BLAS libraries the process has loaded (5 ms to find), found again only after
    a module has been imported since (SciPy brings its own OpenBLAS beside NumPy's)."""
    global _found
    if _found[0] != len(sys.modules):
        from threadpoolctl import ThreadpoolController

        controller = ThreadpoolController()
        _found = (len(sys.modules), controller)
    return _found[1]


@contextlib.contextmanager
def one_blas_thread():
    """Within it, BLAS (NumPy's and SciPy's OpenBLAS, MKL) runs on one thread, so that it leaves the cores to
    Numba's parallel loops; the caller's settings come back on leaving. Made in the main thread, the setting holds
    for every thread of the process while it lasts; made in another thread (a Dask worker's task), OpenBLAS 0.3.31
    honoured it for that thread's calls (the partial pairs of the ModelNet40 subset, ``init="classical"`` in a worker
    thread: 88 ms a pair without it, 30 ms with it), except once the main thread had set and restored a limit
    itself."""
    with _controller().limit(limits=1, user_api="blas"):
        yield
