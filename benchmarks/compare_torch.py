"""Speed and memory of rpmnet_jax against the official PyTorch RPM-Net, on the same machine, in one run.

    python benchmarks/compare_torch.py --torch-src PATH/TO/RPMNet/src [--malloc default|hugetlb]
        [--points 512 1024 2048] [--batch 1 8] [--repeats 10] [--train-repeats 5] [--tasks infer,train]

PATH is the ``src/`` folder of a checkout of https://github.com/yewzijian/RPMNet (not part of this project);
without ``--torch-src`` only the JAX rows run (with ``init_params`` weights). Steps, each in its own process:

1. preparation (``bench_utils.prepare``): the official model's seeded initial weights and the input pair of
   every size, written to a temporary ``.npz``; measurement processes only ``np.load`` it, so each imports
   its own framework alone (recorded as ``jax_loaded`` / ``torch_loaded`` and asserted);
2. check (``--check-points``, B=2, full-precision matmuls): our ``register`` and the official-structure
   composition below give the same transforms (asserted to 5e-5; ~1e-6 on CPU; a failure is recorded and
   stated under the table), and ours agree with the official transforms on the same input and weights
   (recorded);
3. one process per measurement, pinned to the same ``--threads`` CPUs, same malloc setting (``--malloc``):
   - ``infer``: 5 iterations at every ``--points`` x ``--batch``, all outputs returned (transforms, match
     matrices, ...), for the official model, ours, and ours with the official structure (``structure:
     official``: both clouds grouped and featurised every iteration, 10 ball queries and 10 feature passes
     for 5 iterations against our 2 and 6: the row shows how much of the speed-up is that caching);
   - ``train``: one Adam step, B=8, 717 points, 2 iterations: official, ours fused (the training CLI's
     default) and ours with autodiff through the per-neighbour MLP.
   JAX: compile time apart (``compile_seconds``, ahead-of-time); torch: ``first_call_seconds``. Then the
   median, min and max of ``--repeats`` (inference) / ``--train-repeats`` (training) calls.

Prints one JSON line per measurement (also to ``--out-jsonl``); writes a markdown table and a PNG; exits 1 if
any measurement failed.
``--torch-device cuda`` runs the official model on the GPU (``benchmarks/gpu_run.sh``).
"""

from __future__ import annotations

import argparse
import functools
import os
import sys
import tempfile

import bench_utils

ITERS, TRAIN_ITERS = 5, 2
CHECK_BATCH = 2
STRUCTURE_TOL = 5e-5  # official-structure vs register transforms (float32 rounding of moved points)


def register_official_structure(params, src, ref, cfg, num_iters: int = ITERS):
    """``registration.register`` with the official forward's structure: every iteration re-groups and
    re-featurises the reference and the moved source (points and normals). Same :class:`Registration`."""
    from jax import lax
    from rpmnet_jax import registration
    from rpmnet_jax.ops import se3
    xyz_src, norm_src = src[..., :3], src[..., 3:6]
    xyz_ref, norm_ref = ref[..., :3], ref[..., 3:6]

    def iteration(transform, _):
        # Ties the reference to the iteration: without it XLA hoists its (loop-invariant) ball query and
        # features out of the loop, which is our caching, not the official structure.
        xyz_r, norm_r, transform = lax.optimization_barrier((xyz_ref, norm_ref, lax.stop_gradient(transform)))
        xyz_t, norm_t = se3.apply(transform, xyz_src), se3.rotate(transform, norm_src)
        beta, alpha = registration.annealing(params, xyz_t, xyz_r, cfg)
        feat_src = registration.features(params, xyz_t, registration.group(xyz_t, norm_t, cfg), cfg)
        feat_ref = registration.features(params, xyz_r, registration.group(xyz_r, norm_r, cfg), cfg)
        perm = registration.match_matrix(feat_src, feat_ref, beta, alpha, cfg)
        new_transform, weighted_ref, _ = registration.soft_procrustes(perm, xyz_src, xyz_r)
        return new_transform, registration.Registration(new_transform, perm, weighted_ref, alpha, beta)

    _, out = lax.scan(iteration, se3.identity((src.shape[0],), src.dtype), None, length=num_iters)
    return out


