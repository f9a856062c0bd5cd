"""Speed and memory of rpmnet_jax against the official PyTorch RPM-Net, on the same machine, in one run.

    python benchmarks/compare_torch.py --torch-src PATH/TO/RPMNet/src [--points 512 1024 2048] [--batch 1 8]

PATH is the ``src/`` folder of a checkout of https://github.com/yewzijian/RPMNet (not part of this
project). The script builds the official model, copies its weights into ours with
``convert.params_from_torch``, checks that both give the same transforms on the same input, then times
inference (5 iterations, per pair) and one training step (batch 8, 717 points, 2 iterations, Adam) of
each. Every measurement runs in its own process (so peak RSS is its own), pinned to the same CPUs
with the same thread count. Prints one JSON line per measurement; writes a markdown table and a PNG.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
TRAIN_POINTS, TRAIN_BATCH = 717, 8


def _pin(threads: int) -> None:
    """Restricts this process to ``threads`` CPUs (before JAX/torch start their thread pools)."""
    if hasattr(os, "sched_setaffinity"):
        cpus = sorted(os.sched_getaffinity(0))[:threads]
        os.sched_setaffinity(0, cpus)


def _inputs(points: int, batch: int, seed: int = 0):
    """A realistic pair: synthetic shapes (unit sphere) and a random rigid motion of the source."""
    import numpy as np
    sys.path.insert(0, os.path.dirname(HERE))
    from rpmnet_jax.data import synthetic
    rng = np.random.default_rng(seed)
    src, ref, gt = [], [], []
    for b in range(batch):
        shape = synthetic.sample_shape(rng, b % 40, 2 * points)
        rot = synthetic.random_rotation(rng)
        trans = rng.uniform(-0.5, 0.5, 3)
        src.append(shape[:points])
        moved = shape[points:]
        ref.append(np.concatenate([moved[:, :3] @ rot.T + trans, moved[:, 3:] @ rot.T], 1))
        gt.append(np.concatenate([rot, trans[:, None]], 1))
    f32 = lambda x: np.stack(x).astype(np.float32)
    return f32(src), f32(ref), f32(gt)


def _torch_model(torch_src: str):
    # The official ``common`` is a namespace package: drop this folder (it has a ``common.py``) from the path.
    sys.path[:] = [p for p in sys.path if os.path.abspath(p or ".") != HERE]
    sys.path.insert(0, os.path.abspath(torch_src))
    import torch
    from models.rpmnet import get_model  # the official code
    args = argparse.Namespace(no_slack=False, num_sk_iter=5, features=["ppf", "dxyz", "xyz"], feat_dim=96,
                              radius=0.3, num_neighbors=64)
    torch.manual_seed(0)
    return get_model(args)


def _torch_loss(torch, transforms, perms, src_xyz, gt, wt_inliers=0.01, discount=0.5):
    """The official training loss (L1 on transformed source + inlier penalty, discounted iterations)."""
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


def _peak_rss_mb() -> float:
    import resource
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def _median_time(fn, repeats: int, sync=lambda x: x):
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        sync(fn())
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def worker_torch(a) -> dict:
    import torch
    torch.set_num_threads(a.threads)
    net = _torch_model(a.torch_src)
    src, ref, gt = _inputs(a.points, a.batch)
    data = {"points_src": torch.from_numpy(src), "points_ref": torch.from_numpy(ref)}
    record = {"impl": "torch", "torch": torch.__version__, "device": "cpu"}
    if a.task == "infer":
        net.eval()

        def run():
            with torch.no_grad():
                return net(data, num_iter=5)[0][-1]
        t0 = time.perf_counter()
        run()
        first = time.perf_counter() - t0
        seconds = _median_time(run, a.repeats) / a.batch
        record.update(first_call_seconds=first)
    else:
        net.train()
        opt = torch.optim.Adam(net.parameters(), lr=1e-4)
        gt_t = torch.from_numpy(gt)

        def step():
            opt.zero_grad()
            transforms, endpoints = net(data, num_iter=2)
            loss = _torch_loss(torch, transforms, endpoints["perm_matrices"], data["points_src"][..., :3], gt_t)
            loss.backward()
            opt.step()
            return loss
        step()
        seconds = _median_time(step, a.repeats)
    record.update(seconds=seconds)
    return record


def worker_jax(a) -> dict:
    import jax
    import numpy as np
    sys.path.insert(0, os.path.dirname(HERE))
    from rpmnet_jax import config, registration
    from rpmnet_jax import train as training
    from rpmnet_jax.weights import convert
    params = convert.params_from_torch(_torch_state(a.torch_src))
    src, ref, gt = _inputs(a.points, a.batch)
    dev = jax.devices()[0]
    record = {"impl": "jax", "jax": jax.__version__, "device": f"{dev.platform}:{dev.device_kind}"}
    if a.task == "infer":
        fn = jax.jit(registration.register, static_argnames="num_iters")
        t0 = time.perf_counter()
        jax.block_until_ready(fn(params, src, ref, num_iters=5).transform)
        record.update(compile_seconds=time.perf_counter() - t0)
        seconds = _median_time(lambda: fn(params, src, ref, num_iters=5).transform, a.repeats,
                               jax.block_until_ready) / a.batch
    else:
        cfg = training.TrainConfig(model=config.RPMNetConfig(fused_prepool=not a.autodiff_prepool))
        record.update(variant="autodiff" if a.autodiff_prepool else "fused")
        step = training.make_train_step(cfg)
        state = training.create_train_state(jax.random.PRNGKey(0), cfg)
        state = state._replace(params=params, opt_state=training.make_optimizer(cfg).init(params))
        batch = {"points_src": src, "points_ref": ref, "transform_gt": gt}
        t0 = time.perf_counter()
        state, scalars = step(state, batch)
        jax.block_until_ready(scalars["loss"])
        record.update(compile_seconds=time.perf_counter() - t0)
        holder = [state]

        def run():
            holder[0], s = step(holder[0], batch)
            return s["loss"]
        seconds = _median_time(run, a.repeats, jax.block_until_ready)
    record.update(seconds=seconds)
    return record


def _torch_state(torch_src: str) -> dict:
    """The official model's (randomly initialised, seeded) weights as NumPy arrays."""
    return {k: v.detach().numpy() for k, v in _torch_model(torch_src).state_dict().items()}


