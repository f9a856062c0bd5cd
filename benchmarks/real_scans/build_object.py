"""Rebuilds ``benchmarks/real_scans/data/happy_stand/`` from a copy of its source repository.

The set is ten real range scans of the Happy Buddha statuette from the Stanford 3D Scanning Repository
(Cyberware 3030MS optical triangulation scanner), with the ground-truth pose of each scan from the
``happyStandRight.conf`` shipped beside them. The scans come from a public GitHub repository that carries the
Stanford files unchanged under ``data/happy_stand/``; get it with::

    git clone https://github.com/thegyro/Project4-Scan-Matching.git
    git -C Project4-Scan-Matching checkout 8cdb8ae86bade5717851d7dbb7080993c138c150

then::

    python benchmarks/real_scans/build_object.py --source Project4-Scan-Matching \\
        --out benchmarks/real_scans/data/happy_stand

Only the data are read (``data/happy_stand/happyStandRight.conf`` and ``happyStandRight_<angle>.ply``); no code of
that repository is used. Each scan keeps the frame the scanner gave it; at most ``MAX_POINTS`` of its vertices are
kept, drawn without replacement by a generator seeded from ``SEED`` and the scan's name (kept in file order), and
written as binary little-endian PLY with float32 ``x y z`` only. ``poses.conf`` holds the source's poses of the
kept scans (scan frame -> common frame) in :func:`rpmnet_jax.io.poses.write_poses`' convention, which is the
source's own; ``meta.json`` and ``SOURCE.md`` say where it all came from. Run it twice and the output is byte for
byte the same.
"""

from __future__ import annotations

import os
import sys

import numpy as np

import build_common as common

SET_NAME = "happy_stand"
SOURCE_URL = "https://github.com/thegyro/Project4-Scan-Matching"
SOURCE_COMMIT = "8cdb8ae86bade5717851d7dbb7080993c138c150"
SOURCE_DIR = "data/happy_stand"
CONF = "happyStandRight.conf"
SEED = 20240611
MAX_POINTS = 40_000
# Turntable steps of 24 degrees; each part is a contiguous arc, so its scans overlap among themselves.
TUNE = [f"happyStandRight_{a}" for a in (0, 24, 48, 72)]
REPORT = [f"happyStandRight_{a}" for a in (144, 168, 192, 216, 240, 264)]
LICENCE = (
    "Stanford 3D Scanning Repository terms: \"You are welcome to use the data and models for research purposes. "
    "You are also welcome to mirror or redistribute them for free, with appropriate credit given. However, they "
    "are not to be used for commercial purposes, nor should they appear in a product for sale, without Stanford "
    "University Computer Graphics Laboratory permission.\" Credit: Stanford University Computer Graphics "
    "Laboratory, http://graphics.stanford.edu/data/3Dscanrep/ (the source GitHub repository has no licence file "
    "of its own for the data)."
)
SCANNER = ("Cyberware 3030MS optical triangulation scanner, after spacetime analysis of the range video "
           "(data/happy_stand/README)")
SOURCE_MD = """\
# happy_stand: real range scans of the Stanford Happy Buddha, with ground-truth poses

Written by `benchmarks/real_scans/build_object.py`; rebuild it with that script rather than editing it.

## Source

- Data: the Stanford 3D Scanning Repository, Happy Buddha, "stand" series (`happyStandRight_<angle>.ply`,
  turntable steps of 24 degrees, and `happyStandRight.conf`), http://graphics.stanford.edu/data/3Dscanrep/
  (Stanford University Computer Graphics Laboratory; Brian Curless and Marc Levoy).
- Copy read: {url}
  at commit `{commit}`, folder `{path}/` (the Stanford files as committed there:
  ASCII range-image PLYs with their `range_grid`, the `.conf` and the Stanford `README`). Only these data files were read; no code of that
  repository is used or copied.
- Scanner, as the Stanford `README` beside the scans says: "These data files were obtained with a Cyberware 3030MS
  optical triangulation scanner, after performing spacetime analysis on the range video.  They are stored as range
  images in the \"ply\" format. The \".conf\" file contains the transformations required to bring each range
  image into a single coordinate system."
- Units: metres (the statuette is about 20 cm tall; the posed scans span about 0.082 x 0.200 x 0.082 m).

## Licence / terms

The source GitHub repository has no licence of its own for these files; they are the Stanford 3D Scanning
Repository's, whose terms are (as the Stanford repository states them, reproduced for example in Apple's
GLUTSurfaceTexture sample, `stanfordbunny.h`):

> You are welcome to use the data and models for research purposes. You are also welcome to mirror or
> redistribute them for free, with appropriate credit given. However, they are not to be used for commercial
> purposes, nor should they appear in a product for sale, without Stanford University Computer Graphics
> Laboratory permission.

Credit: Stanford University Computer Graphics Laboratory, The Stanford 3D Scanning Repository,
http://graphics.stanford.edu/data/3Dscanrep/ . Research use only; not for commercial use.

## What is here

- {count} of the 15 scans, split by scan; each part is a contiguous arc of the turntable, so its scans overlap
  among themselves, and the parts share no scan:
  - `tune` (0-72 degrees): {tune}
  - `report` (144-264 degrees): {report}
- Each `<scan>.ply`: binary little-endian PLY, float32 `x y z` only, in the scan's own frame as the scanner gave it
  (not posed). At most {max_points} of the scan's vertices, drawn uniformly without replacement by
  `numpy.random.default_rng([{seed}, crc32(scan name)])` and kept in file order (these 10 sources have
  60,735-85,036 vertices). The range grid and the scans' `obj_info` lines are dropped, as is the `.conf`'s `camera` line and
  its `mesh happyStandRight_cybcyl` line (a cylindrical scan that is not in the folder).
- `poses.conf`: the source's ground-truth pose of each kept scan, scan frame -> common frame, written by
  `rpmnet_jax.io.poses.write_poses` (`bmesh NAME tx ty tz qx qy qz qw`, the Stanford convention: world points are
  `p @ R + t` with `R` the quaternion's matrix); it reads back equal to the source's `.conf` lines (to 4e-16).
- `meta.json`: name, kind, source, commit, licence, units, scanner, the tune/report split, seed and source counts.

## Check of the poses

With these poses, each scan against its 24-degree neighbour in the same part (the subsampled files here): of the
points within 5 mm of the neighbour (their overlap, 86-98% of the scan), 84-94% lie within 1 mm and 91-97% within
2 mm of it, median distance 0.27-0.32 mm (full-resolution sources: median 0.19-0.25 mm; point spacing about
0.37 mm). With the quaternion's matrix transposed (the other convention) the medians are 2.3-2.9 mm and only
13-21% lie within 1 mm.

## Rebuild

    git clone {url}.git
    git -C Project4-Scan-Matching checkout {commit}
    python benchmarks/real_scans/build_object.py --source Project4-Scan-Matching \\
        --out benchmarks/real_scans/data/happy_stand
"""


