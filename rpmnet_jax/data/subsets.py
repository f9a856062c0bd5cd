"""Subsets and unions of datasets: the first ``n`` samples, ``n`` spread samples, several datasets one after another."""

from __future__ import annotations

import numpy as np


class Head:
    """The first ``n`` samples of a dataset (a subset, not a copy)."""

    def __init__(self, dataset, n: int):
        self.dataset, self.n = dataset, min(int(n), len(dataset))

    def __len__(self):
        return self.n

    def __getitem__(self, i):
        if not 0 <= i < self.n:
            raise IndexError(f"index {i} out of range for {self.n} samples")
        return self.dataset[i]


class Spread(Head):
    """``n`` samples evenly spaced over a dataset (a subset, not a copy): every source of a :class:`Concat` is
    represented."""

    def __getitem__(self, i):
        if not 0 <= i < self.n:
            raise IndexError(f"index {i} out of range for {self.n} samples")
        return self.dataset[(i * len(self.dataset)) // self.n]


class Concat:
    """Datasets one after another (e.g. real ModelNet40 shapes next to synthetic ones); same ``get`` API.

    Training draws are seeded by the global index, so sample ``i`` of each source gets its own rotation, crop
    and noise; ``val``/``test`` samples stay those of their source (the official deterministic sets).
    """

    def __init__(self, datasets):
        self.datasets = list(datasets)
        if not self.datasets:
            raise ValueError("Concat needs at least one dataset")
        self.offsets = np.cumsum([0] + [len(d) for d in self.datasets])

    def __len__(self) -> int:
        return int(self.offsets[-1])

    def get(self, idx: int, epoch: int = 0, draw: int | None = None) -> dict:
        if not 0 <= idx < len(self):
            raise IndexError(f"index {idx} out of range for {len(self)} samples")
        which = int(np.searchsorted(self.offsets, idx, side="right") - 1)
        return self.datasets[which].get(idx - int(self.offsets[which]), epoch, draw=idx if draw is None else draw)

    def __getitem__(self, idx: int) -> dict:
        return self.get(int(idx))
