"""The two thread pools the geometry runs beside: Numba's, for the compiled loops that run on every core (the k-d
tree's queries, FPFH), and BLAS's, which NumPy calls for its larger products.

They must not run at once. OpenBLAS keeps its threads spinning for a while after each call, so a Numba loop
that follows a product (FPFH's feature matching is one) shares the cores with threads that do nothing. On two
cores the parallel loops then ran at half speed or worse: on the 150 partial test pairs of the real ModelNet40
subset at any orientation, the default ``align`` took 65 ms a pair serial, 94 ms with the parallel loops, and
52 ms with them and BLAS on one thread (:func:`limit_blas`), the same answers. NumPy's products here are small
(33-dimensional features, 3 × 3 frames), so one BLAS thread costs them nothing measurable.
"""

from __future__ import annotations

import contextlib
import sys
import threading

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
_limited = None  # the controller whose libraries were limited
_blas_lock = threading.Lock()
_serial = threading.RLock()  # one caller at a time under Numba's workqueue layer


def _controller():
    """threadpoolctl's view of the BLAS libraries the process has loaded (5 ms to find), found again only after
    a module has been imported since (SciPy brings its own OpenBLAS beside NumPy's)."""
    global _found
    if _found[0] != len(sys.modules):
        from threadpoolctl import ThreadpoolController

        controller = ThreadpoolController()
        _found = (len(sys.modules), controller)
    return _found[1]


def limit_blas() -> None:
    """Sets BLAS (NumPy's and SciPy's OpenBLAS, MKL) to one thread for the rest of the process, so that it leaves
    the cores to Numba's parallel loops: once, and again only when a library has been loaded since. Never undone:
    a setting toggled per call is process-wide, and two threads toggling it undo each other (3 runs in 9 of the
    two-thread test failed so). NumPy's products here are small; a caller that needs many BLAS threads for its
    own large products sets them again after (``threadpoolctl.threadpool_limits``)."""
    global _limited
    with _blas_lock:
        controller = _controller()
        if controller is not _limited:
            controller.limit(limits=1, user_api="blas")  # not as a context: it stays
            _limited = controller


@numba.njit(parallel=True, cache=True)
def _touch(n):
    total = 0
    for i in numba.prange(n):
        total += i
    return total


_layer = []  # Numba's threading layer, once known


def _workqueue() -> bool:
    """Whether Numba runs its parallel loops on its workqueue layer (it cannot run two at once: a second thread's
    loop aborts the process); the layer is chosen when the first parallel loop runs, here, by one thread."""
    if not _layer:
        with _blas_lock:
            if not _layer:
                try:
                    layer = numba.threading_layer()
                except ValueError:  # no parallel loop has run yet
                    _touch(2)
                    layer = numba.threading_layer()
                _layer.append(layer)
    return _layer[0] == "workqueue"


@contextlib.contextmanager
def compiled_loops():
    """Where the library's compiled parallel loops run (``align``, ``align_scans``, a Dask worker's pair task):
    BLAS on one thread (:func:`limit_blas`), and under Numba's workqueue layer one caller at a time (with TBB or
    OpenMP, threads run their loops at once). Usable as a decorator."""
    limit_blas()
    if _workqueue():
        with _serial:
            yield
    else:
        yield
