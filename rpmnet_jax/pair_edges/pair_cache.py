"""Finished pair results of :func:`rpmnet_jax.align_scans` on disk (``cache=``): one ``.npz`` per edge, written
atomically (a temporary file in the folder, then ``os.replace``), read back without pickle.

A result's key is a digest of everything that decides it: the stage, the pair ``(i, j)``, both scans'
contents (their downsampled points and normals: a changed scan file gives new keys, so its pairs are
recomputed), the settings and seed, the network's parameters (network edges), the start pose (refinement
edges) and the source of the code that computes it (:data:`RESULT_CODE`: an upgrade starts new keys). A file
whose key matches is that result, bit for bit.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
import zipfile

import numpy as np

from rpmnet_jax.pair_edges import edges as edges_lib

CACHE_VERSION = 3  # part of every key: a new layout or meaning of the files starts a new set of keys
# The package's code an edge's value depends on (folders and files under rpmnet_jax/): its source is part of every
# key, so an upgrade that changes a constant or a line there (RANSAC's draws, the ICP's gates, DISTINCT_DEG, the
# features, the network) starts a new set of keys, and a resumed run never mixes old edges with new ones. More than
# strictly needed (an edit to a docstring there invalidates too): a cache is cheap to refill, a wrong edge is not.
RESULT_CODE = ("config.py", "registration.py", "geometry", "classical", "ops", "nn", "pairwise", "pair_edges")
_PACKAGE = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
_code = {}  # the digest, once per process


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


def source_files() -> list:
    """The ``.py`` files of :data:`RESULT_CODE`, sorted, as paths under the package."""
    files = []
    for part in RESULT_CODE:
        path = os.path.join(_PACKAGE, part)
        if os.path.isdir(path):
            files += [os.path.join(root, f) for root, _, names in os.walk(path) for f in names if f.endswith(".py")]
        else:
            files.append(path)
    return sorted(files)


def code_digest() -> str:
    """Digest of the source of :func:`source_files` (their paths under the package and their bytes)."""
    if "digest" not in _code:
        parts = []
        for path in source_files():
            with open(path, "rb") as f:
                parts += [os.path.relpath(path, _PACKAGE), np.frombuffer(f.read(), np.uint8)]
        _code["digest"] = digest(*parts)
    return _code["digest"]


def scan_digest(scan: edges_lib.Scan) -> str:
    """Content digest of a :class:`~rpmnet_jax.pair_edges.edges.Scan`: its points and normals (unit or packed: their
    dtype and shape are in the digest)."""
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

    def load(self, name: str) -> list | None:
        """The edges stored under ``name`` (a pair's answers: one, several or none), or ``None`` when there is no
        such file (or it cannot be read)."""
        try:
            with np.load(self.path(name), allow_pickle=False) as f:
                edges = [edges_lib.Edge(int(f["source"][k]), int(f["target"][k]), f["transform"][k].astype(np.float64),
                                        float(f["fitness"][k]), float(f["inlier_rmse"][k]),
                                        f["information"][k].astype(np.float64), float(f["plane_residual"][k]),
                                        str(f["stage"][k]), balanced_fitness=float(f["balanced_fitness"][k]))
                         for k in range(len(f["fitness"]))]
        except (OSError, KeyError, ValueError, IndexError, zipfile.BadZipFile):
            return None
        self.reused += 1
        return edges

    def store(self, name: str, edges: list) -> None:
        """Writes ``edges`` (a pair's answers, possibly none) under ``name`` atomically: a reader sees the whole
        file or none."""
        os.makedirs(self.folder, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{name}.", suffix=".tmp", dir=self.folder)
        field = lambda k, dtype=np.float64: np.array([getattr(e, k) for e in edges], dtype)
        try:
            with os.fdopen(fd, "wb") as f:
                np.savez(f, source=field("source", np.int64), target=field("target", np.int64),
                         transform=field("transform").reshape(-1, 4, 4), fitness=field("fitness"),
                         inlier_rmse=field("inlier_rmse"), information=field("information").reshape(-1, 6, 6),
                         plane_residual=field("plane_residual"), stage=field("stage", np.str_),
                         balanced_fitness=field("balanced_fitness"))
            os.replace(tmp, self.path(name))
        except BaseException:
            if os.path.exists(tmp):
                os.remove(tmp)
            raise
        self.written += 1


def edge_name(stage: str, i: int, j: int, *key_parts) -> str:
    """File name (no extension) of the edge ``i → j`` of ``stage`` under the key ``key_parts``."""
    return f"{stage}-{i}-{j}-{digest(CACHE_VERSION, code_digest(), stage, i, j, *key_parts)[:40]}"
