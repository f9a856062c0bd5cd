"""Evaluation on the paper's protocol: run methods over a deterministic split, official metrics, table."""

from __future__ import annotations

import csv
import json
import math
import os
import time

import numpy as np

from rpmnet_jax import data, registration
from rpmnet_jax.evaluation import baselines
from rpmnet_jax.pairwise import alignment
from rpmnet_jax.pairwise.options import GlobalOptions, NetworkOptions
from rpmnet_jax.data import loader
from rpmnet_jax import metrics
from rpmnet_jax import config as config_lib

METHODS = ("rpmnet", "rpmnet_icp", "rpmnet_auto", "rpmnet_global", "network_icp", "classical_icp", "icp", "fgr",
           "ransac_icp", "fgr_icp", "rpm", "identity")
# the registration pipeline of :func:`rpmnet_jax.align` with these options; network_icp and classical_icp are the
# ablation of its candidate sources: the network's alone (its global search, no classical hypotheses) and the
# classical hypotheses alone (no network)
PIPELINES = {"rpmnet_icp": dict(init="local", refine="icp"), "rpmnet_auto": dict(init="auto", refine="icp"),
             "rpmnet_global": dict(init="global", refine="icp"),
             "network_icp": dict(init="global", refine="icp", global_options=GlobalOptions(classical=0)),
             "classical_icp": dict(init="classical", refine="icp")}
# the methods that run the network (and so take a checkpoint's params); classical_icp and the baselines do not
NETWORK_METHODS = ("rpmnet", "rpmnet_icp", "rpmnet_auto", "rpmnet_global", "network_icp")
CSV_COLUMNS = ("idx", "label", "r_mse", "r_mae", "t_mse", "t_mae", "err_r_deg", "err_t", "chamfer_dist")


def _rpmnet_fn(params, cfg, num_iters):
    fn = registration.jitted(cfg, num_iters, "transforms")
    return lambda s, r: np.swapaxes(np.asarray(fn(params, s, r)), 0, 1)  # (B, I, 3, 4)


def _pipeline_fn(params, cfg, num_iters, options):
    def run(src, ref):
        out = []
        for s, r in zip(np.asarray(src, np.float64), np.asarray(ref, np.float64)):
            a = alignment.align(s[:, :3], r[:, :3], s[:, 3:6], r[:, 3:6], params=params, cfg=cfg,
                                network_options=NetworkOptions(points=max(len(s), len(r)), iters=num_iters),
                                **options)
            out.append(a.transform[:3])
        return np.stack(out)[:, None]
    return run


def method_fn(name: str, params=None, cfg: config_lib.RPMNetConfig | None = None, num_iters: int = 5):
    """``f(src (B,J,6), ref (B,K,6)) -> transforms (B, I, 3, 4)`` (I = 1 for single-shot methods).

    ``rpmnet`` is the network alone (the paper); ``rpmnet_icp``, ``rpmnet_auto`` and ``rpmnet_global`` are
    :func:`rpmnet_jax.align`'s pipeline with a local, automatic or global start and ICP refinement;
    ``network_icp`` / ``classical_icp`` the same with only the network's or only the classical candidates;
    ``ransac_icp`` and ``fgr_icp`` are Open3D's classical recipe (FPFH + RANSAC or FGR, then robust
    point-to-plane ICP; :func:`baselines.global_then_icp`).
    """
    if name == "rpmnet":
        return _rpmnet_fn(params, cfg or config_lib.RPMNetConfig(), num_iters)
    if name in PIPELINES:
        return _pipeline_fn(params, cfg, num_iters, PIPELINES[name])
    if name == "identity":
        return lambda s, r: baselines.identity(s, r)[:, None]
    if name == "rpm":
        return lambda s, r: np.asarray(baselines.classical_rpm(s[..., :3], r[..., :3]))[-1][:, None]
    if name in ("icp", "fgr", "ransac_icp", "fgr_icp"):
        why = baselines.open3d_available()
        if why:
            raise RuntimeError(why)
        f = {"icp": baselines.icp, "fgr": baselines.fgr,
             "ransac_icp": lambda s, r: baselines.global_then_icp(s, r, "ransac"),
             "fgr_icp": lambda s, r: baselines.global_then_icp(s, r, "fgr")}[name]
        return lambda s, r: f(s, r)[:, None]
    raise ValueError(f"unknown method {name!r}; choose from {METHODS}")


