"""Reading and writing point clouds and transforms: PLY, PCD, XYZ/TXT/CSV, NPY/NPZ, LAS/LAZ, E57.

:func:`read` gives a :class:`~rpmnet_jax.io.columns.Cloud` (points, and normals, colours and intensity where the
file has them, named by the file or by ``columns``); :func:`write_cloud` writes every field in float64 where the
format allows, so georeferenced coordinates read back as they were.
"""

from __future__ import annotations

import json
import os

import numpy as np

from rpmnet_jax.io import columns as cols, e57, las, pcd, ply, text

FORMATS = (".ply", ".pcd", ".xyz", ".txt", ".csv", ".npy", ".npz", ".las", ".laz", ".e57")
Cloud = cols.Cloud
CloudError = cols.CloudError


def check_format(path: str) -> str:
    """The extension of ``path``; ``CloudError`` when unknown, or when its reader is not installed (LAS, E57)."""
    ext = os.path.splitext(path)[1].lower()
    if ext not in FORMATS:
        raise CloudError(f"{path}: unknown point-cloud format {ext or '(none)'!r}; use one of {', '.join(FORMATS)}")
    if ext in (".las", ".laz"):
        las.check_available(path)
    elif ext == ".e57":
        e57.check_available(path)
    return ext


def read(path: str, columns=None) -> Cloud:
    """The cloud in ``path``: ``points (N, 3)`` float64 and the normals, colours and intensity it has.

    ``columns`` (``"x,y,z,r,g,b"`` or a list; ``_`` skips a column) names the columns of a text, NPY, PLY or PCD
    file by position, for files whose own names (or lack of them) do not say.
    """
    if os.path.splitext(path)[1]:
        check_format(path)  # '.obj': the format is the news, whether or not the file is there
    cols.check_readable(path)  # a missing folder or file is said as such, not as a format '(none)'
    ext = check_format(path)
    if columns is not None:
        cols.parse(columns)  # unknown names: said before the file is read
        if ext in (".las", ".laz", ".e57", ".npz"):
            raise CloudError(f"{path}: --columns applies to text, NPY, PLY and PCD files; {ext[1:].upper()} names "
                             "its fields")
    try:
        if ext == ".ply":
            vertex = ply.read_vertices(path)
            names = [n for n in vertex.dtype.names or () if vertex.dtype[n].kind in "iuf" and not vertex.dtype[n].shape]
            return cols.from_fields(path, names, [vertex[n] for n in names], columns)
        if ext == ".pcd":
            return pcd.read(path, columns)
        if ext in (".las", ".laz"):
            return las.read(path)
        if ext == ".e57":
            return e57.read(path)
        if ext in (".npy", ".npz"):
            return _read_numpy(path, columns)
        return text.read(path, columns)
    except CloudError:
        raise
    except Exception as e:  # malformed file of a known format
        raise cols.unreadable(path, ext[1:].upper(), e) from None


def read_cloud(path: str, columns=None) -> tuple[np.ndarray, np.ndarray | None]:
    """``points (N, 3)`` float64 and ``normals (N, 3)`` or ``None`` from a file (:func:`read` without the rest)."""
    cloud = read(path, columns)
    return cloud.points, cloud.normals


def _read_numpy(path, columns):
    if path.lower().endswith(".npy"):
        table = np.load(path, allow_pickle=False)
        if table.dtype.names:  # a structured array: its field names
            names = [n for n in table.dtype.names if not table.dtype[n].shape]
            return cols.from_fields(path, names, [table[n] for n in names], columns)
        return cols.from_array(path, table, columns)
    with np.load(path, allow_pickle=False) as data:
        if "points" in data.files:
            pts = np.asarray(data["points"], np.float64)
            if pts.ndim != 2 or pts.shape[1] < 3:
                raise CloudError(f"{path}: 'points' must be N×3, got shape {pts.shape}")
            parts = {k: np.asarray(data[k], np.float64) for k in ("normals", "colours", "intensity") if k in data.files}
            if len(pts) == 0:
                raise CloudError(f"{path}: the cloud is empty")
            return Cloud(pts[:, :3], parts.get("normals"), parts.get("colours"), parts.get("intensity"))
        if len(data.files) == 1:
            return cols.from_array(path, data[data.files[0]])
        raise CloudError(f"{path}: NPZ needs a 'points' array (and optionally 'normals', 'colours', 'intensity'), "
                         f"has {data.files}")


