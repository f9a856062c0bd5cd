"""Seconds to read point-cloud files: ``rpmnet_jax.io.clouds.read_cloud`` beside Open3D's ``read_point_cloud``
(when installed) and ``plyfile`` (the previous reader), same files, same process, one after the other.

    python benchmarks/read_time.py FILE [FILE ...] [--repeats 5]

Prints one JSON line per file: the median seconds of each reader (the first call apart), the points read, whether
ours and plyfile's coordinates are identical, the environment.
"""

from __future__ import annotations

import argparse
import os

import bench_utils


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("files", nargs="+")
    p.add_argument("--repeats", type=int, default=5)
    a = p.parse_args()
    import numpy as np

    from rpmnet_jax.io import clouds

    readers = {"rpmnet_jax": lambda f: clouds.read_cloud(f)[0]}
    try:
        import open3d as o3d

        readers["open3d"] = lambda f: np.asarray(o3d.io.read_point_cloud(f).points)
    except ImportError:
        pass
    for f in a.files:
        record = {"task": "read_cloud", "file": os.path.basename(f), "bytes": os.path.getsize(f)}
        if f.lower().endswith(".ply"):
            from plyfile import PlyData

            readers["plyfile"] = lambda f: np.stack([PlyData.read(f)["vertex"].data[c] for c in "xyz"], 1)
        else:
            readers.pop("plyfile", None)
        for name, read in readers.items():
            record[name] = bench_utils.timed(lambda: read(f), a.repeats)["seconds"]
        ours = readers["rpmnet_jax"](f)
        record["points"] = len(ours)
        if "plyfile" in readers:
            record["identical_to_plyfile"] = bool(np.array_equal(ours, readers["plyfile"](f).astype(np.float64)))
        bench_utils.emit({**record, **bench_utils.environment()})


if __name__ == "__main__":
    main()
