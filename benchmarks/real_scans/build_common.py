"""What the real-scan set builders (``build_object.py``, ``build_indoor.py``, ``build_lidar.py``) share.

Reading a file of the source repository at its commit, thinning a scan (first point per voxel, a seeded subsample),
the binary PLY writer, the files beside the scans (``poses.conf``, ``meta.json``, ``SOURCE.md``), posing and
reading back clouds for the pose checks, and the command line. Each builder keeps what is its set's own: its
constants, its readers, its ``SOURCE.md`` text and its pose check.
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import subprocess
import sys
import zlib

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.join(HERE, "..", "..")


def rpmnet_io(module: str):
    """``rpmnet_jax.io.<module>`` of this checkout (the builders run as scripts, from a bare checkout too)."""
    if REPO not in sys.path:
        sys.path.insert(0, REPO)
    return importlib.import_module(f"rpmnet_jax.io.{module}")


def git_show(source: str, commit: str, path: str) -> bytes | None:
    """The bytes of ``path`` at ``commit`` in the git repository ``source``; None if there is none."""
    try:
        done = subprocess.run(["git", "-C", source, "show", f"{commit}:{path}"], capture_output=True, check=False)
    except OSError:
        return None
    return done.stdout if done.returncode == 0 else None


def read_source(source: str, commit: str, path: str, url: str) -> bytes:
    """The bytes of ``path`` (``/``-separated) at ``commit`` of ``source`` (a clone of ``url``), or from
    ``source`` as a checked-out folder."""
    data = git_show(source, commit, path)
    if data is not None:
        return data
    local = os.path.join(source, *path.split("/"))
    if os.path.isfile(local):
        with open(local, "rb") as f:
            return f.read()
    raise OSError(f"{source}: no {path} at commit {commit} (a full clone of {url} is needed)")


def first_per_voxel(points: np.ndarray, voxel: float) -> np.ndarray:
    """The rows of ``points (N, 3)`` that come first (in order) in their ``voxel`` cube, kept in order."""
    cells = np.floor(np.asarray(points, np.float64) / voxel).astype(np.int64)
    _, first = np.unique(cells, axis=0, return_index=True)
    return points[np.sort(first)]


def subsample(points: np.ndarray, name: str, max_points: int, seed: int) -> np.ndarray:
    """At most ``max_points`` rows of ``points``, drawn without replacement by a generator seeded from ``seed``
    and ``crc32(name)``, kept in order."""
    if len(points) <= max_points:
        return points
    rng = np.random.default_rng([seed, zlib.crc32(name.encode("ascii"))])
    return points[np.sort(rng.choice(len(points), max_points, replace=False))]


def write_binary_ply(path: str, points: np.ndarray) -> None:
    """Binary little-endian PLY with one ``vertex`` element of float32 ``x y z``."""
    points = np.ascontiguousarray(points, dtype="<f4")
    header = ("ply\nformat binary_little_endian 1.0\n"
              f"element vertex {len(points)}\nproperty float x\nproperty float y\nproperty float z\nend_header\n")
    with open(path, "wb") as f:
        f.write(header.encode("ascii"))
        f.write(points.tobytes())


def write_scans(out: str, names, sources, kept) -> dict:
    """Writes each cloud of ``kept`` as ``out/<name>.ply``; ``{name: (points of its source, points kept)}``."""
    os.makedirs(out, exist_ok=True)
    for name, points in zip(names, kept):
        write_binary_ply(os.path.join(out, name + ".ply"), points)
    return {name: (len(s), len(k)) for name, s, k in zip(names, sources, kept)}


def source_meta(name: str, kind: str, url: str, commit: str, path: str, licence: str) -> dict:
    """The first keys of a set's ``meta.json``: the set, where it came from, its licence and its units (metres)."""
    return {"name": name, "kind": kind, "source_url": url, "source_commit": commit, "source_path": path,
            "licence": licence, "units": "m"}


def write_set_files(out: str, names, poses, meta: dict, source_md: str, **fields) -> None:
    """Writes into ``out`` the files beside the scans: ``poses.conf`` (``poses (S, 4, 4)``, scan ``<name>.ply``
    -> common frame), ``meta.json``, and ``SOURCE.md`` from the template ``source_md`` filled with ``url``,
    ``commit``, ``path``, ``tune``, ``report``, ``seed`` (from ``meta``), ``count`` (of ``names``) and ``fields``."""
    rpmnet_io("poses").write_poses(os.path.join(out, "poses.conf"), [n + ".ply" for n in names], poses)
    with open(os.path.join(out, "meta.json"), "w") as f:
        json.dump(meta, f, indent=2)
        f.write("\n")
    with open(os.path.join(out, "SOURCE.md"), "w") as f:
        f.write(source_md.format(url=meta["source_url"], commit=meta["source_commit"], path=meta["source_path"],
                                 tune=", ".join(meta["tune"]), report=", ".join(meta["report"]), seed=meta["seed"],
                                 count=len(names), **fields))


def posed(points: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """``(N, 3)`` float64: ``points (N, 3)`` mapped by ``pose (4, 4)`` (scan -> common frame, ``R p + t``)."""
    return np.asarray(points, np.float64) @ pose[:3, :3].T + pose[:3, 3]


def read_written(out: str, name: str) -> np.ndarray:
    """``(N, 3)`` float64 points of the scan ``out/<name>.ply`` as written."""
    return np.asarray(rpmnet_io("clouds").read_cloud(os.path.join(out, name + ".ply"))[0], np.float64)


def print_columns(rows, labels, width: int, digits: int, mean: bool = False) -> None:
    """One line per column of ``rows (P, C)``: its label (right-aligned to ``width``), min - max (and mean)."""
    table = np.array(rows)
    for k, label in enumerate(labels):
        column = table[:, k]
        line = f"{label:>{width}}: {column.min():.{digits}f} - {column.max():.{digits}f}"
        print(line + (f" (mean {column.mean():.{digits}f})" if mean else ""))


def main(argv, doc: str, build, check=None, *, set_name: str, source_help: str, noun: str, width: int) -> int:
    """The builders' command line: ``--source``, ``--out`` (default ``data/<set_name>``) and, where the set has a
    pose check, ``--check``; runs ``build(source, out) -> {name: (source points, kept points)}`` and reports."""
    p = argparse.ArgumentParser(description=doc.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--source", required=True, help=source_help)
    p.add_argument("--out", default=os.path.join(HERE, "data", set_name),
                   help=f"output folder (default: benchmarks/real_scans/data/{set_name})")
    if check is not None:
        p.add_argument("--check", action="store_true", help="also print the pose check (needs SciPy)")
    a = p.parse_args(argv)
    try:
        counts = build(a.source, a.out)
    except (ValueError, OSError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    for name, (n, k) in counts.items():
        print(f"{name:<{width}} {n:>7} -> {k:>6} points")
    print(f"wrote {len(counts)} {noun}, poses.conf, meta.json and SOURCE.md to {a.out}")
    if check is not None and a.check:
        check(a.source, a.out)
    return 0
