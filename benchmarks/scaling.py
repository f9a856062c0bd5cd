"""How the cost of ``register`` grows with the cloud size (B=1, 5 iterations), with a per-stage split.

    python benchmarks/scaling.py [--torch-src PATH/TO/RPMNet/src] [--points 512 1024 2048 4096 8192]
        [--repeats 5] [--threads N] [--malloc default|hugetlb]

Inputs and the official model's seeded weights are prepared once in a process of their own (as in
``compare_torch.py``); each size and framework is then measured in its own process (peak RSS is that size's
own), pinned to the same ``--threads`` CPUs, with the same malloc setting. JAX, one JSON line per size:
  - ``register`` (``seconds``, min/max, ``compile_seconds`` apart): the whole 5-iteration registration with
    every output returned (the ``Registration``: transforms, match matrices, weighted references, alpha,
    beta; the official model returns its match matrices too), reference grouped/featurised once.
    ``peak_rss_mb`` is read right after it, before the stage functions below compile: like for like with the
    official model's;
  - ``grouping``: ball query + PPF of one cloud, O(N^2) compute (distances to every point), memory bounded by
    the query chunk (O(chunk * N));
  - ``features``: the feature PointNet on one cloud, O(N * 64), linear;
  - ``matching``: feature distances + Sinkhorn (slack) + weighted Procrustes, O(J * K) compute and memory.
With ``--torch-src`` the official model (every output returned; ``first_call_seconds`` apart) runs at the same
sizes. Writes a markdown table and a PNG next to this script (``--out-md``, ``--out-png``).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile

import bench_utils
import compare_torch


def measure_stages(prepared: str, points: int, repeats: int) -> dict:
    """Median seconds of one call of each stage on the size's source cloud (this process has imported jax)."""
    import jax
    import jax.numpy as jnp
    from rpmnet_jax import config, registration
    cfg = config.RPMNetConfig()
    prep = bench_utils.Prepared(prepared)
    params = jax.device_put(prep.jax_params())
    src, _, _ = prep.pair(points, 1)
    xyz, nrm = jnp.asarray(src[..., :3]), jnp.asarray(src[..., 3:])
    group = jax.jit(lambda x, n: registration.group(x, n, cfg))
    features = jax.jit(lambda p, x, h: registration.features(p, x, h, cfg))
    hood = jax.block_until_ready(group(xyz, nrm))
    feats = jax.block_until_ready(features(params, xyz, hood))
    one = jnp.ones((1,), jnp.float32)

    def matching(f_src, f_ref, ref_xyz):
        perm = registration.match_matrix(f_src, f_ref, one, 0.5 * one, cfg)
        return registration.soft_procrustes(perm, xyz, ref_xyz)[0]

    stages = {"grouping": (group, (xyz, nrm)), "features": (features, (params, xyz, hood)),
              "matching": (jax.jit(matching), (feats, feats, xyz))}
    return {f"{name}_seconds": bench_utils.time_jax(fn, *args, repeats=repeats)["seconds"]
            for name, (fn, args) in stages.items()}


