"""The validation curve of one or more training runs (TensorBoard logs of ``--workdir``s): JSON and a PNG.

    python -m experiments.validation_curve --workdirs runs/v1,runs/v2 --out docs/validation_curve.png

Runs are chained in the given order (a run started with ``--init-from`` the previous one's weights continues
its step count).
"""

from __future__ import annotations

import argparse
import glob
import json
import os
import struct
import sys


def read_scalars(workdir: str, tag: str) -> list[tuple[int, float]]:
    """``[(step, value)]`` of a scalar in the TensorBoard event files of ``workdir/tb``."""
    from tensorboardX.proto import event_pb2

    out = []
    for path in sorted(glob.glob(os.path.join(workdir, "tb", "events.*"))):
        with open(path, "rb") as f:
            data = f.read()
        i = 0
        while i + 12 <= len(data):
            (n,) = struct.unpack("Q", data[i:i + 8])
            event = event_pb2.Event()
            event.ParseFromString(data[i + 12:i + 12 + n])
            i += 12 + n + 4
            out += [(int(event.step), float(v.simple_value)) for v in event.summary.value if v.tag == tag]
    return sorted(dict(out).items())


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--workdirs", required=True, help="comma-separated training workdirs, oldest first")
    p.add_argument("--offsets", default=None, help="comma-separated step offsets of the runs (default 0 each)")
    p.add_argument("--tag", default="val/err_r_deg_mean")
    p.add_argument("--out", required=True, help="PNG path; the points go to the same name with .json")
    a = p.parse_args(argv)
    dirs = [d for d in a.workdirs.split(",") if d]
    offsets = [int(x) for x in a.offsets.split(",")] if a.offsets else [0] * len(dirs)
    points, marks = [], {}
    for d, off in zip(dirs, offsets):
        rows = read_scalars(d, a.tag)
        if not rows:
            print(f"error: no {a.tag!r} in {d}/tb", file=sys.stderr)
            return 2
        marks[os.path.basename(os.path.normpath(d))] = off + rows[0][0]
        points += [(off + s, v) for s, v in rows]
    from rpmnet_jax.cli import plots
    plots.plot_validation_curve(a.out, [s for s, _ in points], [v for _, v in points], marks=marks)
    with open(os.path.splitext(a.out)[0] + ".json", "w") as f:
        json.dump({"tag": a.tag, "points": points}, f, indent=1)
    print(json.dumps(points))
    return 0


if __name__ == "__main__":
    sys.exit(main())