def write_cloud(path: str, points: np.ndarray, normals: np.ndarray | None = None, colours: np.ndarray | None = None,
                intensity: np.ndarray | None = None) -> None:
    """Writes ``points (N, 3)`` (and ``normals (N, 3)``, ``colours (N, 3)``, ``intensity (N,)``) in the format of
    ``path``'s extension (:func:`write`)."""
    as_array = (lambda a: None if a is None else np.asarray(a, np.float64))
    write(path, Cloud(as_array(points), as_array(normals), as_array(colours), as_array(intensity)))


def write(path: str, cloud: Cloud) -> None:
    """Writes ``cloud`` row for row (NaN rows stay) in the format of ``path``'s extension: float64 coordinates
    (text: 17 significant digits; LAS: a scale and offset that lose nothing, :mod:`~rpmnet_jax.io.las`)."""
    ext = check_format(path)
    if ext == ".ply":
        _write_ply(path, cloud)
    elif ext == ".pcd":
        pcd.write(path, cloud)
    elif ext in (".las", ".laz"):
        las.write(path, cloud)
    elif ext == ".e57":
        e57.write(path, [cloud])
    elif ext == ".npy":
        _write_npy(path, cloud)
    elif ext == ".npz":
        np.savez(path, points=cloud.points, **{k: getattr(cloud, k) for k in ("normals", "colours", "intensity")
                                                if getattr(cloud, k) is not None})
    else:
        text.write(path, cloud)


def _fields(cloud: Cloud, colour_type: str) -> list:
    """``[(name, type, (N,) values)]`` of a cloud's fields, with PLY's names."""
    out = [(n, "f8", cloud.points[:, k]) for k, n in enumerate("xyz")]
    if cloud.normals is not None:
        out += [(n, "f8", cloud.normals[:, k]) for k, n in enumerate(("nx", "ny", "nz"))]
    if cloud.colours is not None:
        out += [(n, colour_type, cloud.colours[:, k]) for k, n in enumerate(("red", "green", "blue"))]
    if cloud.intensity is not None:
        out.append(("intensity", "f8", cloud.intensity))
    return out


def _write_ply(path: str, cloud: Cloud) -> None:
    from plyfile import PlyData, PlyElement

    fields = _fields(cloud, cols.integer_type(cloud.colours))
    table = np.empty(len(cloud.points), dtype=[(n, t) for n, t, _ in fields])
    for name, _, values in fields:
        table[name] = values
    PlyData([PlyElement.describe(table, "vertex")]).write(path)


def _write_npy(path: str, cloud: Cloud) -> None:
    """A plain ``(N, 3)`` or ``(N, 6)`` array for points (and normals); a structured array with named fields
    (``x y z nx ny nz red green blue intensity``) when there are colours or intensity."""
    if cloud.colours is None and cloud.intensity is None:
        arrays = [cloud.points] + ([] if cloud.normals is None else [cloud.normals])
        np.save(path, np.concatenate(arrays, axis=1))
        return
    fields = _fields(cloud, "f8")
    table = np.empty(len(cloud.points), dtype=[(n, t) for n, t, _ in fields])
    for name, _, values in fields:
        table[name] = values
    np.save(path, table)


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
    information matrix of the best, as ``.json`` (float64 exact): each answer's fields by their ``Answer`` names."""
    rows = [{"transform": np.asarray(c.transform, np.float64).tolist(), "score": c.score, "fitness": c.fitness,
             "inlier_rmse": c.inlier_rmse, "init": c.init, "support": list(getattr(c, "support", ()))}
            for c in candidates]
    with open(path, "w") as f:
        json.dump({"candidates": rows, "information": np.asarray(information, np.float64).tolist(), **extra},
                  f, indent=2)


def read_transform(path: str) -> np.ndarray:
    if path.lower().endswith(".json"):
        with open(path) as f:
            return np.asarray(json.load(f)["transform"], np.float64)
    return np.loadtxt(path)
