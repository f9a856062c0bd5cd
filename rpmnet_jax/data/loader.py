"""Batching with fixed shapes and a background prefetch thread (host-side)."""

from __future__ import annotations

import concurrent.futures
import queue
import threading
from typing import Iterator

import numpy as np

BATCH_KEYS = ("points_src", "points_ref", "transform_gt", "points_raw", "label", "idx")


def batch_indices(n: int, batch_size: int, *, shuffle: bool, drop_remainder: bool, seed: int = 0,
                  epoch: int = 0) -> list[np.ndarray]:
    """Index arrays of each batch; the order is a pure function of ``(seed, epoch)``."""
    if batch_size < 1:
        raise ValueError(f"batch_size must be >= 1, got {batch_size}")
    order = np.arange(n)
    if shuffle:
        order = np.random.default_rng([seed, epoch]).permutation(n)
    stop = (n // batch_size) * batch_size if drop_remainder else n
    return [order[i:i + batch_size] for i in range(0, stop, batch_size)]


def collate(samples: list[dict], keys=BATCH_KEYS) -> dict:
    """Stacks equally shaped samples into a batch dict of arrays."""
    out = {}
    for key in keys:
        if key in samples[0]:
            try:
                out[key] = np.stack([s[key] for s in samples])
            except ValueError as e:
                shapes = sorted({np.shape(s[key]) for s in samples})
                raise ValueError(f"cannot batch {key!r}: samples have shapes {shapes}") from e
    return out


def batches(dataset, batch_size: int, *, shuffle: bool = False, drop_remainder: bool = False, seed: int = 0,
            epoch: int = 0, start_batch: int = 0, prefetch: int = 2, workers: int = 2,
            keys=BATCH_KEYS) -> Iterator[dict]:
    """Batches of ``dataset`` for one epoch, built ahead of use by background threads.

    ``dataset.get(i, epoch)`` is used when the dataset has it (training randomness per epoch), else
    ``dataset[i]``. ``start_batch`` skips that many batches (exact resume mid-epoch). NumPy's sampling
    code releases the GIL in its inner loops, so ``workers`` threads overlap.
    """
    plan = batch_indices(len(dataset), batch_size, shuffle=shuffle, drop_remainder=drop_remainder, seed=seed,
                         epoch=epoch)[start_batch:]
    fetch = (lambda i: dataset.get(int(i), epoch)) if hasattr(dataset, "get") else (lambda i: dataset[int(i)])
    if prefetch <= 0:
        for idx in plan:
            yield collate([fetch(i) for i in idx], keys)
        return
    out: queue.Queue = queue.Queue(maxsize=prefetch)
    stop = threading.Event()
    sentinel = object()

    def produce():
        try:
            with concurrent.futures.ThreadPoolExecutor(max(1, workers)) as pool:
                for idx in plan:
                    if stop.is_set():
                        return
                    out.put(collate(list(pool.map(fetch, idx)), keys))
            out.put(sentinel)
        except BaseException as e:  # surface errors in the consumer
            out.put(e)

    thread = threading.Thread(target=produce, daemon=True)
    thread.start()
    try:
        while True:
            item = out.get()
            if item is sentinel:
                return
            if isinstance(item, BaseException):
                raise item
            yield item
    finally:
        stop.set()
        while thread.is_alive():  # unblock a producer waiting on a full queue
            try:
                out.get_nowait()
            except queue.Empty:
                thread.join(timeout=0.05)
