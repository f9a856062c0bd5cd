"""Freed memory given back to the system (glibc's ``malloc_trim``)."""

import sys

import pytest

from rpmnet_jax import memory


def _resident_mb() -> float:
    with open("/proc/self/status") as f:
        return next(int(line.split()[1]) / 1024 for line in f if line.startswith("VmRSS"))


@pytest.mark.skipif(not sys.platform.startswith("linux") or memory._malloc_trim() is None, reason="glibc only")
def test_the_free_pages_between_live_blocks_go_back():
    """200 MB of 64 KB blocks (under glibc's mmap threshold: in the heap), nine in ten freed, every tenth kept so the
    heap cannot shrink from its top: the freed pages stay resident until :func:`memory.give_back`."""
    blocks = [bytearray(b"x" * (64 * 1024)) for _ in range(3200)]
    kept = blocks[::10]
    del blocks
    before = _resident_mb()
    memory.give_back()
    after = _resident_mb()
    assert before - after > 100, (before, after)
    assert all(b[-1:] == b"x" for b in kept)  # the live blocks untouched