def _torch_loss(transforms, perms, src_xyz, gt, wt_inliers=0.01, discount=0.5):
    """The official training loss (L1 on transformed source + inlier penalty, discounted iterations)."""
    import torch

    def apply(t, x):
        return x @ t[:, :, :3].transpose(1, 2) + t[:, None, :, 3]
    target = apply(gt, src_xyz)
    total = 0.0
    n = len(transforms)
    for i, (t, perm) in enumerate(zip(transforms, perms)):
        mae = torch.mean(torch.abs(apply(t, src_xyz) - target))
        inlier = (torch.mean(1.0 - perm.sum(dim=1)) + torch.mean(1.0 - perm.sum(dim=2))) * wt_inliers
        total = total + discount ** (n - 1 - i) * (mae + inlier)
    return total


def worker_torch(a, prep) -> dict:
    import torch
    torch.set_num_threads(a.threads)
    dev = torch.device(a.torch_device)
    net = bench_utils.official_model(a.torch_src, prep.weights).to(dev)
    src, ref, gt = (torch.from_numpy(x).to(dev) for x in prep.pair(a.points, a.batch))
    data = {"points_src": src, "points_ref": ref}
    sync = (lambda _: torch.cuda.synchronize()) if dev.type == "cuda" else (lambda x: x)
    if a.task == "infer":
        net.eval()

        def run():
            with torch.no_grad():
                return net(data, num_iter=ITERS)  # (transforms, endpoints with the match matrices)
    else:
        net.train()
        opt = torch.optim.Adam(net.parameters(), lr=1e-4)

        def run():
            opt.zero_grad()
            transforms, endpoints = net(data, num_iter=TRAIN_ITERS)
            loss = _torch_loss(transforms, endpoints["perm_matrices"], src[..., :3], gt)
            loss.backward()
            opt.step()
            return loss
    return {"impl": "torch", **bench_utils.timed(run, a.repeats, sync, a.max_seconds)}


def worker_jax(a, prep) -> dict:
    import jax
    from rpmnet_jax import config, registration
    from rpmnet_jax import train as training
    params = jax.device_put(prep.jax_params())
    src, ref, gt = jax.device_put(prep.pair(a.points, a.batch))
    if a.task == "infer":
        fn = register_official_structure if a.structure == "official" else registration.register
        jitted = jax.jit(functools.partial(fn, cfg=config.RPMNetConfig(), num_iters=ITERS))  # every output
        timing = bench_utils.time_jax(jitted, params, src, ref, repeats=a.repeats, max_seconds=a.max_seconds)
        return {"impl": "jax", "structure": a.structure, **timing}
    model = config.RPMNetConfig(fused_prepool=a.variant == "fused", num_train_reg_iters=TRAIN_ITERS)
    cfg = training.TrainConfig(model=model)
    step = training.make_train_step(cfg)
    holder = [training.create_train_state(jax.random.PRNGKey(0), cfg, params=params)]
    batch = {"points_src": src, "points_ref": ref, "transform_gt": gt}
    compiled, compile_s = bench_utils.compile_jax(step, holder[0], batch)

    def run():
        holder[0], scalars = compiled(holder[0], batch)  # the state is donated
        return scalars["loss"]
    timing = bench_utils.timed(run, a.repeats, jax.block_until_ready, a.max_seconds)
    return {"impl": "jax", "variant": a.variant, **timing, "compile_seconds": compile_s}