def run_method(fn, dataset, batch_size: int, limit: int | None = None, progress: bool = True, desc: str = ""):
    """Runs ``fn`` over ``dataset``; returns per-pair metrics (final transform), the transforms
    ``(N, I, 3, 4)``, per-iteration Chamfer distances ``(N, I)`` and seconds per pair (after warm-up)."""
    from tqdm.auto import tqdm

    n = len(dataset) if limit is None else min(limit, len(dataset))
    per_pair: dict = {"idx": [], "label": []}
    all_t, chamfer_iters, seconds, timed = [], [], 0.0, 0
    subset = data.Head(dataset, n)
    batches = loader.batches(subset, batch_size, keys=("points_src", "points_ref", "transform_gt", "points_raw",
                                                       "label", "idx"))
    for i, batch in enumerate(tqdm(batches, total=math.ceil(n / batch_size), desc=desc, disable=not progress)):
        t0 = time.perf_counter()
        transforms = fn(batch["points_src"], batch["points_ref"])
        if i > 0 or n <= batch_size:  # the first batch pays for compilation
            seconds += time.perf_counter() - t0
            timed += len(transforms)
        all_t.append(transforms)
        m = metrics.registration_metrics(transforms[:, -1], batch["transform_gt"], batch["points_src"],
                                         batch["points_ref"], batch["points_raw"])
        for k, v in m.items():
            per_pair.setdefault(k, []).append(v)
        per_pair["idx"].append(batch["idx"])
        per_pair["label"].append(batch["label"])
        chamfer_iters.append(np.stack([
            metrics.registration_metrics(transforms[:, it], batch["transform_gt"], batch["points_src"],
                                         batch["points_ref"], batch["points_raw"])["chamfer_dist"]
            for it in range(transforms.shape[1])], axis=1))
    per_pair = {k: np.concatenate(v) for k, v in per_pair.items()}
    return per_pair, np.concatenate(all_t), np.concatenate(chamfer_iters), seconds / max(timed, 1)


def format_table(rows: dict) -> str:
    """Paper-style table (Tables 1-3): anisotropic MAE, isotropic mean errors, modified Chamfer distance."""
    head = (f"{'Method':<10} | {'Rot. MAE (deg)':>14} {'Trans. MAE':>11} | {'Rot. iso (deg)':>14} "
            f"{'Trans. iso':>11} | {'CD~':>10} | {'s/pair':>8}")
    lines = [head, "-" * len(head)]
    for name, r in rows.items():
        if "error" in r:
            lines.append(f"{name:<10} | {r['error']}")
            continue
        s = r["summary"]
        lines.append(f"{name:<10} | {s['r_mae']:>14.4f} {s['t_mae']:>11.5f} | {s['err_r_deg_mean']:>14.4f} "
                     f"{s['err_t_mean']:>11.5f} | {s['chamfer_dist']:>10.6f} | {r['seconds_per_pair']:>8.4f}")
    return "\n".join(lines)


def write_outputs(out_dir: str, name: str, per_pair: dict, transforms: np.ndarray) -> None:
    os.makedirs(out_dir, exist_ok=True)
    np.save(os.path.join(out_dir, f"transforms_{name}.npy"), transforms.astype(np.float32))
    with open(os.path.join(out_dir, f"per_pair_{name}.csv"), "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(CSV_COLUMNS)
        for i in range(len(per_pair["idx"])):
            w.writerow([int(per_pair["idx"][i]), int(per_pair["label"][i])] +
                       [f"{float(per_pair[k][i]):.8g}" for k in CSV_COLUMNS[2:]])


def save_json(path: str, obj) -> None:
    with open(path, "w") as f:
        json.dump(obj, f, indent=2)
