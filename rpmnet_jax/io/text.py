"""Text point clouds (``.xyz .txt .csv``): one point a row, values split by whitespace or commas, columns named
by a header line when there is one (``x,y,z,r,g,b``, CloudCompare's ``//X Y Z R G B``, or a ``#`` comment of
column names), else by count (:func:`rpmnet_jax.io.columns.from_array`)."""

from __future__ import annotations

import warnings

import numpy as np

from rpmnet_jax.io import columns as cols


def read(path: str, columns=None) -> cols.Cloud:
    names, skip, delimiter = _layout(path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # NumPy warns on an empty file; the empty check says so
        table = np.loadtxt(path, delimiter=delimiter, ndmin=2, comments=("#", "//"), skiprows=skip)
    if table.size == 0:
        raise cols.CloudError(f"{path}: the cloud is empty")
    if columns is None and names is not None:
        if len(names) != table.shape[1]:
            raise cols.CloudError(f"{path}: the header names {len(names)} columns, the rows have {table.shape[1]}")
        return cols.from_fields(path, names, list(table.T))
    return cols.from_array(path, table, columns)


def _layout(path: str):
    """``(header names or None, lines to skip, delimiter)`` from the first lines of the file."""
    names, skip, delimiter = None, 0, None
    with open(path, encoding="utf-8", errors="replace") as f:
        for number, line in enumerate(f):
            text = line.strip().lstrip("\ufeff")
            if not text:
                continue
            if text.startswith("//") or (number == 0 and not text.startswith("#") and not _numbers(text)):
                names, skip = _split(text.lstrip("/")), (0 if text.startswith("//") else number + 1)
                continue
            if text.startswith("#"):  # a comment; a header only if every word names a column
                words = _split(text.lstrip("#"))
                if names is None and words and all(w.lower() in cols.FILE_NAMES for w in words):
                    names = words
                continue
            delimiter = "," if "," in text else None
            break
    return names, skip, delimiter


def _split(text: str) -> list:
    return [w for w in text.replace(",", " ").replace(";", " ").split() if w]


def _numbers(text: str) -> bool:
    try:
        [float(w) for w in _split(text)]
        return True
    except ValueError:
        return False


def write(path: str, cloud: cols.Cloud) -> None:
    """Every field at 17 significant digits (float64 reads back exactly); a ``#`` header line naming the columns
    when there are colours or intensity (x y z and normals alone: none, as before)."""
    names, arrays = ["x", "y", "z"], [cloud.points]
    if cloud.normals is not None:
        names += ["nx", "ny", "nz"]
        arrays.append(cloud.normals)
    if cloud.colours is not None:
        names += ["r", "g", "b"]
        arrays.append(cloud.colours)
    if cloud.intensity is not None:
        names.append("intensity")
        arrays.append(cloud.intensity[:, None])
    delimiter = "," if path.lower().endswith(".csv") else " "
    header = "" if len(names) in (3, 6) and cloud.colours is None else delimiter.join(names)
    np.savetxt(path, np.concatenate(arrays, axis=1).astype(np.float64), delimiter=delimiter, fmt="%.17g",
               header=header, comments="# ")
