"""Reading and writing point clouds and transforms: PLY, PCD, XYZ/TXT/CSV, NPY/NPZ."""

from __future__ import annotations

import io
import json
import os
import warnings

import numpy as np

from rpmnet_jax.io import ply

FORMATS = (".ply", ".pcd", ".xyz", ".txt", ".csv", ".npy", ".npz")


class CloudError(ValueError):
    """A point-cloud file could not be used; the message is one line for the user."""


def check_format(path: str) -> str:
    ext = os.path.splitext(path)[1].lower()
    if ext not in FORMATS:
        raise CloudError(f"{path}: unknown point-cloud format {ext or '(none)'!r}; use one of {', '.join(FORMATS)}")
    return ext


def read_cloud(path: str) -> tuple[np.ndarray, np.ndarray | None]:
    """``points (N, 3)`` float64 and ``normals (N, 3)`` or ``None`` from a file."""
    ext = check_format(path)
    if os.path.isdir(path):
        raise CloudError(f"{path}: is a folder, not a point-cloud file")
    if not os.path.isfile(path):
        raise CloudError(f"{path}: no such file")
    if not os.access(path, os.R_OK):
        raise CloudError(f"{path}: permission denied")
    try:
        if ext == ".ply":
            arr = _read_ply(path)
        elif ext == ".pcd":
            arr = _read_pcd(path)
        elif ext in (".npy", ".npz"):
            arr = _read_numpy(path)
        else:
            delimiter = "," if ext == ".csv" else None
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # NumPy warns on an empty file; the shape check below says so
                arr = np.loadtxt(path, delimiter=delimiter, ndmin=2, comments="#")
    except CloudError:
        raise
    except Exception as e:  # malformed file of a known format
        raise CloudError(f"{path}: cannot read as {ext[1:].upper()} ({type(e).__name__}: {e})") from None
    arr = np.asarray(arr, np.float64)
    if arr.ndim != 2 or arr.shape[1] not in (3, 6):
        raise CloudError(f"{path}: expected N×3 (xyz) or N×6 (xyz + normals) values, got shape {arr.shape}")
    if arr.shape[0] == 0:
        raise CloudError(f"{path}: the cloud is empty")
    return arr[:, :3], (arr[:, 3:6] if arr.shape[1] == 6 else None)


def _read_ply(path):
    vertex = ply.read_vertices(path)
    names = vertex.dtype.names or ()
    if not all(c in names for c in ("x", "y", "z")):
        raise CloudError(f"{path}: PLY vertices without x y z properties (has {list(names)})")
    cols = [vertex[c] for c in ("x", "y", "z")]
    if all(c in names for c in ("nx", "ny", "nz")):
        cols += [vertex[c] for c in ("nx", "ny", "nz")]
    return np.stack(cols, axis=1).astype(np.float64)


def _read_pcd(path):
    with open(path, "rb") as f:
        header = {}
        while True:
            line = f.readline()
            if not line:
                raise CloudError(f"{path}: PCD header without a DATA line")
            parts = line.decode("ascii", "replace").strip().split()
            if not parts or parts[0].startswith("#"):
                continue
            header[parts[0].upper()] = parts[1:]
            if parts[0].upper() == "DATA":
                break
        body = f.read()
    fields = header["FIELDS"]
    sizes = [int(s) for s in header.get("SIZE", ["4"] * len(fields))]
    types = header.get("TYPE", ["F"] * len(fields))
    counts = [int(c) for c in header.get("COUNT", ["1"] * len(fields))]
    n = int(header["POINTS"][0]) if "POINTS" in header else int(header["WIDTH"][0]) * int(header["HEIGHT"][0])
    kind = header["DATA"][0].lower()
    if kind == "ascii":
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # an empty body: "input contained no data" (the shape check says so)
            rows = np.loadtxt(io.BytesIO(body), dtype=np.float64, ndmin=2, comments=None)  # NumPy's C parser
        columns, i = {}, 0
        for name, c in zip(fields, counts):
            columns[name] = rows[:, i]
            i += c
    elif kind == "binary":
        dtype = np.dtype([(name, {"F": "f", "I": "i", "U": "u"}[t] + str(s), (c,) if c > 1 else ())
                          for name, s, t, c in zip(fields, sizes, types, counts)])
        table = np.frombuffer(body[: n * dtype.itemsize], dtype=dtype, count=n)
        columns = {name: table[name].astype(np.float64) for name in fields}
    else:
        raise CloudError(f"{path}: PCD DATA {kind!r} is not supported (ascii or binary)")
    if not all(c in columns for c in ("x", "y", "z")):
        raise CloudError(f"{path}: PCD without x y z fields (has {fields})")
    cols = [columns[c] for c in ("x", "y", "z")]
    if all(c in columns for c in ("normal_x", "normal_y", "normal_z")):
        cols += [columns[c] for c in ("normal_x", "normal_y", "normal_z")]
    return np.stack(cols, axis=1)


