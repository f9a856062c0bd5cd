"""Finished pair results of :func:`rpmnet_jax.align_scans` on disk (``cache=``): one ``.npz`` per edge, written
atomically (a temporary file in the folder, then ``os.replace``), read back without pickle.

A result's key is a digest of everything that decides it: the stage, the pair ``(i, j)``, both scans'
contents (their downsampled points and normals: a changed scan file gives new keys, so its pairs are
recomputed), the settings and seed, the network's parameters (network edges) and the start pose (refinement
edges). A file whose key matches is that result, bit for bit.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
import zipfile

import numpy as np

from rpmnet_jax.multiway import edges as edges_lib

CACHE_VERSION = 2  # part of every key: a new layout or meaning of the files starts a new set of keys


def digest(*parts) -> str:
    """Hex SHA-256 of ``parts``: arrays by dtype, shape and bytes, anything else by ``repr``."""
    h = hashlib.sha256()
    for part in parts:
        if isinstance(part, np.ndarray):
            part = np.ascontiguousarray(part)
            h.update(f"{part.dtype.str}{part.shape}".encode())
            h.update(part.tobytes())
        else:
            h.update(repr(part).encode())
        h.update(b"\x00")
    return h.hexdigest()


def scan_digest(scan: edges_lib.Scan) -> str:
    """Content digest of a :class:`~rpmnet_jax.multiway.edges.Scan`: its points and normals ``(V, 3)``."""
    return digest(scan.points, scan.normals)


def params_digest(params) -> str:
    """Digest of a network parameter tree, by path and value."""
    import jax

    leaves = jax.tree_util.tree_leaves_with_path(params)
    return digest(*[x for path, leaf in leaves for x in (jax.tree_util.keystr(path), np.asarray(leaf))])


def check_folder(folder) -> str:
    """``folder`` as a string; ``ValueError`` (one line) when it is a file or its parent folder is missing."""
    folder = os.fspath(folder)
    if os.path.exists(folder) and not os.path.isdir(folder):
        raise ValueError(f"cache {folder} is a file, not a folder")
    if not os.path.isdir(os.path.dirname(os.path.abspath(folder))):
        raise ValueError(f"the folder holding cache {folder} does not exist")
    return folder


class PairCache:
    """Edges on disk under ``folder`` (made on the first write). ``reused`` and ``written`` count this run's
    hits and new files."""

    def __init__(self, folder):
        self.folder = check_folder(folder)
        self.reused = 0
        self.written = 0

    def path(self, name: str) -> str:
        return os.path.join(self.folder, f"{name}.npz")

    def load(self, name: str) -> edges_lib.Edge | None:
        """The edge stored under ``name``, or ``None`` when there is none (or it cannot be read)."""
        try:
            with np.load(self.path(name), allow_pickle=False) as f:
                edge = edges_lib.Edge(int(f["source"]), int(f["target"]), f["transform"].astype(np.float64),
                                      float(f["fitness"]), float(f["inlier_rmse"]),
                                      f["information"].astype(np.float64), float(f["plane_residual"]),
                                      str(f["stage"]))
        except (OSError, KeyError, ValueError, zipfile.BadZipFile):
            return None
        self.reused += 1
        return edge

    def store(self, name: str, edge: edges_lib.Edge) -> None:
        """Writes ``edge`` under ``name`` atomically: a reader sees the whole file or none."""
        os.makedirs(self.folder, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{name}.", suffix=".tmp", dir=self.folder)
        try:
            with os.fdopen(fd, "wb") as f:
                np.savez(f, source=edge.source, target=edge.target, transform=edge.transform, fitness=edge.fitness,
                         inlier_rmse=edge.inlier_rmse, information=edge.information,
                         plane_residual=edge.plane_residual, stage=np.str_(edge.stage))
            os.replace(tmp, self.path(name))
        except BaseException:
            if os.path.exists(tmp):
                os.remove(tmp)
            raise
        self.written += 1


def edge_name(stage: str, i: int, j: int, *key_parts) -> str:
    """File name (no extension) of the edge ``i → j`` of ``stage`` under the key ``key_parts``."""
    return f"{stage}-{i}-{j}-{digest(CACHE_VERSION, stage, i, j, *key_parts)[:40]}"
