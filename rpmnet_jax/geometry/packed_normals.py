"""Unit normals in four bytes: two int16 of the octahedral map (Cigolle et al., "A survey of efficient
representations for independent unit vectors", JCGT 2014), for the scans a site holds all at once.

A unit normal ``n`` goes to ``p = (n_x, n_y) / (|n_x| + |n_y| + |n_z|)`` on the octahedron's upper half, the lower
half folded over the square's corners; ``p ∈ [-1, 1]²`` is rounded to ``SCALE`` steps. Back: ``(p, 1 − |p_x| −
|p_y|)`` unfolded and made unit. Every normal comes back within ``MAX_ERROR`` radians (12 bytes a normal in float32,
4 here: a 1,000-station site's finer scans 552 → 184 MB). A normal that is not finite is held as ``NAN_CODE`` and
comes back NaN. :func:`unit` reads either kind of normals, :func:`row` the same in compiled loops.
"""

from __future__ import annotations

import numba
import numpy as np

SCALE = 32767  # steps of p on each side of 0
NAN_CODE = -32768  # outside ±SCALE: a normal that was not finite
MAX_ERROR = 1e-4  # radians (0.006 deg): the bound on the angle between a unit normal and its packed copy (the
# largest over a million random normals: 6.4e-5, tests/packed_normals_test.py)


def pack(normals) -> np.ndarray:
    """``(N, 2)`` int16 codes of unit ``normals (N, 3)`` (non-finite or zero rows: ``NAN_CODE``)."""
    n = np.asarray(normals, np.float64).reshape(-1, 3)
    with np.errstate(invalid="ignore", divide="ignore"):
        p = n[:, :2] / np.abs(n).sum(axis=1, keepdims=True)
        signs = np.where(p >= 0.0, 1.0, -1.0)
        folded = (1.0 - np.abs(p[:, ::-1])) * signs
        p = np.where(n[:, 2:3] < 0.0, folded, p)
        codes = np.round(p * SCALE)
    codes[~(np.all(np.isfinite(n), axis=1) & np.all(np.isfinite(codes), axis=1))] = NAN_CODE  # (0, 0, inf) too
    return codes.astype(np.int16)


def unpack(codes, dtype=np.float32) -> np.ndarray:
    """``(N, 3)`` unit normals in ``dtype`` of ``codes (N, 2)`` (:func:`pack`'s; ``NAN_CODE``: NaN), each read by
    :func:`row`."""
    codes = np.ascontiguousarray(codes, np.int16).reshape(-1, 2)
    out = np.empty((len(codes), 3))
    _unpack_rows(codes, out)
    return out.astype(dtype, copy=False)


def is_packed(normals) -> bool:
    """Whether ``normals`` hold :func:`pack`'s codes (``(N, 2)`` int16), not unit vectors."""
    return normals.dtype == np.int16 and normals.ndim == 2 and normals.shape[1] == 2


def unit(normals, rows=None) -> np.ndarray:
    """The unit normals of ``normals`` (unit vectors ``(N, 3)``: as they are; :func:`pack`'s codes: unpacked, in
    float32), only ``rows`` when given."""
    picked = normals if rows is None else normals[rows]
    return unpack(picked) if is_packed(normals) else picked


@numba.njit(cache=True, inline="always")
def row(normals, k, out) -> None:
    """``out (3,)`` = the unit normal of row ``k`` of ``normals``: ``(N, 3)`` unit vectors, or ``(N, 2)`` codes
    (:func:`unpack` in a compiled loop, the same numbers in float64)."""
    if normals.shape[1] == 2:
        u, v = normals[k, 0], normals[k, 1]
        if u == NAN_CODE or v == NAN_CODE:
            out[0] = out[1] = out[2] = np.nan
            return
        x, y = u / SCALE, v / SCALE
        z = 1.0 - (abs(x) + abs(y))
        if z < 0.0:
            x, y = (1.0 - abs(y)) * (1.0 if x >= 0.0 else -1.0), (1.0 - abs(x)) * (1.0 if y >= 0.0 else -1.0)
        norm = np.sqrt(x * x + y * y + z * z)
        out[0], out[1], out[2] = x / norm, y / norm, z / norm
    else:
        out[0], out[1], out[2] = normals[k, 0], normals[k, 1], normals[k, 2]


@numba.njit(cache=True)
def _unpack_rows(codes, out) -> None:
    """``out (N, 3)`` = every row of ``codes (N, 2)`` read by :func:`row`."""
    for k in range(len(codes)):
        row(codes, k, out[k])