def _read_numpy(path):
    if path.lower().endswith(".npy"):
        return np.load(path, allow_pickle=False)
    with np.load(path, allow_pickle=False) as data:
        if "points" in data.files:
            pts = data["points"]
            return np.concatenate([pts[:, :3], data["normals"]], 1) if "normals" in data.files else pts
        if len(data.files) == 1:
            return data[data.files[0]]
        raise CloudError(f"{path}: NPZ needs a 'points' array (and optionally 'normals'), has {data.files}")


def write_cloud(path: str, points: np.ndarray, normals: np.ndarray | None = None) -> None:
    """Writes ``points (N, 3)`` (and ``normals``) in the format of ``path``'s extension, in float64 (text:
    17 significant digits), so georeferenced coordinates read back as they were."""
    ext = check_format(path)
    points = np.asarray(points, np.float64)
    normals = None if normals is None else np.asarray(normals, np.float64)
    arr = points if normals is None else np.concatenate([points, normals], axis=1)
    names = ["x", "y", "z"] + ([] if normals is None else ["nx", "ny", "nz"])
    if ext == ".ply":
        from plyfile import PlyData, PlyElement
        table = np.empty(len(arr), dtype=[(n, "f8") for n in names])
        for i, n in enumerate(names):
            table[n] = arr[:, i]
        PlyData([PlyElement.describe(table, "vertex")]).write(path)
    elif ext == ".pcd":
        fields = ["x", "y", "z"] + ([] if normals is None else ["normal_x", "normal_y", "normal_z"])
        k = len(fields)
        header = (f"# .PCD v0.7\nVERSION 0.7\nFIELDS {' '.join(fields)}\nSIZE {' '.join(['8'] * k)}\n"
                  f"TYPE {' '.join(['F'] * k)}\nCOUNT {' '.join(['1'] * k)}\nWIDTH {len(arr)}\nHEIGHT 1\n"
                  f"VIEWPOINT 0 0 0 1 0 0 0\nPOINTS {len(arr)}\nDATA binary\n")
        with open(path, "wb") as f:
            f.write(header.encode("ascii"))
            f.write(arr.astype("<f8").tobytes())
    elif ext == ".npy":
        np.save(path, arr)
    elif ext == ".npz":
        np.savez(path, points=points, **({} if normals is None else {"normals": normals}))
    else:
        np.savetxt(path, arr, delimiter="," if ext == ".csv" else " ", fmt="%.17g")


def write_transform(path: str, transform: np.ndarray, **extra) -> None:
    """A 4×4 matrix as ``.txt`` (4 rows, ``numpy.loadtxt`` reads it back) or ``.json``, exact in float64."""
    transform = np.asarray(transform, np.float64)
    if path.lower().endswith(".json"):
        with open(path, "w") as f:
            json.dump({"transform": transform.tolist(), **extra}, f, indent=2)
    else:
        np.savetxt(path, transform, fmt="%.17g")


def write_candidates(path: str, candidates, information: np.ndarray, **extra) -> None:
    """The distinct answers of an alignment (:class:`rpmnet_jax.pairwise.alignment.Answer`, best first) and the
    information matrix of the best, as ``.json`` (float64 exact)."""
    rows = [{"transform": np.asarray(c.transform, np.float64).tolist(), "score": c.score, "fitness": c.fitness,
             "inlier_rmse": c.inlier_rmse, "start": c.init} for c in candidates]
    with open(path, "w") as f:
        json.dump({"candidates": rows, "information": np.asarray(information, np.float64).tolist(), **extra},
                  f, indent=2)


def read_transform(path: str) -> np.ndarray:
    if path.lower().endswith(".json"):
        with open(path) as f:
            return np.asarray(json.load(f)["transform"], np.float64)
    return np.loadtxt(path)
