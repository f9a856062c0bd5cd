"""PCD files (PCL's format), ASCII or binary: fields by name (``normal_x``, packed ``rgb``, ``intensity``);
written in float64 (colours that are bytes as PCL's packed ``rgb``)."""

from __future__ import annotations

import dataclasses
import io
import warnings

import numpy as np

from rpmnet_jax.io import ascii_table, columns as cols


def read(path: str, columns=None) -> cols.Cloud:
    """The cloud of a PCD file (``columns``: the fields by position, after ``rgb`` is split into r g b)."""
    with open(path, "rb") as f:
        header = {}
        while True:
            line = f.readline()
            if not line:
                raise cols.CloudError(f"{path}: PCD header without a DATA line")
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
        parsed = ascii_table.parse_rows(body, 0, n, sum(counts))  # exact fast path, else NumPy's C parser
        if parsed is not None and not body[parsed[1]:].strip():
            rows = parsed[0]
        else:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # an empty body: "input contained no data" (the shape check says so)
                rows = np.loadtxt(io.BytesIO(body), dtype=np.float64, ndmin=2, comments=None)
        table, i = {}, 0
        for name, c in zip(fields, counts):
            table[name] = rows[:, i] if c == 1 else rows[:, i:i + c]
            i += c
    elif kind == "binary":
        dtype = np.dtype([(name, {"F": "f", "I": "i", "U": "u"}[t] + str(s), (c,) if c > 1 else ())
                          for name, s, t, c in zip(fields, sizes, types, counts)])
        data = np.frombuffer(body[: n * dtype.itemsize], dtype=dtype, count=n)
        table = {name: data[name] if _packed_colour(name, c) else data[name].astype(np.float64)  # rgb: its bits
                 for name, c in zip(fields, counts)}
    else:
        raise cols.CloudError(f"{path}: PCD DATA {kind!r} is not supported (ascii or binary)")
    names, values = [], []
    for name, size, typ, count in zip(fields, sizes, types, counts):
        if _packed_colour(name, count):
            names += ["red", "green", "blue"]
            values += _unpack_rgb(table[name], typ, size)
        elif count == 1:
            names.append(name)
            values.append(table[name])
        elif columns is None:  # a histogram or the like: not a point attribute
            continue
        else:
            raise cols.CloudError(f"{path}: --columns cannot name the {count}-value PCD field {name!r}")
    cloud = cols.from_fields(path, names, values, columns)
    viewpoint = _viewpoint(path, header.get("VIEWPOINT"))
    return cloud if viewpoint is None else dataclasses.replace(cloud, viewpoint=viewpoint)


DEFAULT_VIEWPOINT = (0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0)  # PCL's "tx ty tz qw qx qy qz" when nothing is known


def _viewpoint(path: str, values) -> np.ndarray | None:
    """The sensor position ``(3,)`` of a ``VIEWPOINT`` header line (PCL's ``sensor_origin_``: where the sensor
    stood in the cloud's coordinates), ``None`` when absent or PCL's default."""
    if values is None:
        return None
    try:
        numbers = tuple(float(v) for v in values)
    except ValueError:
        raise cols.CloudError(f"{path}: PCD VIEWPOINT must be 7 numbers (tx ty tz qw qx qy qz), got {values}") from None
    if len(numbers) != 7 or not np.all(np.isfinite(numbers)):
        raise cols.CloudError(f"{path}: PCD VIEWPOINT must be 7 finite numbers (tx ty tz qw qx qy qz), got {values}")
    return None if numbers == DEFAULT_VIEWPOINT else np.array(numbers[:3])


def _packed_colour(name: str, count: int) -> bool:
    """Whether a field is PCL's packed colour (read as its raw bits: through float64, an alpha of 255 makes a red of
    128–191 a signalling NaN, which the widening turns quiet, changing the red)."""
    return name.lower() in ("rgb", "rgba") and count == 1


def _unpack_rgb(values: np.ndarray, typ: str, size: int) -> list:
    """PCL's packed colour (``0x00RRGGBB`` in the bits of a float32, or a uint32) as three ``(N,)`` arrays."""
    bits = values.astype(np.float32).view(np.uint32) if typ == "F" and size == 4 else values.astype(np.uint32)
    return [((bits >> s) & 255).astype(np.float64) for s in (16, 8, 0)]


def write(path: str, cloud: cols.Cloud) -> None:
    """Binary PCD, float64 fields (``normal_x`` …, ``intensity``); colours as packed ``rgb`` when they are bytes,
    else as float64 ``red green blue``."""
    names, arrays = ["x", "y", "z"], [cloud.points]
    if cloud.normals is not None:
        names += ["normal_x", "normal_y", "normal_z"]
        arrays.append(cloud.normals)
    packed = cloud.colours is not None and cols.integer_type(cloud.colours, ("u1",)) == "u1"
    if cloud.colours is not None and not packed:
        names += ["red", "green", "blue"]
        arrays.append(cloud.colours)
    if cloud.intensity is not None:
        names.append("intensity")
        arrays.append(cloud.intensity[:, None])
    table = np.empty(len(cloud.points), dtype=[(n, "<f8") for n in names] + ([("rgb", "<f4")] if packed else []))
    for name, column in zip(names, np.concatenate(arrays, axis=1).astype(np.float64).T):
        table[name] = column
    if packed:
        c = cloud.colours.astype(np.uint32)
        table["rgb"] = ((c[:, 0] << 16) | (c[:, 1] << 8) | c[:, 2]).view(np.float32)
    fields = list(table.dtype.names)
    sizes = [str(table.dtype[f].itemsize) for f in fields]
    header = (f"# .PCD v0.7\nVERSION 0.7\nFIELDS {' '.join(fields)}\nSIZE {' '.join(sizes)}\n"
              f"TYPE {' '.join(['F'] * len(fields))}\nCOUNT {' '.join(['1'] * len(fields))}\n"
              f"WIDTH {len(table)}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {len(table)}\nDATA binary\n")
    with open(path, "wb") as f:
        f.write(header.encode("ascii"))
        f.write(table.tobytes())
