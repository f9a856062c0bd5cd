"""The one set of helpers for the benchmark scripts: timing, memory, CPU pinning, malloc setting, inputs, weights.

This module imports neither jax nor torch at module level: a measurement process imports only its own framework
(each helper that needs one imports it when called). ``prepare`` runs in a process of its own (``python
benchmarks/bench_utils.py --prepare FILE ...``): it builds the official model with its seeded initial weights
and the synthetic input pairs, and writes both to one ``.npz`` that every measurement process ``np.load``\\ s.
The repository root is put on ``sys.path`` so the scripts run from a bare checkout (nothing installed).
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import resource
import statistics
import subprocess
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
if REPO not in sys.path:
    sys.path.insert(0, REPO)


# ---- process set-up -------------------------------------------------------------------------------------------

def available_cpus() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()


def pin(threads: int) -> None:
    """Restricts this process to its first ``threads`` CPUs (call before the framework starts its thread pool)."""
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, sorted(os.sched_getaffinity(0))[:threads])


def malloc_env(setting: str) -> dict:
    """The environment for a measurement process: glibc's malloc defaults (``"default"``: no ``GLIBC_TUNABLES``)
    or the training CLI's huge-page tunables (``"hugetlb"``: ``rpmnet_jax.cli.runtime.TUNABLES``). They are read
    at process start, so they are set for the worker, the same for both frameworks."""
    env = {k: v for k, v in os.environ.items() if k != "GLIBC_TUNABLES"}
    if setting == "hugetlb":
        from rpmnet_jax.cli import runtime
        env["GLIBC_TUNABLES"] = runtime.TUNABLES
    elif setting != "default":
        raise ValueError(f"malloc setting must be 'default' or 'hugetlb', got {setting!r}")
    return env


def run_worker(cmd: list, env: dict, record: dict, jsonl: str | None = None) -> dict:
    """Runs one measurement process and prints (and appends to ``jsonl``) ``record`` updated with its record, the
    last line of its stdout (JSON); on failure, with ``error`` (the last line of its stderr)."""
    proc = subprocess.run([str(c) for c in cmd], capture_output=True, text=True, env=env)
    lines = proc.stdout.strip().splitlines()
    if proc.returncode != 0 or not lines:
        record = dict(record, error=(proc.stderr.strip().splitlines() or [f"exit {proc.returncode}"])[-1])
    else:
        record = dict(record, **json.loads(lines[-1]))
    emit(record, jsonl)
    return record


def test_file_arguments(parser, *, dataset: str, pairs: int, rot_mag: float) -> None:
    """The arguments of a script that runs the first ``--pairs`` of a test file (``--split val``): ``--data-root``,
    ``--dataset``, ``--pairs``, ``--rot-mag``, and ``--threads`` (see :func:`pin`)."""
    parser.add_argument("--data-root", required=True)
    parser.add_argument("--dataset", default=dataset, choices=("clean", "noisy", "partial"))
    parser.add_argument("--pairs", type=int, default=pairs)
    parser.add_argument("--rot-mag", type=float, default=rot_mag)
    parser.add_argument("--threads", type=int, default=available_cpus(), help="CPUs to run on (default: all)")


LIBRARIES = ("numpy", "scipy", "numba", "jax", "jaxlib", "gtsam")  # whose builds can change an answer


def session(script: str, argv, threads: int, malloc: str) -> dict:
    """What a results table states about its run: date, CPU, threads, malloc setting, the command line and the
    installed versions of :data:`LIBRARIES` (the same code on other builds can give other answers)."""
    args = list(sys.argv[1:] if argv is None else argv)
    return {"date": datetime.date.today().isoformat(), "cpu": cpu_model(), "cpus": available_cpus(),
            "threads": threads, "malloc": malloc,
            "command": " ".join(["python", f"benchmarks/{script}", *_without_paths(args)]),
            "libraries": library_versions()}


def reset_peak_memory() -> bool:
    """Resets this process's peak resident memory (Linux: ``/proc/self/clear_refs``), so that
    :func:`peak_memory_mb` measures from here (``getrusage``'s ``ru_maxrss`` is reset too: read it before);
    False where the system has no such reset."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


def peak_memory_mb() -> float | None:
    """This process's peak resident memory since it started or since :func:`reset_peak_memory` (VmHWM), MB;
    None where ``/proc`` is not there."""
    try:
        with open("/proc/self/status") as f:
            return next(round(int(line.split()[1]) / 1024, 1) for line in f if line.startswith("VmHWM"))
    except (OSError, StopIteration):
        return None


def library_versions() -> dict:
    """``{name: version}`` of :data:`LIBRARIES` as installed (``None``: not installed), without importing them."""
    from importlib import metadata

    versions = {}
    for name in LIBRARIES:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = None
    return versions


_PATH_FLAGS = {"--torch-src": "PATH/TO/RPMNet/src", "--out-md": None, "--out-png": None, "--out-jsonl": None}


def _without_paths(args: list) -> list:
    """The command line as a table states it: the official checkout's location as a placeholder, output
    paths left out (both are this machine's, not the measurement's)."""
    out, skip = [], False
    for arg in args:
        if skip:
            skip = False
            continue
        flag, _, value = arg.partition("=")
        if flag in _PATH_FLAGS:
            skip = not value
            if _PATH_FLAGS[flag]:
                out += [flag, _PATH_FLAGS[flag]]
            continue
        out.append(arg)
    return out


def slope(xs, ys) -> float:
    """Least-squares slope of ``log y`` against ``log x`` (1: linear growth, 2: quadratic)."""
    return float(np.polyfit(np.log(xs), np.log(ys), 1)[0])


def emit(record: dict, path: str | None = None) -> None:
    """Prints ``record`` as one JSON line (and appends it to ``path``)."""
    line = json.dumps(record)
    print(line, flush=True)
    if path:
        with open(path, "a") as f:
            f.write(line + "\n")


# ---- what was measured where ----------------------------------------------------------------------------------

def commit(repo: str = REPO) -> str:
    """The checkout's commit (``+`` when tracked files differ from it), or ``"unknown"``; ``repo``: another
    checkout (a ``git worktree`` of an earlier commit)."""
    git = ["git", "-C", repo]
    try:
        head = subprocess.run(git + ["rev-parse", "--short", "HEAD"], capture_output=True, text=True, check=True)
        dirty = subprocess.run(git + ["status", "--porcelain", "--untracked-files=no"], capture_output=True,
                               text=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return head.stdout.strip() + ("+" if dirty else "")


def frameworks_loaded(own: str | None = None) -> dict:
    """``{"jax_loaded", "torch_loaded"}`` for this process; with ``own``, asserts the other one is absent."""
    loaded = {"jax_loaded": "jax" in sys.modules, "torch_loaded": "torch" in sys.modules}
    if own is not None:
        other = {"jax": "torch", "torch": "jax"}[own]
        assert not loaded[f"{other}_loaded"], f"the {own} measurement imported {other}"
    return loaded


def cpu_model() -> str:
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def environment() -> dict:
    """Machine, CPUs, malloc setting, and the version and device of whichever framework this process loaded."""
    env = {"cpu": cpu_model(), "cpus": available_cpus(), "python": platform.python_version(),
           "glibc_tunables": os.environ.get("GLIBC_TUNABLES", "")}
    if "jax" in sys.modules:
        jax = sys.modules["jax"]
        dev = jax.devices()[0]
        env.update(jax=jax.__version__, device=f"{dev.platform}:{getattr(dev, 'device_kind', '')}",
                   matmul_precision=str(jax.config.jax_default_matmul_precision or "default"))
    if "torch" in sys.modules:
        torch = sys.modules["torch"]
        env["torch"] = torch.__version__
        if "jax" not in sys.modules:
            env["device"] = f"cuda:{torch.cuda.get_device_name()}" if torch.cuda.is_initialized() else "cpu"
        if torch.cuda.is_initialized():
            env["tf32"] = {"matmul": torch.backends.cuda.matmul.allow_tf32, "cudnn": torch.backends.cudnn.allow_tf32}
    return env


def peak_rss_mb() -> float:
    """Peak resident set size of this process in MiB."""
    scale = 1 if sys.platform == "darwin" else 1024  # ru_maxrss is bytes on macOS, KiB on Linux
    return round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * scale / 2**20, 1)


def device_peak_mb() -> float | None:
    """Peak accelerator memory of this process in MiB (JAX or torch CUDA); None on CPU."""
    if "jax" in sys.modules:
        stats = sys.modules["jax"].devices()[0].memory_stats() or {}
        if "peak_bytes_in_use" in stats:
            return round(stats["peak_bytes_in_use"] / 2**20, 1)
    if "torch" in sys.modules and sys.modules["torch"].cuda.is_initialized():
        return round(sys.modules["torch"].cuda.max_memory_allocated() / 2**20, 1)
    return None


# ---- timing ---------------------------------------------------------------------------------------------------

def timed(run, repeats: int, sync=lambda x: x, max_seconds: float | None = None) -> dict:
    """Times ``sync(run())``: the first call apart (``first_call_seconds``), then ``repeats`` calls: median
    (``seconds``), min and max. With ``max_seconds``, stops early once the repeats took that long (at least 3)."""
    t0 = time.perf_counter()
    sync(run())
    first = time.perf_counter() - t0
    times = []
    while len(times) < repeats:
        t0 = time.perf_counter()
        sync(run())
        times.append(time.perf_counter() - t0)
        if max_seconds is not None and len(times) >= 3 and sum(times) >= max_seconds:
            break
    return {"first_call_seconds": first, "seconds": statistics.median(times), "min_seconds": min(times),
            "max_seconds": max(times), "repeats": len(times)}


def compile_jax(jitted, *args):
    """``(compiled, seconds)``: ``jitted`` lowered and compiled ahead of time for ``args`` (the compile time
    alone; calling ``compiled(*args)`` then never traces or compiles)."""
    t0 = time.perf_counter()
    compiled = jitted.lower(*args).compile()
    return compiled, time.perf_counter() - t0


def warm_align(src, ref, src_normals=None, ref_normals=None, **kwargs) -> None:
    """Pays every compilation :func:`rpmnet_jax.align` can meet on clouds of these sizes before a timed run: the
    classical path, the network from the identity and its global search."""
    from rpmnet_jax.pairwise import alignment
    for init in ("auto", "local", "global"):
        alignment.align(src, ref, src_normals, ref_normals, init=init, **kwargs)


def time_jax(jitted, *args, repeats: int, max_seconds: float | None = None) -> dict:
    """:func:`timed` of a jitted function, compiled first (``compile_seconds``); results blocked on."""
    import jax
    compiled, compile_s = compile_jax(jitted, *args)
    return dict(timed(lambda: compiled(*args), repeats, jax.block_until_ready, max_seconds),
                compile_seconds=compile_s)


def plot(path: str, lines, xlabel: str, ylabel: str) -> None:
    """A log-log PNG of ``lines``: ``(points [(x, y)], style, label, colour or None)``; empty lines are left out.
    Without matplotlib (e.g. on a bare GPU machine) it says so and writes nothing."""
    try:
        import matplotlib
    except ImportError:
        print(f"matplotlib not installed: no plot {path}", file=sys.stderr)
        return
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(5, 3.5))
    for pts, style, label, colour in lines:
        if pts:
            ax.plot(*zip(*pts), style, color=colour, label=label)
    ax.set_xscale("log", base=2)
    ax.set_yscale("log")
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


