"""How :func:`rpmnet_jax.align_scans` grows with the number of scans: time, pairs registered and peak memory.

    python benchmarks/scan_scaling.py [--sizes 10,30,60,120,240] [--image-size 160] [--noise 0.0005]
        [--mesh ../shared/data/stanford_bunny/bun_zipper_res2.ply] [--plot docs/scan_scaling.png]
        [--out-jsonl results.jsonl] [--keep DIR]

For each size a set of simulated range scans of ``--mesh`` is made (:mod:`rpmnet_jax.simulation.range_scans`, files
in a seeded shuffled order, into a temporary folder or ``--keep DIR/scansN``) and registered by
``benchmarks/campaign_time.py``'s own side in a fresh process (reading included), then scored against the true
poses. One JSON line per size (seconds, process seconds, peak resident memory, pairs registered, scans within
0.5° and 1 mm), then one with the log-log slopes of time and pairs against scans (1: linear, 2: all pairs).
``pairs registered`` counts the pair registrations of every stage (``ScanAlignment.pairs``; a pair
registered in two stages counts twice); the global placements onto the merged scans are not pairs and are not
counted. ``--plot``: time, pairs and peak memory against the number of scans, log-log, beside linear and
quadratic references.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile

import bench_utils
import campaign_time

MESH = os.path.join(bench_utils.REPO, "..", "shared", "data", "stanford_bunny", "bun_zipper_res2.ply")


def make_set(folder: str, vertices, faces, scans: int, a) -> None:
    """Simulates ``scans`` scans of the mesh and writes them, shuffled, with ``truth.conf`` to ``folder``."""
    from rpmnet_jax.simulation import range_scans

    made = range_scans.simulate(vertices, faces, scans, image_size=a.image_size, noise=a.noise, seed=a.seed)
    range_scans.write_set(folder, made, shuffle_seed=a.seed, settings={
        "mesh": os.path.basename(a.mesh), "scans": scans, "image_size": a.image_size, "noise": a.noise,
        "seed": a.seed, "shuffle": True})


def plot(path: str, rows) -> None:
    """Time, pairs and peak memory against scans, log-log, each beside lines of slope 1 and 2 through its first
    point."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from matplotlib import ticker

    n = [r["scans"] for r in rows]
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.6))
    for ax, key, label in zip(axes, ("seconds", "pairs_registered", "peak_rss_mb"),
                              ("seconds (reading + align_scans)", "pairs registered", "peak resident memory, MB")):
        y = [r[key] for r in rows]
        ax.plot(n, y, "o-", color="C0", label="align_scans")
        ax.plot(n, [y[0] * k / n[0] for k in n], "--", color="grey", label="linear")
        ax.plot(n, [y[0] * (k / n[0]) ** 2 for k in n], ":", color="grey", label="quadratic")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xticks(n, [str(k) for k in n])
        ax.yaxis.set_major_locator(ticker.LogLocator(subs=(1.0, 2.0, 5.0)))
        ax.yaxis.set_major_formatter(ticker.ScalarFormatter())
        ax.yaxis.set_minor_formatter(ticker.NullFormatter())
        ax.set_xlabel("scans")
        ax.set_ylabel(label)
        ax.legend(fontsize=7)
    fig.suptitle(f"align_scans against the number of scans ({rows[0]['image_size']}² pixels a scan, "
                 f"{rows[0]['cpus']} CPUs)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--sizes", default="10,30,60,120,240", help="numbers of scans, comma-separated")
    p.add_argument("--mesh", default=MESH, help="triangle mesh (PLY; default the Stanford bunny, metres)")
    p.add_argument("--image-size", type=int, default=160, help="pixels per image side (default 160)")
    p.add_argument("--noise", type=float, default=0.0005, help="depth noise std, mesh units (default 0.5 mm)")
    p.add_argument("--units", choices=("m", "mm"), default="m", help="the mesh's units (errors are stated in mm)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--plot", default=None, help="PNG of time and pairs against scans")
    p.add_argument("--out-jsonl", default=None, help="append the JSON lines to this file")
    p.add_argument("--keep", default=None, help="write the sets to DIR/scansN and keep them")
    a = p.parse_args(argv)
    from rpmnet_jax.io import clouds as cloud_io, ply

    sizes = sorted({int(s) for s in a.sizes.split(",") if s})
    vertices, faces = ply.read_mesh(a.mesh)
    work = a.keep or tempfile.mkdtemp(prefix="scan_scaling_")
    session = bench_utils.session("scan_scaling.py", argv, bench_utils.available_cpus(), "default")
    rows = []
    try:
        for n in sizes:
            folder = os.path.join(work, f"scans{n}")
            make_set(folder, vertices, faces, n, a)
            names, paths, truth = campaign_time.scan_files(folder, "truth.conf")
            out = campaign_time.child_run(campaign_time.__file__, [folder, "--seed", str(a.seed)], "ours")
            record = {"task": "scan_scaling", "mesh": os.path.basename(a.mesh), "scans": n,
                      "image_size": a.image_size, "noise": a.noise, "commit": campaign_time.commit(), **session, **out}
            if "error" not in out:
                clouds = [cloud_io.read_cloud(path)[0] for path in paths]
                scored = campaign_time.score(record.pop("poses"), truth, clouds, 1000.0 if a.units == "m" else 1.0)
                record.update({k: v for k, v in scored.items() if k not in ("rotation_deg", "rms")})
                rows.append(record)
            bench_utils.emit(record, a.out_jsonl)
            if not a.keep:
                shutil.rmtree(folder)
    finally:
        if not a.keep:
            shutil.rmtree(work, ignore_errors=True)
    if len(rows) >= 2:
        n = [r["scans"] for r in rows]
        bench_utils.emit({"task": "scan_scaling_slopes", "sizes": n,
                          "seconds_slope": bench_utils.slope(n, [r["seconds"] for r in rows]),
                          "pairs_slope": bench_utils.slope(n, [r["pairs_registered"] for r in rows]),
                          "peak_rss_slope": bench_utils.slope(n, [r["peak_rss_mb"] for r in rows])}, a.out_jsonl)
    if a.plot and rows:
        plot(a.plot, rows)
    return 0 if len(rows) == len(sizes) else 1


if __name__ == "__main__":
    sys.exit(main())