def worker_check(a, prep) -> dict:
    """Max |difference| of transforms: official structure vs ``register`` (asserted), ours vs the official.
    Float32 matmuls at full precision (a GPU's default TF32 would blur the comparison; the CPU's is full)."""
    import jax
    import numpy as np
    from rpmnet_jax import config, registration
    params, cfg = prep.jax_params(), config.RPMNetConfig()
    src, ref = prep.check["src"], prep.check["ref"]
    with jax.default_matmul_precision("highest"):
        ours = np.asarray(jax.jit(functools.partial(registration.register, cfg=cfg, num_iters=ITERS))(
            params, src, ref).transforms)
        structure = np.asarray(jax.jit(functools.partial(register_official_structure, cfg=cfg))(
            params, src, ref).transforms)
    record = {"impl": "jax", "task": "check", "points": src.shape[1], "batch": src.shape[0],
              "check_matmul_precision": "highest",
              "max_abs_diff_official_structure": float(np.abs(structure - ours).max())}
    if "transforms" in prep.check:
        official = prep.check["transforms"]
        record.update(max_abs_diff_official=float(np.abs(official - ours).max()),
                      max_abs_diff_official_last=float(np.abs(official[-1] - ours[-1]).max()))
    assert record["max_abs_diff_official_structure"] <= STRUCTURE_TOL, record
    return record


def measure(a) -> dict:
    """One measurement in this process, as its record; ``a``: the parsed worker flags (see :func:`worker_flags`)."""
    a = argparse.Namespace(**dict(vars(a), points=a.points[0], batch=a.batch[0]))  # one size
    prep = bench_utils.Prepared(a.prepared)
    record = {"check": worker_check, "jax": worker_jax, "torch": worker_torch}[a.worker](a, prep)
    record = {"task": a.task, "points": a.points, "batch": a.batch, **record}
    if record["task"] == "infer":
        record.update(iters=ITERS, seconds_per_pair=record["seconds"] / record["batch"],
                      pairs_per_second=record["batch"] / record["seconds"])
    elif record["task"] == "train":
        record["iters"] = TRAIN_ITERS
    return dict(record, threads=a.threads, peak_rss_mb=bench_utils.peak_rss_mb(),
                device_peak_mb=bench_utils.device_peak_mb(), **bench_utils.environment(),
                **bench_utils.frameworks_loaded("jax" if a.worker == "check" else a.worker))


def worker_flags(impl: str, prepared: str, task: str, points: int, batch: int, threads: int, repeats: int,
                 torch_src: str | None = None, torch_device: str = "cpu", max_seconds: float | None = None,
                 extra=()) -> list[str]:
    """The command-line flags of one measurement (parsed with :func:`parser`, measured by :func:`measure`)."""
    flags = ["--worker", impl, "--prepared", prepared, "--task", task, "--points", points, "--batch", batch,
             "--threads", threads, "--repeats", repeats, "--torch-device", torch_device, *extra]
    flags += ["--torch-src", torch_src] if torch_src else []
    flags += ["--max-seconds", max_seconds] if max_seconds else []
    return [str(f) for f in flags]


def _jobs(a) -> list[tuple]:
    """``(impl, task, points, batch, extra worker flags)`` of every measurement, in order."""
    impls = ("torch", "jax") if a.torch_src else ("jax",)
    jobs = []
    if "infer" in a.tasks:
        for n in a.points:
            for b in a.batch:
                jobs += [(impl, "infer", n, b, ()) for impl in impls]
                jobs.append(("jax", "infer", n, b, ("--structure", "official")))
    if "train" in a.tasks:
        size = (a.train_points, a.train_batch)
        jobs += [(impl, "train", *size, ()) for impl in impls]
        jobs.append(("jax", "train", *size, ("--variant", "autodiff")))
    return jobs


def _span(r: dict, per: int, digits: int) -> str:
    """``median (min–max)`` of a record's call seconds divided by ``per``."""
    return (f"{r['seconds'] / per:.{digits}f} ({r['min_seconds'] / per:.{digits}f}–"
            f"{r['max_seconds'] / per:.{digits}f})")