# ---- inputs and weights ---------------------------------------------------------------------------------------

def inputs(points: int, batch: int, seed: int = 0):
    """A realistic pair ``src, ref (B, points, 6)`` and ``gt (B, 3, 4)`` (maps source onto reference): synthetic
    shapes (unit sphere), the reference a random rigid motion of other points of the same shape. Imports jax
    (through ``rpmnet_jax``): call it in a JAX process or in :func:`prepare`."""
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


def official_model(torch_src: str, state: dict | None = None):
    """The official RPM-Net (paper settings), initialised with ``torch.manual_seed(0)``, or with ``state``
    (name -> NumPy array) loaded into it."""
    sys.path.insert(0, os.path.abspath(torch_src))
    import torch
    from models.rpmnet import get_model  # the official code (not part of this repository)
    args = argparse.Namespace(no_slack=False, num_sk_iter=5, features=["ppf", "dxyz", "xyz"], feat_dim=96,
                              radius=0.3, num_neighbors=64)
    torch.manual_seed(0)
    net = get_model(args)
    if state is not None:
        net.load_state_dict({k: torch.from_numpy(np.asarray(v)) for k, v in state.items()})
    return net


def _size_key(points: int, batch: int) -> str:
    return f"{points}x{batch}"


def prepare(path: str, sizes, torch_src: str | None = None, check=None, iters: int = 5) -> None:
    """Writes ``path`` (.npz): the input pair of every ``(points, batch)`` in ``sizes``; initial weights in the
    official layout (``weights/<name>``): the official model's seeded ones with ``torch_src``, else ours
    (``init_params`` seed 0); for ``check = (points, batch)`` a pair (seed 1) and, with ``torch_src``, the
    official model's ``iters`` transforms on it (``check/transforms``)."""
    arrays = {}
    for points, batch in sizes:
        for name, value in zip(("src", "ref", "gt"), inputs(points, batch)):
            arrays[f"{name}/{_size_key(points, batch)}"] = value
    if check is not None:
        arrays["check/src"], arrays["check/ref"], _ = inputs(*check, seed=1)
    if torch_src is None:
        import jax
        from rpmnet_jax import init_params
        from rpmnet_jax.weights import convert
        weights = convert.params_to_torch(init_params(jax.random.PRNGKey(0)))
    else:
        import torch
        net = official_model(torch_src).eval()
        weights = {k: v.detach().numpy() for k, v in net.state_dict().items()}
        if check is not None:
            with torch.no_grad():
                out = net({"points_src": torch.from_numpy(arrays["check/src"]),
                           "points_ref": torch.from_numpy(arrays["check/ref"])}, num_iter=iters)[0]
            arrays["check/transforms"] = torch.stack(out).numpy()
    arrays.update({f"weights/{k}": np.asarray(v) for k, v in weights.items()})
    np.savez(path, **arrays)


