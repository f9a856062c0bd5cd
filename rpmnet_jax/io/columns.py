"""What each column of a point table is (x y z, normals, colour, intensity), named by the file or by the caller,
and the :class:`Cloud` every reader returns.

Files with names (PLY properties, PCD fields, a text header, a structured NPY) are read by name; a headerless
table by count only where that is unambiguous: 3 columns are x y z, 4 are x y z intensity, 6 are x y z and
normals when the last three are unit vectors. Anything else needs ``columns`` (``--columns`` on the CLIs).
"""

from __future__ import annotations

import dataclasses
import os

import numpy as np

ALLOWED = "x y z nx ny nz r g b (or red green blue) intensity, and _ to skip a column"
_USER = {"x": "x", "y": "y", "z": "z", "nx": "nx", "ny": "ny", "nz": "nz", "r": "r", "g": "g", "b": "b",
         "red": "r", "green": "g", "blue": "b", "intensity": "intensity", "_": None}
# the names files use (lower case): PLY, PCL's PCD, CloudCompare's text and PLY exports, LAS extra bytes
FILE_NAMES = {**_USER, "normal_x": "nx", "normal_y": "ny", "normal_z": "nz", "normalx": "nx", "normaly": "ny",
              "normalz": "nz", "diffuse_red": "r", "diffuse_green": "g", "diffuse_blue": "b",
              "scalar_intensity": "intensity", "i": "intensity"}
ADVICE = "name the columns with --columns (columns= in Python), e.g. x,y,z,r,g,b"


class CloudError(ValueError):
    """A point-cloud file could not be used; the message is one line for the user."""


def check_readable(path: str) -> None:
    """``CloudError`` unless ``path`` is a file this process may read (missing, a folder, no permission)."""
    if not os.path.exists(path):
        raise CloudError(f"{path}: no such file or folder")
    if os.path.isdir(path):
        raise CloudError(f"{path}: is a folder, not a point-cloud file")
    if not os.access(path, os.R_OK):
        raise CloudError(f"{path}: permission denied")


def unreadable(path: str, kind: str, error: Exception) -> CloudError:
    """The one-line error for a file of a known ``kind`` (``"PLY"`` …) that its reader failed on."""
    message = str(error).strip().splitlines()[0] if str(error).strip() else ""
    return CloudError(f"{path}: cannot read as {kind} ({type(error).__name__}: {message})")


@dataclasses.dataclass(frozen=True)
class Cloud:
    """One point cloud as read: ``points (N, 3)`` float64 (NaN rows stay), and per point ``normals (N, 3)``,
    ``colours (N, 3)`` (the file's own values: 0–255, 0–65535 or 0–1) and ``intensity (N,)``, each or ``None``;
    ``viewpoint (3,)``: where the file says its sensor stood, in the cloud's coordinates (a PCD's ``VIEWPOINT``
    other than PCL's default), else ``None``."""

    points: np.ndarray
    normals: np.ndarray | None = None
    colours: np.ndarray | None = None
    intensity: np.ndarray | None = None
    viewpoint: np.ndarray | None = None

    def moved(self, transform: np.ndarray) -> "Cloud":
        """The cloud moved by ``transform (4, 4)`` (points ``p @ R.T + t``, normals rotated; the rest kept)."""
        t = np.asarray(transform, np.float64)
        normals = None if self.normals is None else self.normals @ t[:3, :3].T
        viewpoint = None if self.viewpoint is None else t[:3, :3] @ self.viewpoint + t[:3, 3]
        return dataclasses.replace(self, points=self.points @ t[:3, :3].T + t[:3, 3], normals=normals,
                                   viewpoint=viewpoint)

    def rows(self, keep: np.ndarray) -> "Cloud":
        """The rows ``keep`` (a boolean mask or indices) of every field."""
        return Cloud(*(None if a is None else a[keep] for a in (self.points, self.normals, self.colours,
                                                                 self.intensity)))


def parse(spec) -> list:
    """The roles (``"x"`` … ``"intensity"``, ``None`` to skip) of ``spec``: ``"x,y,z,r,g,b"`` or a sequence."""
    names = [n.strip().lower() for n in (spec.split(",") if isinstance(spec, str) else spec)]
    unknown = [n for n in names if n not in _USER]
    if unknown:
        raise CloudError(f"unknown column name{'s' * (len(unknown) > 1)} {', '.join(map(repr, unknown))}; "
                         f"use {ALLOWED}")
    return [_USER[n] for n in names]