def write_table(path: str, records: list, meta: dict) -> None:
    """Markdown table: per (task, points, batch) the official model next to each JAX variant."""
    ok = [r for r in records if "seconds" in r]
    torch_rows = {(r["task"], r["points"], r["batch"]): r for r in ok if r["impl"] == "torch"}
    structure = {(r["points"], r["batch"]): r for r in ok if r.get("structure") == "official"}
    check = next((r for r in records if r.get("task") == "check"), {})
    digits = 4 if meta.get("device", "cpu").startswith(("gpu", "cuda")) else 3
    lines = [f"{meta['date']}; {meta['cpu']} ({meta['cpus']} CPUs), {meta['threads']} threads per framework; "
             f"malloc {meta['malloc']}; jax {meta.get('jax')} on {meta.get('device')}, torch {meta.get('torch')} on "
             f"{meta.get('torch_device')}.",
             f"`{meta['command']}`", "",
             "Medians (min–max) of the repeats; inference per pair (5 iterations, every output returned), training "
             "per step (Adam, 2 iterations). JAX compile time and the official model's first call are apart.", "",
             "| task | points | batch | official s | official first call s | official peak MB | rpmnet_jax s | "
             "jax compile s | jax peak MB | pairs/s official / jax | speed-up | from caching |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for j in ok:
        if j["impl"] != "jax":
            continue
        per = j["batch"] if j["task"] == "infer" else 1
        t = torch_rows.get((j["task"], j["points"], j["batch"]))
        task = j["task"] + {"official": ", official structure", "ours": ""}.get(j.get("structure"), "") + (
            f" ({j['variant']})" if j.get("variant") else "")
        torch_cols = (f"{_span(t, per, digits)} | {t['first_call_seconds']:.2f} | {t['peak_rss_mb']:.0f}" if t
                      else "- | - | -")
        rate = lambda r: f"{r['batch'] / r['seconds']:.{digits - 1}f}" if r else "-"
        pairs = f"{rate(t)} / {rate(j)}" if j["task"] == "infer" else "-"
        speed = f"{t['seconds'] / j['seconds']:.2f}×" if t else "-"
        s = structure.get((j["points"], j["batch"])) if j.get("structure") == "ours" else None
        caching = f"{s['seconds'] / j['seconds']:.2f}×" if s else "-"
        lines.append(f"| {task} | {j['points']} | {j['batch']} | {torch_cols} | {_span(j, per, digits)} | "
                     f"{j['compile_seconds']:.1f} | {j['peak_rss_mb']:.0f} | {pairs} | {speed} | {caching} |")
    lines += ["", "Official structure: the same network composed as the official forward (both clouds grouped "
              "and featurised every iteration: 10 ball queries and 10 feature passes for 5 iterations, against "
              "2 and 6 here). *From caching* = official-structure time / ours: the part of the speed-up that is "
              "that caching; the rest (speed-up / caching) is the implementation."]
    if "max_abs_diff_official_structure" in check:
        lines.append(f"Check ({check['points']} points, B={check['batch']}): official structure vs ours "
                     f"{check['max_abs_diff_official_structure']:.1e}" + (
                         f"; official vs ours {check['max_abs_diff_official']:.1e}"
                         if "max_abs_diff_official" in check else "") + " (max |Δ| of the transforms).")
    if "error" in check:
        lines.append("The check FAILED: the official-structure rows are not shown to compute what ours does.")
    lines += [f"Failed: {r['impl']} {r['task']} {r['points']}x{r['batch']}: {r['error']}" for r in records
              if "error" in r]
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n")


def write_plot(path: str, records: list) -> None:
    """Seconds per pair against points, one line per implementation and batch size."""
    series = (("torch", None, "tab:red", "official"), ("jax", "ours", "tab:blue", "rpmnet_jax"),
              ("jax", "official", "tab:green", "rpmnet_jax, official structure"))
    infer = [r for r in records if r.get("task") == "infer" and "seconds" in r]
    lines = []
    for impl, structure, colour, label in series:
        for batch, style in zip(sorted({r["batch"] for r in infer}), ("-o", "--s", ":^", "-.v")):
            pts = sorted((r["points"], r["seconds"] / r["batch"]) for r in infer
                         if r["impl"] == impl and r["batch"] == batch and r.get("structure") == structure)
            lines.append((pts, style, f"{label} B={batch}", colour))
    bench_utils.plot(path, lines, "points per cloud", "seconds per pair (5 iterations)")


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--torch-src", help="src/ folder of the official RPM-Net checkout (without it: JAX rows only)")
    p.add_argument("--torch-device", default="cpu", help="torch device of the official model (cpu, cuda)")
    p.add_argument("--points", type=int, nargs="+", default=[512, 1024, 2048])
    p.add_argument("--batch", type=int, nargs="+", default=[1, 8])
    p.add_argument("--train-points", type=int, default=717)
    p.add_argument("--train-batch", type=int, default=8)
    p.add_argument("--check-points", type=int, default=1024, help="points of the transform check (batch 2)")
    p.add_argument("--tasks", default="infer,train", help="comma-separated subset of infer,train")
    p.add_argument("--threads", type=int, default=bench_utils.available_cpus(),
                   help="CPUs and threads given to each framework (default: all)")
    p.add_argument("--malloc", choices=("default", "hugetlb"), default="default",
                   help="glibc malloc setting for both frameworks: default, or the training CLI's huge pages")
    p.add_argument("--repeats", type=int, default=10, help="timed repeats per inference measurement")
    p.add_argument("--train-repeats", type=int, default=5, help="timed repeats per training measurement")
    p.add_argument("--max-seconds", type=float, help="stop repeating a measurement after this long (>= 3 repeats)")
    p.add_argument("--out-md", default=os.path.join(bench_utils.HERE, "results_compare_torch.md"))
    p.add_argument("--out-png", default=os.path.join(bench_utils.HERE, "results_compare_torch.png"))
    p.add_argument("--out-jsonl", default=os.path.join(bench_utils.HERE, "results_compare_torch.jsonl"))
    p.add_argument("--worker", choices=("jax", "torch", "check"), help=argparse.SUPPRESS)
    p.add_argument("--prepared", help=argparse.SUPPRESS)
    p.add_argument("--task", choices=("infer", "train", "check"), default="infer", help=argparse.SUPPRESS)
    p.add_argument("--structure", choices=("ours", "official"), default="ours", help=argparse.SUPPRESS)
    p.add_argument("--variant", choices=("fused", "autodiff"), default="fused", help=argparse.SUPPRESS)
    return p


def main(argv=None) -> int:
    p = parser()
    a = p.parse_args(argv)
    if a.torch_src and not os.path.isfile(os.path.join(a.torch_src, "models", "rpmnet.py")):
        p.error(f"--torch-src {a.torch_src!r} is not the official RPM-Net src/ folder (no models/rpmnet.py)")
    if a.worker:
        bench_utils.pin(a.threads)
        bench_utils.emit(measure(a))
        return 0

    a.tasks = [t for t in a.tasks.split(",") if t]
    env = bench_utils.malloc_env(a.malloc)
    meta = dict(bench_utils.session("compare_torch.py", argv, a.threads, a.malloc),
                torch_device=a.torch_device if a.torch_src else None)
    open(a.out_jsonl, "w").close()
    with tempfile.TemporaryDirectory(prefix="rpmnet_bench_") as tmp:
        prepared = os.path.join(tmp, "prepared.npz")
        sizes = [(n, b) for n in a.points for b in a.batch] if "infer" in a.tasks else []
        sizes += [(a.train_points, a.train_batch)] if "train" in a.tasks else []
        bench_utils.run_prepare(prepared, sizes, a.torch_src, check=(a.check_points, CHECK_BATCH))
        records = []
        for impl, task, n, b, extra in [("check", "check", a.check_points, CHECK_BATCH, ())] + _jobs(a):
            flags = worker_flags(impl, prepared, task, n, b, a.threads, a.train_repeats if task == "train" else
                                 a.repeats, a.torch_src, a.torch_device, a.max_seconds, extra)
            record = bench_utils.run_worker([sys.executable, os.path.abspath(__file__), *flags], env, {
                "impl": impl, "task": task, "points": n, "batch": b, "malloc": a.malloc}, a.out_jsonl)
            records.append(record)
            meta = {**{k: record[k] for k in ("jax", "torch") if k in record}, **meta}  # versions: first seen
            if impl == "jax":
                meta.setdefault("device", record.get("device"))
    write_table(a.out_md, records, meta)
    write_plot(a.out_png, records)
    print(f"table {a.out_md}, plot {a.out_png}, records {a.out_jsonl}", file=sys.stderr)
    return 1 if any("error" in r for r in records) else 0


if __name__ == "__main__":
    sys.exit(main())