def run_prepare(path: str, sizes, torch_src: str | None = None, check=None) -> None:
    """:func:`prepare` in a process of its own (it imports both frameworks)."""
    cmd = [sys.executable, os.path.abspath(__file__), "--prepare", path,
           "--sizes", *[_size_key(*s) for s in sizes]]
    cmd += ["--torch-src", torch_src] if torch_src else []
    cmd += ["--check", _size_key(*check)] if check else []
    subprocess.run(cmd, check=True)


class Prepared:
    """What :func:`prepare` wrote: ``pair(points, batch) -> (src, ref, gt)``, ``weights`` (official names -> NumPy
    arrays), ``check`` (the check pair and the official transforms on it, or None)."""

    def __init__(self, path: str):
        with np.load(path) as data:
            arrays = {k: data[k] for k in data.files}
        self._arrays = arrays
        self.weights = {k[len("weights/"):]: v for k, v in arrays.items() if k.startswith("weights/")}
        self.check = {k[len("check/"):]: v for k, v in arrays.items() if k.startswith("check/")} or None

    def pair(self, points: int, batch: int):
        key = _size_key(points, batch)
        return tuple(self._arrays[f"{name}/{key}"] for name in ("src", "ref", "gt"))

    def jax_params(self):
        """The weights as our parameter pytree (NumPy arrays)."""
        from rpmnet_jax.weights import convert
        return convert.params_from_torch(self.weights)


def _main(argv=None) -> int:
    p = argparse.ArgumentParser(description="Writes the inputs and official weights for a benchmark run.")
    p.add_argument("--prepare", required=True, metavar="FILE")
    p.add_argument("--sizes", nargs="+", required=True, help="POINTSxBATCH ...")
    p.add_argument("--torch-src")
    p.add_argument("--check", help="POINTSxBATCH of the pair the official transforms are computed on")
    a = p.parse_args(argv)
    parse = lambda s: tuple(int(x) for x in s.split("x"))
    prepare(a.prepare, [parse(s) for s in a.sizes], a.torch_src, parse(a.check) if a.check else None)
    return 0


if __name__ == "__main__":
    sys.exit(_main())
