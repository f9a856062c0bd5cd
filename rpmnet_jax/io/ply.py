"""The vertex table of a PLY file, read at the speed of a C++ reader.

A PLY file is a header (elements, each with typed properties) and then the elements' rows in order. Range scans
put their vertices first and a large second element after them (the Stanford scans: a 204,800-row
``range_grid`` of lists); only the vertices are needed. When the vertex element comes first and has no list
properties, its rows are parsed by one compiled loop (ASCII, :mod:`rpmnet_jax.io.ascii_table`) or NumPy's
``frombuffer`` (binary), and the rest of the file is never parsed: a few ms for the 40,097 vertices of
``bun045.ply`` where parsing the whole file with ``plyfile`` took 2.5–4.9 s. Any other layout goes through
``plyfile``.
"""

from __future__ import annotations

import io
import warnings
from typing import NamedTuple

import numpy as np

from rpmnet_jax.io import ascii_table

TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2", "ushort": "u2",
         "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4", "float": "f4", "float32": "f4",
         "double": "f8", "float64": "f8"}
FORMATS = {"ascii": None, "binary_little_endian": "<", "binary_big_endian": ">"}


class Element(NamedTuple):
    name: str
    count: int
    properties: list  # [(name, type)]; a list property's type is "list"


class Header(NamedTuple):
    format: str  # "ascii", "binary_little_endian" or "binary_big_endian"
    elements: list  # [Element], in file order
    size: int  # bytes up to and including the end_header line


def read_header(f) -> Header:
    """The header of the PLY file open for binary reading at its start; ``ValueError`` when it is not one."""
    if f.readline().strip() != b"ply":
        raise ValueError("not a PLY file (no 'ply' magic line)")
    fmt, elements, size = None, [], 4
    while True:
        line = f.readline()
        if not line:
            raise ValueError("PLY header without end_header")
        size += len(line)
        words = line.decode("ascii", "replace").split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "end_header":
            break
        if words[0] == "format" and len(words) == 3 and words[1] in FORMATS:
            fmt = words[1]
        elif words[0] == "element" and len(words) == 3 and words[2].isdigit():
            elements.append(Element(words[1], int(words[2]), []))
        elif words[0] == "property" and elements and len(words) == 3 and words[1] in TYPES:
            elements[-1].properties.append((words[2], words[1]))
        elif words[0] == "property" and elements and len(words) == 5 and words[1] == "list":
            elements[-1].properties.append((words[4], "list"))
        else:
            raise ValueError(f"malformed PLY header line {line.strip()[:60]!r}")
    if fmt is None:
        raise ValueError("PLY header without a known format line")
    return Header(fmt, elements, size)


def read_vertices(path: str) -> np.ndarray:
    """The vertex element of a PLY file as a structured array (the file's own property names and types)."""
    with open(path, "rb") as f:
        header = read_header(f)
        first = header.elements[0] if header.elements else None
        if first is None or first.name != "vertex" or any(t == "list" for _, t in first.properties):
            return _with_plyfile(path)
        order = FORMATS[header.format]
        dtype = np.dtype([(name, (order or "<") + TYPES[t]) for name, t in first.properties])
        if order is None:
            return _ascii_rows(f, first, dtype)
        body = f.read(first.count * dtype.itemsize)
        if len(body) < first.count * dtype.itemsize:
            raise ValueError(f"the header declares {first.count} vertices; the file ends after "
                             f"{len(body) // dtype.itemsize}")
        return np.frombuffer(body, dtype=dtype, count=first.count)


def _ascii_rows(f, vertex: Element, dtype: np.dtype) -> np.ndarray:
    """``vertex.count`` rows of the ASCII body of ``f`` as a structured array of ``dtype``: parsed in float64 (what
    every PLY type converts to exactly) by :mod:`rpmnet_jax.io.ascii_table` (NumPy's ``loadtxt`` where its exact
    fast path does not apply), then cast to the declared types."""
    k = len(vertex.properties)
    body = f.read()
    parsed = ascii_table.parse_rows(body, 0, vertex.count, k)
    if parsed is not None:
        rows = parsed[0]
    else:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # an empty vertex table: "input contained no data"
            rows = np.loadtxt(io.BytesIO(body), dtype=np.float64, max_rows=vertex.count, ndmin=2, comments=None)
    if vertex.count and (rows.shape[0] != vertex.count or rows.shape[1] != k):
        raise ValueError(f"the header declares {vertex.count} vertices of {k} values; the body has "
                         f"{rows.shape[0]} rows of {rows.shape[1]}")
    out = np.empty(vertex.count, dtype=dtype)
    for i, name in enumerate(dtype.names):
        out[name] = rows[:, i] if vertex.count else []
    return out


def _with_plyfile(path: str) -> np.ndarray:
    from plyfile import PlyData

    with warnings.catch_warnings():  # ASCII files with an empty face list make NumPy warn
        warnings.filterwarnings("ignore", message="loadtxt: input contained no data")
        return PlyData.read(path)["vertex"].data
