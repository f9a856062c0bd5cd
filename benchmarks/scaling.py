"""How the cost of ``register`` grows with the cloud size (B=1, 5 iterations), with a per-stage split.

    python benchmarks/scaling.py [--points 512 1024 2048 4096 8192] [--torch-src PATH/TO/RPMNet/src]

Each size runs in its own process (peak RSS is that size's own). One JSON line per size with the whole
registration and its stages, timed separately:
  - ``grouping``: ball query + PPF of one cloud, O(N^2) compute (distances to every point), memory
    bounded by the query chunk (O(chunk * N));
  - ``features``: the feature PointNet on one cloud, O(N * 64) — linear;
  - ``matching``: feature distances + Sinkhorn (slack) + weighted reference, O(J * K) compute and memory;
  - ``register``: the whole 5-iteration registration (reference grouped/featurised once).
With ``--torch-src`` the official model runs at the same sizes in separate processes as well.
Writes a markdown table and a PNG next to this script (``--out-md``, ``--out-png``).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))


def measure_jax(points: int, repeats: int) -> dict:
    sys.path.insert(0, os.path.dirname(HERE))
    import jax
    import jax.numpy as jnp
    import compare_torch
    from common import environment, time_jitted
    from rpmnet_jax import RPMNetConfig, init_params, registration

    cfg = RPMNetConfig()
    params = init_params(jax.random.PRNGKey(0), cfg)
    src, ref, _ = compare_torch._inputs(points, 1)
    xyz, nrm = jnp.asarray(src[..., :3]), jnp.asarray(src[..., 3:])
    hood = jax.block_until_ready(registration.group(xyz, nrm, cfg))
    feats = jax.block_until_ready(registration.features(params, xyz, hood, cfg))
    one = jnp.ones((1,), jnp.float32)

    def matching(f_src, f_ref, ref_xyz):
        perm = registration.match_matrix(f_src, f_ref, one, 0.5 * one, cfg)
        return registration.soft_procrustes(perm, xyz, ref_xyz)[0]

    stages = {
        "grouping": (jax.jit(lambda x, n: registration.group(x, n, cfg)), (xyz, nrm)),
        "features": (jax.jit(lambda p, x, h: registration.features(p, x, h, cfg)), (params, xyz, hood)),
        "matching": (jax.jit(matching), (feats, feats, xyz)),
        "register": (jax.jit(lambda p, s, r: registration.register(p, s, r, cfg).transform), (params, src, ref)),
    }
    record = {"impl": "jax", "points": points, "batch": 1}
    for name, (fn, args) in stages.items():
        compile_s, run_s = time_jitted(fn, *args, repeats=repeats)
        record[f"{name}_seconds"] = run_s
        if name == "register":
            record["compile_seconds"] = compile_s
    record["seconds"] = record["register_seconds"]
    record.update(environment())
    return record


def measure_torch(points: int, repeats: int, torch_src: str) -> dict:
    import statistics
    import time

    import torch
    import compare_torch
    torch.set_num_threads(len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count())
    net = compare_torch._torch_model(torch_src).eval()
    src, ref, _ = compare_torch._inputs(points, 1)
    data = {"points_src": torch.from_numpy(src), "points_ref": torch.from_numpy(ref)}
    times = []
    with torch.no_grad():
        for _ in range(repeats + 1):
            t0 = time.perf_counter()
            net(data, num_iter=5)
            times.append(time.perf_counter() - t0)
    return {"impl": "torch", "points": points, "batch": 1, "seconds": statistics.median(times[1:])}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--points", type=int, nargs="+", default=[512, 1024, 2048, 4096, 8192])
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--torch-src", default=None, help="also run the official model (its src/ folder)")
    p.add_argument("--out-md", default=os.path.join(HERE, "results_scaling.md"))
    p.add_argument("--out-png", default=os.path.join(HERE, "results_scaling.png"))
    p.add_argument("--worker", choices=("jax", "torch"), help=argparse.SUPPRESS)
    a = p.parse_args(argv)
    sys.path.insert(0, HERE)
    if a.worker:
        import compare_torch  # not benchmarks/common: it would shadow the official ``common`` package
        n = a.points[0]
        record = measure_jax(n, a.repeats) if a.worker == "jax" else measure_torch(n, a.repeats, a.torch_src)
        record["peak_rss_mb"] = round(compare_torch._peak_rss_mb(), 1)
        print(json.dumps(record), flush=True)
        return 0

    impls = ["jax"] + (["torch"] if a.torch_src else [])
    records = []
    for n in a.points:
        for impl in impls:
            cmd = [sys.executable, os.path.abspath(__file__), "--worker", impl, "--points", str(n),
                   "--repeats", str(a.repeats)] + (["--torch-src", a.torch_src] if a.torch_src else [])
            proc = subprocess.run(cmd, capture_output=True, text=True)
            if proc.returncode != 0:
                tail = (proc.stderr.strip().splitlines() or [f"exit {proc.returncode}"])[-1]
                record = {"impl": impl, "points": n, "batch": 1, "error": tail}
            else:
                record = json.loads(proc.stdout.strip().splitlines()[-1])
            records.append(record)
            print(json.dumps(record), flush=True)
    _write_outputs(a, records)
    return 0


def _write_outputs(a, records) -> None:
    lines = ["| points | jax register s | grouping s | features s | matching s | jax peak MB | torch s | torch peak MB |",
             "|---|---|---|---|---|---|---|---|"]
    fmt = lambda r, k, f: (f"{r[k]:{f}}" if r and k in r else "-")
    for n in a.points:
        j = next((r for r in records if r["impl"] == "jax" and r["points"] == n), None)
        t = next((r for r in records if r["impl"] == "torch" and r["points"] == n), None)
        lines.append(f"| {n} | {fmt(j, 'seconds', '.3f')} | {fmt(j, 'grouping_seconds', '.4f')} | "
                     f"{fmt(j, 'features_seconds', '.4f')} | {fmt(j, 'matching_seconds', '.4f')} | "
                     f"{fmt(j, 'peak_rss_mb', '.0f')} | {fmt(t, 'seconds', '.3f')} | {fmt(t, 'peak_rss_mb', '.0f')} |")
    with open(a.out_md, "w") as f:
        f.write("\n".join(lines) + "\n")
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(5, 3.5))
    for impl, key, style in (("jax", "seconds", "-o"), ("jax", "grouping_seconds", ":."), ("jax", "features_seconds", ":."),
                             ("jax", "matching_seconds", ":."), ("torch", "seconds", "-s")):
        pts = [(r["points"], r[key]) for r in records if r["impl"] == impl and key in r]
        if pts:
            label = impl if key == "seconds" else f"{impl} {key.replace('_seconds', '')} (1 call)"
            ax.plot(*zip(*pts), style, label=label)
    ax.set_xscale("log", base=2)
    ax.set_yscale("log")
    ax.set_xlabel("points per cloud (B=1)")
    ax.set_ylabel("seconds")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(a.out_png, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    sys.exit(main())