def from_fields(path: str, names, values, columns=None) -> Cloud:
    """A cloud from the file's fields ``names`` and their ``values`` (each ``(N,)``), in file order: by the
    file's names, or by position when ``columns`` names every field (its names, or ``_`` to skip)."""
    if columns is not None:
        roles = parse(columns)
        if len(roles) != len(values):
            raise CloudError(f"{path}: --columns names {len(roles)} columns, the file has {len(values)} "
                             f"({' '.join(names)})")
    else:
        roles = [FILE_NAMES.get(str(n).lower()) for n in names]
        if not {"x", "y", "z"} <= set(roles):
            raise CloudError(f"{path}: no x y z columns among {list(names)}; {ADVICE}")
    return _assemble(path, roles, values, strict=columns is not None)


def from_array(path: str, table: np.ndarray, columns=None) -> Cloud:
    """A cloud from a table ``(N, K)`` without names: by ``columns``, or by ``K`` where that is unambiguous
    (3: x y z; 4: x y z intensity; 6: x y z and unit normals)."""
    table = np.asarray(table, np.float64)
    if table.ndim != 2:
        raise CloudError(f"{path}: expected a table of N rows, got shape {table.shape}")
    k = table.shape[1]
    if columns is not None:
        roles = parse(columns)
        if len(roles) != k:
            raise CloudError(f"{path}: --columns names {len(roles)} columns, the file has {k}")
        return _assemble(path, roles, list(table.T))
    if k == 6 and not _unit_rows(table[:, 3:]):
        raise CloudError(f"{path}: N×6 values without names whose last three are not unit normals (colours?); "
                         f"{ADVICE}")
    roles = {3: "x y z", 4: "x y z intensity", 6: "x y z nx ny nz"}.get(k)
    if roles is None:
        raise CloudError(f"{path}: N×{k} values without names are ambiguous (3 columns are x y z, 4 x y z intensity, "
                         f"6 x y z and unit normals); {ADVICE}")
    return _assemble(path, roles.split(), list(table.T))


def _unit_rows(vectors: np.ndarray) -> bool:
    finite = np.all(np.isfinite(vectors), axis=1)
    return bool(np.all(np.abs(np.linalg.norm(vectors[finite], axis=1) - 1) < 1e-3))


def _assemble(path, roles, values, strict=True) -> Cloud:
    """The cloud of the columns ``values`` with ``roles``; a group named in part (``r`` without ``g b``) is an
    error when the caller named it (``strict``), left out when the file did."""
    named = [r for r in roles if r is not None]
    twice = sorted({r for r in named if named.count(r) > 1})
    if twice and strict:
        raise CloudError(f"{path}: column {twice[0]!r} is named twice")
    column = {}
    for r, v in zip(roles, values):  # a file's second name for the same thing (i and intensity): the first wins
        if r is not None and r not in column:
            column[r] = np.asarray(v, np.float64)

    def group(keys, what):
        present = [k for k in keys if k in column]
        if present and len(present) < len(keys) and (strict or what == "points"):
            raise CloudError(f"{path}: {what} need all of {' '.join(keys)}, got only {' '.join(present)}")
        return np.stack([column[k] for k in keys], axis=1) if len(present) == len(keys) else None

    points = group(("x", "y", "z"), "points")
    if points is None:
        raise CloudError(f"{path}: no x y z columns; {ADVICE}")
    if len(points) == 0:
        raise CloudError(f"{path}: the cloud is empty")
    return Cloud(points, group(("nx", "ny", "nz"), "normals"), group(("r", "g", "b"), "colours"),
                 column.get("intensity"))


def integer_type(values: np.ndarray | None, kinds=("u1", "u2")) -> str:
    """The smallest of ``kinds`` that holds ``values`` exactly (whole numbers in range), else ``"f8"``."""
    if values is None or len(values) == 0:
        return kinds[0]
    v = np.asarray(values, np.float64)
    if not (np.all(np.isfinite(v)) and np.all(v == np.round(v))):
        return "f8"
    for kind in kinds:
        info = np.iinfo(kind)
        if v.min() >= info.min and v.max() <= info.max:
            return kind
    return "f8"