def write_table(path: str, records: list, meta: dict) -> None:
    fmt = lambda r, k, f: (f"{r[k]:{f}}" if r and r.get(k) is not None else "-")
    span = lambda r: (f"{r['seconds']:.3f} ({r['min_seconds']:.3f}–{r['max_seconds']:.3f})"
                      if r and "seconds" in r else "-")
    lines = [f"{meta['date']}; {meta['cpu']} ({meta['cpus']} CPUs), {meta['threads']} threads per framework; malloc "
             f"{meta['malloc']}; jax {meta.get('jax')}, torch {meta.get('torch')}.", f"`{meta['command']}`", "",
             "B=1, 5 iterations, every output returned; medians (min–max). Stage columns: one call each, timed "
             "apart; jax peak MB is read after `register`, before the stages compile.", "",
             "| points | jax register s | jax compile s | grouping s | features s | matching s | jax peak MB | "
             "official s | official first call s | official peak MB | speed-up |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for n in meta["points"]:
        j = next((r for r in records if r["impl"] == "jax" and r["points"] == n and "seconds" in r), None)
        t = next((r for r in records if r["impl"] == "torch" and r["points"] == n and "seconds" in r), None)
        speed = f"{t['seconds'] / j['seconds']:.2f}×" if j and t else "-"
        lines.append(f"| {n} | {span(j)} | {fmt(j, 'compile_seconds', '.1f')} | {fmt(j, 'grouping_seconds', '.4f')} | "
                     f"{fmt(j, 'features_seconds', '.4f')} | {fmt(j, 'matching_seconds', '.4f')} | "
                     f"{fmt(j, 'peak_rss_mb', '.0f')} | {span(t)} | {fmt(t, 'first_call_seconds', '.2f')} | "
                     f"{fmt(t, 'peak_rss_mb', '.0f')} | {speed} |")
    lines += [f"Failed: {r['impl']} {r['points']}: {r['error']}" for r in records if "error" in r]
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n")


def write_plot(path: str, records: list) -> None:
    lines = []
    for impl, key, style in (("jax", "seconds", "-o"), ("jax", "grouping_seconds", ":."),
                             ("jax", "features_seconds", ":."), ("jax", "matching_seconds", ":."),
                             ("torch", "seconds", "-s")):
        name = {"jax": "rpmnet_jax", "torch": "official"}[impl]
        label = name if key == "seconds" else f"{name} {key.replace('_seconds', '')} (1 call)"
        lines.append(([(r["points"], r[key]) for r in records if r["impl"] == impl and key in r], style, label, None))
    bench_utils.plot(path, lines, "points per cloud (B=1)", "seconds")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--points", type=int, nargs="+", default=[512, 1024, 2048, 4096, 8192])
    p.add_argument("--repeats", type=int, default=5, help="timed repeats per measurement")
    p.add_argument("--max-seconds", type=float, help="stop repeating a measurement after this long (>= 3 repeats)")
    p.add_argument("--torch-src", default=None, help="also run the official model (its src/ folder)")
    p.add_argument("--threads", type=int, default=bench_utils.available_cpus(),
                   help="CPUs and threads given to each framework (default: all)")
    p.add_argument("--malloc", choices=("default", "hugetlb"), default="default",
                   help="glibc malloc setting for both frameworks: default, or the training CLI's huge pages")
    p.add_argument("--out-md", default=os.path.join(bench_utils.HERE, "results_scaling.md"))
    p.add_argument("--out-png", default=os.path.join(bench_utils.HERE, "results_scaling.png"))
    p.add_argument("--out-jsonl", default=os.path.join(bench_utils.HERE, "results_scaling.jsonl"))
    p.add_argument("--worker", choices=("jax", "torch"), help=argparse.SUPPRESS)
    p.add_argument("--prepared", help=argparse.SUPPRESS)
    a = p.parse_args(argv)

    def flags(impl: str, prepared: str, points: int) -> list[str]:
        return compare_torch.worker_flags(impl, prepared, "infer", points, 1, a.threads, a.repeats, a.torch_src,
                                          max_seconds=a.max_seconds)

    if a.worker:
        bench_utils.pin(a.threads)
        n = a.points[0]
        record = compare_torch.measure(compare_torch.parser().parse_args(flags(a.worker, a.prepared, n)))
        if a.worker == "jax":
            record.update(measure_stages(a.prepared, n, a.repeats))
        bench_utils.emit(record)
        return 0

    meta = dict(bench_utils.session("scaling.py", argv, a.threads, a.malloc), points=a.points)
    env = bench_utils.malloc_env(a.malloc)
    impls = ["jax"] + (["torch"] if a.torch_src else [])
    open(a.out_jsonl, "w").close()
    records = []
    with tempfile.TemporaryDirectory(prefix="rpmnet_bench_") as tmp:
        prepared = os.path.join(tmp, "prepared.npz")
        bench_utils.run_prepare(prepared, [(n, 1) for n in a.points], a.torch_src)
        for n in a.points:
            for impl in impls:
                cmd = [sys.executable, os.path.abspath(__file__), "--worker", impl, "--prepared", prepared,
                       "--points", n, "--repeats", a.repeats, "--threads", a.threads]
                cmd += (["--torch-src", a.torch_src] if a.torch_src else []) + (
                    ["--max-seconds", a.max_seconds] if a.max_seconds else [])
                record = bench_utils.run_worker(cmd, env, {"impl": impl, "points": n, "batch": 1, "malloc": a.malloc},
                                                a.out_jsonl)
                records.append(record)
                meta = {**{k: record[k] for k in ("jax", "torch") if k in record}, **meta}
    write_table(a.out_md, records, meta)
    write_plot(a.out_png, records)
    print(f"table {a.out_md}, plot {a.out_png}, records {a.out_jsonl}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
