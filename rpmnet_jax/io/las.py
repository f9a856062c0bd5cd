"""LAS and LAZ files through ``laspy`` (LAZ with its ``lazrs`` backend): the scaled coordinates in float64,
colours and intensity as stored, normals from ``nx ny nz`` extra bytes.

Written with a header that loses nothing: offset the floor of the minimum, scale the finest power of ten whose
integers still span the cloud (1e-7 m up to 214 m of extent, 1e-6 m up to 2.1 km, ...), so a point 4,000 km from
the origin comes back within half the scale. Rows that are not finite are written as withheld points and read
back as NaN rows. Intensity that is not a whole number in 0–65535 goes into a float64 extra dimension
``scalar_intensity``; colours that are not whole numbers in 0–65535 are scaled from 0–1 to 0–65535.
"""

from __future__ import annotations

import numpy as np

from rpmnet_jax.io import columns as cols

INSTALL = "pip install 'rpmnet_jax[scanners]'"
_INT32 = 2 ** 31 - 2


def check_available(path: str) -> None:
    """``CloudError`` (one line) when ``laspy`` (or, for ``.laz``, a LAZ backend) is not installed."""
    try:
        import laspy
    except ImportError:
        raise cols.CloudError(f"{path}: reading and writing LAS needs laspy: {INSTALL}") from None
    if path.lower().endswith(".laz") and not laspy.LazBackend.detect_available():
        raise cols.CloudError(f"{path}: LAZ needs laspy's lazrs backend: {INSTALL}")


def read(path: str) -> cols.Cloud:
    """The cloud of a LAS/LAZ file: ``points (N, 3)`` float64 (withheld points as NaN rows), colours when the
    point format has them (and they are not all zero), intensity when not all zero, normals from extra bytes."""
    check_available(path)
    import laspy

    las = laspy.read(path)
    if len(las.points) == 0:
        raise cols.CloudError(f"{path}: the LAS file has no points")
    points = np.stack([np.asarray(las.x, np.float64), np.asarray(las.y, np.float64),
                       np.asarray(las.z, np.float64)], axis=1)
    dims = {name.lower(): name for name in las.point_format.dimension_names}
    if "withheld" in dims:
        points[np.asarray(las.withheld, bool)] = np.nan
    colours = None
    if "red" in dims:
        colours = np.stack([np.asarray(las[c], np.float64) for c in ("red", "green", "blue")], axis=1)
        colours = colours if colours.any() else None
    extra = {name.lower(): name for name in las.point_format.extra_dimension_names}
    if "scalar_intensity" in extra:
        intensity = np.asarray(las[extra["scalar_intensity"]], np.float64)
    else:
        intensity = np.asarray(las.intensity, np.float64)
        intensity = intensity if intensity.any() else None
    normals = None
    if all(k in extra for k in ("nx", "ny", "nz")):
        normals = np.stack([np.asarray(las[extra[k]], np.float64) for k in ("nx", "ny", "nz")], axis=1)
    return cols.Cloud(points, normals, colours, intensity)


def header_frame(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(offsets (3,), scales (3,))`` for ``points (N, 3)``: the floor of the minimum, and per axis the finest
    power of ten (1e-9 … 1) whose int32 range covers the extent from it."""
    finite = points[np.all(np.isfinite(points), axis=1)]
    if len(finite) == 0:
        return np.zeros(3), np.full(3, 1e-3)
    offsets = np.floor(finite.min(axis=0))
    extent = finite.max(axis=0) - offsets
    scales = np.array([next(10.0 ** -k for k in range(9, -1, -1) if e / 10.0 ** -k <= _INT32) for e in extent])
    return offsets, scales


def write(path: str, cloud: cols.Cloud) -> None:
    """LAS 1.4 (point format 6, or 7 with colours); LAZ when ``path`` ends in ``.laz``."""
    check_available(path)
    import laspy

    points = np.asarray(cloud.points, np.float64)
    bad = ~np.all(np.isfinite(points), axis=1)
    header = laspy.LasHeader(point_format=6 if cloud.colours is None else 7, version="1.4")
    header.offsets, header.scales = header_frame(points)
    whole = cloud.intensity is not None and cols.integer_type(cloud.intensity, ("u2",)) == "u2"
    extra = ([laspy.ExtraBytesParams(name=k, type=np.float64) for k in ("nx", "ny", "nz")]
             if cloud.normals is not None else [])
    if cloud.intensity is not None and not whole:
        extra.append(laspy.ExtraBytesParams(name="scalar_intensity", type=np.float64))
    if extra:
        header.add_extra_dims(extra)
    las = laspy.LasData(header)
    safe = np.where(bad[:, None], header.offsets, points)
    las.x, las.y, las.z = safe[:, 0], safe[:, 1], safe[:, 2]
    las.withheld = bad
    if cloud.colours is not None:
        colours = np.asarray(cloud.colours, np.float64)
        if cols.integer_type(colours, ("u2",)) != "u2":
            colours = np.clip(np.nan_to_num(colours), 0, 1) * 65535
        for k, name in enumerate(("red", "green", "blue")):
            las[name] = np.round(colours[:, k]).astype(np.uint16)
    if cloud.intensity is not None:
        if whole:
            las.intensity = np.asarray(cloud.intensity).astype(np.uint16)
        else:
            las["scalar_intensity"] = np.asarray(cloud.intensity, np.float64)
    if cloud.normals is not None:
        for k, name in enumerate(("nx", "ny", "nz")):
            las[name] = np.asarray(cloud.normals[:, k], np.float64)
    las.write(path)
