"""Freed memory given back to the system between the long stages of a run.

glibc's ``malloc`` keeps what a process frees in its heap for later allocations; when those are of other sizes
the pages stay resident. :func:`align_scans <rpmnet_jax.align_scans>` frees the registration's scans (a
1,000-station site: 1.1 GB) before it prepares the finer ones, and the network's buffers after its stage; without
giving those pages back the process held them to the end (the town's 1,000 stations of seed 13: 586 MB free but
resident through the finer refinement). Elsewhere (no glibc) this does nothing.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools


@functools.cache
def _malloc_trim():
    """glibc's ``malloc_trim``, or None where the C library has none."""
    name = ctypes.util.find_library("c")
    if name is None:
        return None
    try:
        return getattr(ctypes.CDLL(name), "malloc_trim", None)
    except OSError:
        return None


def give_back() -> None:
    """Returns the free pages of the heap to the system (``malloc_trim(0)``); nothing without glibc."""
    trim = _malloc_trim()
    if trim is not None:
        trim(0)