def read_ascii_ply_vertices(path: str) -> np.ndarray:
    """``(N, 3)`` float32 ``x y z`` of the vertex element of an ASCII PLY whose first element is ``vertex`` with
    exactly the float properties ``x y z`` (the Stanford range images; their ``range_grid`` element is ignored)."""
    with open(path, "rb") as f:
        if f.readline().strip() != b"ply":
            raise ValueError(f"{path}: not a PLY file")
        header = []
        for line in f:
            words = line.decode("ascii").split()
            if words == ["end_header"]:
                break
            header.append(words)
        else:
            raise ValueError(f"{path}: no end_header")
        body = f.read()
    if ["format", "ascii", "1.0"] not in header:
        raise ValueError(f"{path}: expected an ASCII PLY")
    elements = [w for w in header if w[0] == "element"]
    if not elements or elements[0][1] != "vertex":
        raise ValueError(f"{path}: the first element is not 'vertex'")
    start = header.index(elements[0]) + 1
    props = []
    for w in header[start:]:
        if w[0] != "property":
            break
        props.append(w[1:])
    if props != [["float", "x"], ["float", "y"], ["float", "z"]]:
        raise ValueError(f"{path}: vertex properties {props}, expected float x y z")
    count = int(elements[0][2])
    lines = body.split(b"\n", count)[:count]
    values = np.array(b" ".join(lines).split(), dtype=np.float64)
    if values.size != 3 * count:
        raise ValueError(f"{path}: {values.size} vertex values, expected {3 * count}")
    return values.reshape(count, 3).astype(np.float32)


def build(source: str, out: str) -> dict:
    """Writes the set into ``out`` from the work tree ``source``; ``{scan: (source points, kept points)}``."""
    folder = os.path.join(source, SOURCE_DIR)
    poses = common.rpmnet_io("poses").read_poses(os.path.join(folder, CONF))
    names = TUNE + REPORT
    missing = [n for n in names if n not in poses]
    if missing:
        raise ValueError(f"{CONF} has no pose for {missing}")
    scans = [read_ascii_ply_vertices(os.path.join(folder, name + ".ply")) for name in names]
    for name, points in zip(names, scans):
        if not np.all(np.isfinite(points)):
            raise ValueError(f"{name}: non-finite vertices")
    kept = [common.subsample(points, name, MAX_POINTS, SEED) for name, points in zip(names, scans)]
    counts = common.write_scans(out, names, scans, kept)
    meta = {
        **common.source_meta(SET_NAME, "object", SOURCE_URL, SOURCE_COMMIT, SOURCE_DIR, LICENCE),
        "scanner": SCANNER,
        "tune": TUNE,
        "report": REPORT,
        "points_per_scan": MAX_POINTS,
        "seed": SEED,
        "source_points": {n: c[0] for n, c in counts.items()},
    }
    common.write_set_files(out, names, [poses[n] for n in names], meta, SOURCE_MD, max_points=f"{MAX_POINTS:,}")
    return counts


def main(argv=None) -> int:
    return common.main(argv, __doc__, build, set_name=SET_NAME, noun="scans", width=22,
                       source_help="local clone of " + SOURCE_URL + " (at " + SOURCE_COMMIT + ")")


if __name__ == "__main__":
    sys.exit(main())