def worker_check(a) -> dict:
    """Max |difference| between the official and our transforms on the same input and weights."""
    import jax
    import numpy as np
    import torch
    sys.path.insert(0, os.path.dirname(HERE))
    from rpmnet_jax import registration
    from rpmnet_jax.weights import convert
    torch.set_num_threads(a.threads)
    net = _torch_model(a.torch_src).eval()
    params = convert.params_from_torch({k: v.detach().numpy() for k, v in net.state_dict().items()})
    src, ref, _ = _inputs(a.points, a.batch, seed=1)
    with torch.no_grad():
        t_torch = torch.stack(net({"points_src": torch.from_numpy(src), "points_ref": torch.from_numpy(ref)},
                                  num_iter=5)[0]).numpy()
    t_jax = np.asarray(jax.jit(registration.register)(params, src, ref).transforms)
    return {"impl": "both", "task": "check", "max_abs_diff_transforms": float(np.abs(t_torch - t_jax).max()),
            "max_abs_diff_last": float(np.abs(t_torch[-1] - t_jax[-1]).max())}


def run_worker(a, impl: str, task: str, points: int, batch: int, extra=()) -> dict:
    cmd = [sys.executable, os.path.abspath(__file__), "--worker", impl, "--task", task, "--torch-src", a.torch_src,
           "--points", str(points), "--batch", str(batch), "--threads", str(a.threads),
           "--repeats", str(a.repeats if task == "infer" else a.train_repeats), *extra]
    env = dict(os.environ)
    if a.malloc == "hugetlb":  # the same glibc setting for both frameworks (see rpmnet_jax/runtime.py)
        from rpmnet_jax.cli import runtime
        env["GLIBC_TUNABLES"] = runtime.TUNABLES
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
    if proc.returncode != 0:
        return {"impl": impl, "task": task, "points": points, "batch": batch,
                "error": (proc.stderr.strip().splitlines() or ["failed"])[-1]}
    return dict(json.loads(proc.stdout.strip().splitlines()[-1]), malloc=a.malloc)


def write_table(path: str, records: list, meta: dict) -> None:
    """Markdown table: one row per (task, variant, points, batch) with torch and jax side by side."""
    torch_rows = {(r["task"], r["points"], r["batch"]): r for r in records
                  if r.get("impl") == "torch" and "seconds" in r}
    lines = [f"Machine: {meta['machine']}; {meta['threads']} threads per framework; malloc {meta['malloc']}; "
             f"jax {meta.get('jax')}, torch {meta.get('torch')}. Seconds per pair (infer) or per step (train).", "",
             "| task | points | batch | torch s | torch peak MB | jax s | jax peak MB | speed-up |",
             "|---|---|---|---|---|---|---|---|"]
    for j in records:
        if j.get("impl") != "jax" or "seconds" not in j:
            continue
        t = torch_rows.get((j["task"], j["points"], j["batch"]))
        task = j["task"] + (f" ({j['variant']})" if j.get("variant") else "")
        torch_cols = f"{t['seconds']:.3f} | {t['peak_rss_mb']:.0f}" if t else "- | -"
        speed = f"{t['seconds'] / j['seconds']:.2f}x" if t else "-"
        lines.append(f"| {task} | {j['points']} | {j['batch']} | {torch_cols} | {j['seconds']:.3f} | "
                     f"{j['peak_rss_mb']:.0f} | {speed} |")
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n")


