"""The vertex table of a PLY file, read at the speed of a C++ reader.

A PLY file is a header (elements, each with typed properties) and then the elements' rows in order. Range scans
put their vertices first and a large second element after them (the Stanford scans: a 204,800-row
``range_grid`` of lists); only the vertices are needed. When the vertex element comes first and has no list
properties, its rows are parsed by one compiled loop (ASCII, :mod:`rpmnet_jax.io.ascii_table`) or NumPy's
``frombuffer`` (binary), and the rest of the file is never parsed: a few ms for the 40,097 vertices of
``bun045.ply`` where parsing the whole file with ``plyfile`` took 2.5–4.9 s. Any other layout goes through
``plyfile``.

:func:`read_mesh` reads a triangle mesh (vertices and a ``vertex_indices`` / ``vertex_index`` face list) the same
way: the common layout (vertices, then triangles and nothing else on a face row) parsed directly, any other
(polygons, fan-triangulated; other elements between) through ``plyfile``.
"""

from __future__ import annotations

import io
import warnings
from typing import NamedTuple

import numpy as np

from rpmnet_jax.io import ascii_table, columns

TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2", "ushort": "u2",
         "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4", "float": "f4", "float32": "f4",
         "double": "f8", "float64": "f8"}
FORMATS = {"ascii": None, "binary_little_endian": "<", "binary_big_endian": ">"}
FACE_LISTS = ("vertex_indices", "vertex_index")  # the names of a face's vertex list


class Element(NamedTuple):
    name: str
    count: int
    properties: list  # [(name, type)]; a list property's type is "list"
    lists: dict  # {name: (count type, item type)} of the list properties (PLY type names)


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
            elements.append(Element(words[1], int(words[2]), [], {}))
        elif words[0] == "property" and elements and len(words) == 3 and words[1] in TYPES:
            elements[-1].properties.append((words[2], words[1]))
        elif words[0] == "property" and elements and len(words) == 5 and words[1] == "list":
            elements[-1].properties.append((words[4], "list"))
            elements[-1].lists[words[4]] = (words[2], words[3])
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


def read_mesh(path: str) -> tuple[np.ndarray, np.ndarray]:
    """``vertices (V, 3)`` float64 and triangles ``faces (F, 3)`` int64 (vertex rows) of a PLY mesh; polygons are
    fan-triangulated. A file that is not a readable mesh: a one-line :class:`~rpmnet_jax.io.columns.CloudError`."""
    try:
        with open(path, "rb") as f:
            header = read_header(f)
            names = [e.name for e in header.elements]
            if "vertex" not in names or "face" not in names:
                raise ValueError(f"no {'vertex' if 'vertex' not in names else 'face'} element: not a mesh")
            mesh = _triangles_fast(f, header)
        vertices, faces = mesh if mesh is not None else _mesh_with_plyfile(path)
        if faces.size and (faces.min() < 0 or faces.max() >= len(vertices)):
            raise ValueError(f"face indices outside the {len(vertices)} vertices")
        return vertices, faces
    except Exception as e:  # a damaged file of any kind is one line for the user
        message = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise columns.CloudError(f"{path}: cannot read as a PLY mesh ({message})") from None


def _triangles_fast(f, header: Header):
    """``(vertices, faces)`` of the common layout (vertex element first, no lists in it; then a face element of
    one vertex list, triangles only), ``f`` just after the header; None for any other layout."""
    if len(header.elements) < 2 or [e.name for e in header.elements[:2]] != ["vertex", "face"]:
        return None
    vertex, face = header.elements[:2]
    props = dict(vertex.properties)
    if (any(t == "list" for t in props.values()) or any(k not in props for k in "xyz")
            or len(face.properties) != 1 or face.properties[0][0] not in FACE_LISTS
            or any(t not in TYPES for t in face.lists.get(face.properties[0][0], ("?",)))):
        return None
    order = FORMATS[header.format]
    if order is None:
        body = f.read()
        rows = ascii_table.parse_rows(body, 0, vertex.count, len(vertex.properties))
        tris = rows and ascii_table.parse_rows(body, rows[1], face.count, 4)
        if not tris or np.any(tris[0][:, 0] != 3) or np.any(tris[0][:, 1:] != np.round(tris[0][:, 1:])):
            return None  # not the exact fast path, or polygons: plyfile reads it
        names = [n for n, _ in vertex.properties]  # each coordinate in its declared type, as plyfile reads it
        xyz = np.stack([rows[0][:, names.index(k)].astype(TYPES[props[k]]) for k in "xyz"], axis=1)
        return xyz.astype(np.float64), tris[0][:, 1:].astype(np.int64)
    dtype = np.dtype([(name, order + TYPES[t]) for name, t in vertex.properties])
    count_type, item_type = face.lists[face.properties[0][0]]
    tri_dtype = np.dtype([("n", order + TYPES[count_type]), ("i", order + TYPES[item_type], (3,))])
    body = f.read(vertex.count * dtype.itemsize + face.count * tri_dtype.itemsize)
    if len(body) < vertex.count * dtype.itemsize + face.count * tri_dtype.itemsize:
        return None  # short, or polygons: plyfile reads it or says what is wrong
    table = np.frombuffer(body, dtype=dtype, count=vertex.count)
    tris = np.frombuffer(body, dtype=tri_dtype, count=face.count, offset=vertex.count * dtype.itemsize)
    if np.any(tris["n"] != 3):
        return None
    xyz = np.stack([table[k].astype(np.float64) for k in "xyz"], axis=1)
    return xyz, tris["i"].astype(np.int64)


def _mesh_with_plyfile(path: str):
    """``(vertices, faces)`` of any PLY mesh ``plyfile`` reads; polygons fan-triangulated."""
    from plyfile import PlyData

    with warnings.catch_warnings():  # ASCII files with an empty list make NumPy warn
        warnings.filterwarnings("ignore", message="loadtxt: input contained no data")
        data = PlyData.read(path)
    vertex, face = data["vertex"].data, data["face"].data
    xyz = np.stack([np.asarray(vertex[k], np.float64) for k in "xyz"], axis=1)
    name = next((n for n in FACE_LISTS if n in (face.dtype.names or ())), None)
    if name is None:
        raise ValueError(f"the face element has no {' or '.join(FACE_LISTS)} list")
    tris = [[p[0], p[k], p[k + 1]] for p in face[name] for k in range(1, len(p) - 1)]
    return xyz, np.asarray(tris, np.int64).reshape(-1, 3)
