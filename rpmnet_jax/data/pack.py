"""A compact copy of training data for a machine the data folders do not reach (a lent GPU): float16, fewer points.

Each dataset folder becomes ``out/<name>/modelnet40_ply_hdf5_2048`` in the same format (so ``ModelNet40`` and
``--data-root`` read it unchanged): the shapes its ``train`` split uses (train files, first 20 categories), each
cut to ``num_points`` random points of its 2,048, and the first ``val_shapes`` shapes of its ``val`` split
(test files, first 20 categories: validation only, never trained on) as its test file; nothing of the ``test``
split (the last 20 categories). The 1,024 points a training pair draws per cloud then share ``1024 /
num_points`` of their points (the full clouds: half), the price of the size.
"""

from __future__ import annotations

import os
import shutil

import numpy as np

from rpmnet_jax.data import modelnet40


def _subsample(points: np.ndarray, num_points: int, rng: np.random.Generator) -> np.ndarray:
    """``(N, P, 6)`` → ``(N, num_points, 6)`` float16: each shape's random points, without repeats."""
    if num_points > points.shape[1]:
        raise ValueError(f"num_points {num_points} is more than the {points.shape[1]} points of a shape")
    return np.stack([p[rng.choice(len(p), num_points, replace=False)] for p in points]).astype(np.float16)


def pack(roots, out_dir, num_points: int = 1280, val_shapes: int = 32, seed: int = 0) -> dict:
    """Writes the compact copy of every folder of ``roots`` under ``out_dir`` (which must not exist; written
    beside it first, so a failure leaves nothing); returns ``{name: {"train": N, "val": M, "bytes": B}}``."""
    out_dir = os.path.abspath(os.fspath(out_dir))
    if os.path.exists(out_dir):
        raise FileExistsError(f"{out_dir!r} exists; the pack is written to a new folder")
    names = [os.path.basename(os.path.normpath(r)) for r in roots]
    if len(set(names)) != len(names):
        raise ValueError(f"two dataset folders have the same name: {names}")
    sets = [(modelnet40.ModelNet40(r, "train", "partial"), modelnet40.ModelNet40(r, "val", "partial"))
            for r in roots]  # read (and checked) before anything is written
    tmp = out_dir + ".tmp"
    shutil.rmtree(tmp, ignore_errors=True)
    rng = np.random.default_rng(seed)
    report = {}
    try:
        for name, (train, val) in zip(names, sets):
            folder = os.path.join(tmp, name, modelnet40.FOLDER)
            parts = (("train", train.points, train.labels),
                     ("test", val.points[:val_shapes], val.labels[:val_shapes]))
            sizes = [os.path.getsize(modelnet40.write_split(folder, subset, _subsample(points, num_points, rng),
                                                            labels, compress=True))
                     for subset, points, labels in parts]
            modelnet40.write_shape_names(folder, train.class_names)
            report[name] = {"train": len(train), "val": min(val_shapes, len(val)), "bytes": sum(sizes)}
        os.replace(tmp, out_dir)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return report

