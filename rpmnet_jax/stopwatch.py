"""The one timing helper of the library: seconds per named stage of a pipeline, and in all."""

from __future__ import annotations

import contextlib
import time


class Stopwatch:
    """Wall seconds per stage (summed over its runs; stages in the order they first ran), and wall and CPU
    seconds since it was made."""

    def __init__(self):
        self.seconds: dict = {}
        self._wall0, self._cpu0 = time.perf_counter(), time.process_time()

    @contextlib.contextmanager
    def stage(self, name: str):
        t = time.perf_counter()
        try:
            yield
        finally:
            self.seconds[name] = self.seconds.get(name, 0.0) + time.perf_counter() - t

    def elapsed(self) -> float:
        return time.perf_counter() - self._wall0

    def cpu_elapsed(self) -> float:
        return time.process_time() - self._cpu0

    def timings(self) -> dict:
        """``{stage: seconds, ..., "total": seconds since made}``."""
        return {**self.seconds, "total": self.elapsed()}