def write_plot(path: str, records: list) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(5, 3.5))
    for impl, colour in (("torch", "tab:red"), ("jax", "tab:blue")):
        for batch, style in ((1, "-o"), (8, "--s")):
            pts = sorted((r["points"], r["seconds"]) for r in records
                         if r.get("task") == "infer" and r.get("impl") == impl and r.get("batch") == batch
                         and "seconds" in r)
            if pts:
                ax.plot(*zip(*pts), style, color=colour, label=f"{impl} B={batch}")
    ax.set_xlabel("points per cloud")
    ax.set_ylabel("seconds per pair (5 iterations)")
    ax.set_xscale("log", base=2)
    ax.set_yscale("log")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--torch-src", required=True, help="src/ folder of the official RPM-Net checkout")
    p.add_argument("--points", type=int, nargs="+", default=[512, 1024, 2048])
    p.add_argument("--batch", type=int, nargs="+", default=[1, 8])
    p.add_argument("--tasks", default="infer,train", help="comma-separated subset of infer,train")
    p.add_argument("--threads", type=int, default=len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity")
                   else os.cpu_count(), help="CPUs and threads given to each framework (default: all)")
    p.add_argument("--malloc", choices=("default", "hugetlb"), default="default",
                   help="glibc malloc setting for both frameworks: default, or transparent huge pages (what the "
                        "rpmnet_jax CLIs use)")
    p.add_argument("--repeats", type=int, default=5, help="timed repeats per inference measurement")
    p.add_argument("--train-repeats", type=int, default=3, help="timed repeats per training measurement")
    p.add_argument("--out-md", default=os.path.join(HERE, "results_compare_torch.md"))
    p.add_argument("--out-png", default=os.path.join(HERE, "results_compare_torch.png"))
    p.add_argument("--worker", choices=("jax", "torch", "check"), help=argparse.SUPPRESS)
    p.add_argument("--task", choices=("infer", "train"), default="infer", help=argparse.SUPPRESS)
    p.add_argument("--autodiff-prepool", action="store_true", help=argparse.SUPPRESS)
    a = p.parse_args(argv)
    if not os.path.isfile(os.path.join(a.torch_src, "models", "rpmnet.py")):
        p.error(f"--torch-src {a.torch_src!r} is not the official RPM-Net src/ folder (no models/rpmnet.py)")
    if a.worker:
        _pin(a.threads)
        a.points, a.batch = a.points[0], a.batch[0]
        record = {"check": worker_check, "jax": worker_jax, "torch": worker_torch}[a.worker](a)
        record.setdefault("task", a.task)
        record.update(points=a.points, batch=a.batch, threads=a.threads, peak_rss_mb=round(_peak_rss_mb(), 1))
        print(json.dumps(record), flush=True)
        return 0

    import platform
    tasks = [t for t in a.tasks.split(",") if t]
    meta = {"machine": f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPUs", "threads": a.threads, "malloc": a.malloc}
    records = [run_worker(a, "check", "infer", 1024, 1)]
    records[0]["task"] = "check"
    print(json.dumps(records[0]), flush=True)
    jobs = []
    if "infer" in tasks:
        jobs += [(impl, "infer", n, b, ()) for n in a.points for b in a.batch for impl in ("torch", "jax")]
    if "train" in tasks:
        jobs += [("torch", "train", TRAIN_POINTS, TRAIN_BATCH, ()), ("jax", "train", TRAIN_POINTS, TRAIN_BATCH, ()),
                 ("jax", "train", TRAIN_POINTS, TRAIN_BATCH, ("--autodiff-prepool",))]
    for impl, task, n, b, extra in jobs:
        record = run_worker(a, impl, task, n, b, extra)
        meta.setdefault(impl, record.get(impl))
        records.append(record)
        print(json.dumps(record), flush=True)
    write_table(a.out_md, records, meta)
    write_plot(a.out_png, records)
    print(json.dumps({"table": a.out_md, "plot": a.out_png}), file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
