"""Refinement A/B: our ICP (as :func:`rpmnet_jax.align` runs it) against Open3D's robust point-to-plane ICP
(:func:`baselines.robust_icp`, the classical recipe's settings), from the same starts on the same clouds.

Starts, per pair: ``perturbed`` — the ground truth moved by a seeded random rotation of ``3–10°`` about a
random axis and a translation of up to ``0.02`` (unit-sphere data); ``rpmnet`` — the network's answer as
``align(init="local")`` computes it (same preparation, same seed). Errors are the isotropic rotation (°) and
translation errors of :func:`metrics.transform_errors`.
"""

from __future__ import annotations

import csv
import time

import numpy as np
from scipy.spatial.transform import Rotation

from rpmnet_jax import config as config_lib
from rpmnet_jax import metrics, registration
from rpmnet_jax.evaluation import baselines
from rpmnet_jax.ops import se3
from rpmnet_jax.classical import icp
from rpmnet_jax.pairwise import alignment, candidates, options, prepare, starts

STARTS = ("perturbed", "rpmnet")
CSV_COLUMNS = ("idx", "label", "start", "start_err_r", "start_err_t", "ours_err_r", "ours_err_t", "o3d_err_r",
               "o3d_err_t", "ours_seconds", "o3d_seconds", "ours_iterations")


def perturbed_start(gt, rng: np.random.Generator, min_deg: float = 3.0, max_deg: float = 10.0,
                    max_trans: float = 0.02) -> np.ndarray:
    """``gt (3, 4)`` moved by a random rotation of ``min_deg..max_deg`` and translation ``≤ max_trans`` →
    ``(4, 4)`` (maps source onto reference)."""
    axis = rng.normal(size=3)
    rot = Rotation.from_rotvec(np.radians(rng.uniform(min_deg, max_deg)) * axis / np.linalg.norm(axis))
    direction = rng.normal(size=3)
    delta = np.eye(4)
    delta[:3, :3] = rot.as_matrix()
    delta[:3, 3] = rng.uniform(0.0, max_trans) * direction / np.linalg.norm(direction)
    return delta @ se3.to_homogeneous(np.asarray(gt, np.float64))


def _to_unit(pair: prepare.PreparedPair, t44) -> np.ndarray:
    """Caller's-units ``(4, 4)`` → the normalised frame's ``(4, 4)`` (inverse of ``to_callers_units``)."""
    t = np.array(t44, np.float64)
    t[:3, 3] = (t[:3, 3] + t[:3, :3] @ pair.c_src - pair.c_ref) / pair.scale
    return t


class Prepared:
    """One pair prepared as ``align`` prepares it (default options), for refining from any start."""

    def __init__(self, src6, ref6, seed: int = 0):
        src6, ref6 = np.asarray(src6, np.float64), np.asarray(ref6, np.float64)
        self.pair = prepare.prepare_pair(src6[:, :3], ref6[:, :3], src6[:, 3:6], ref6[:, 3:6],
                                         num_points=max(len(src6), len(ref6)), seed=seed)
        self.dense = prepare.dense_clouds(self.pair, options.RefineOptions().points, seed,
                                          prepare.RowNormals(self.pair.ref, self.pair.ref_normals))
        self.max_dist_unit = alignment.DEFAULT_RELATIVE_DISTANCE

    def network_start(self, params, cfg=None, num_iters: int = 5) -> np.ndarray:
        """The network's answer from the identity ``(4, 4)``, caller's units (``align``'s local start)."""
        reg = registration.jitted(cfg or config_lib.RPMNetConfig(), int(num_iters))(
            params, self.pair.src6, self.pair.ref6)
        return self.pair.to_callers_units(np.asarray(reg.transforms[-1, 0], np.float64))

    def refine(self, start44) -> icp.Refinement:
        """Our ICP from ``start44 (4, 4)`` (caller's units), through ``align``'s own refinement step → the
        refinement in the caller's units."""
        start = starts.Start("ab", np.zeros((1, 3, 4)), 0.0, _to_unit(self.pair, start44))
        c = candidates.refine_starts([start], self.dense, self.max_dist_unit, "icp", options.RefineOptions())[0]
        return icp.Refinement(self.pair.to_callers_units(c.transform[:3]), c.converged, c.num_iterations)


def run(dataset, starts=STARTS, limit: int | None = None, params=None, seed: int = 0, progress: bool = True
        ) -> list[dict]:
    """One row per pair and start of ``dataset`` (``points_src``, ``points_ref`` ``(·, 6)``,
    ``transform_gt``): the start's, ours and Open3D's errors and seconds."""
    from tqdm.auto import tqdm

    unknown = [s for s in starts if s not in STARTS]
    if unknown:
        raise ValueError(f"unknown starts {unknown}; choose from {STARTS}")
    n = len(dataset) if limit is None else min(limit, len(dataset))
    rows = []
    for i in tqdm(range(n), disable=not progress, desc="refine A/B"):
        s = dataset[i]
        gt = np.asarray(s["transform_gt"], np.float64)
        prepared = Prepared(s["points_src"], s["points_ref"], seed=seed)
        for kind in starts:
            start = (perturbed_start(gt, np.random.default_rng([seed, int(s["idx"])])) if kind == "perturbed"
                     else prepared.network_start(params))
            t0 = time.perf_counter()
            ours = prepared.refine(start)
            t1 = time.perf_counter()
            theirs = baselines.robust_icp(s["points_src"], s["points_ref"], start)
            t2 = time.perf_counter()
            row = {"idx": int(s["idx"]), "label": int(s["label"]), "start": kind}
            for name, t in (("start", start), ("ours", ours.transform), ("o3d", theirs)):
                row[f"{name}_err_r"], row[f"{name}_err_t"] = metrics.transform_errors(t, gt)
            row.update(ours_seconds=t1 - t0, o3d_seconds=t2 - t1, ours_iterations=ours.num_iterations)
            rows.append(row)
    return rows


def summarize(rows: list[dict]) -> dict:
    """Per start: pairs, median / mean rotation (°) and translation errors of the start, ours and Open3D's,
    the share of pairs each improved on its start, the share where ours ends at least as close as Open3D's
    (rotation), and seconds per pair."""
    out = {}
    for kind in dict.fromkeys(r["start"] for r in rows):
        sel = [r for r in rows if r["start"] == kind]
        col = lambda k: np.array([r[k] for r in sel], np.float64)
        summary = {"pairs": len(sel)}
        for name in ("start", "ours", "o3d"):
            er, et = col(f"{name}_err_r"), col(f"{name}_err_t")
            summary[name] = {"err_r_median": float(np.median(er)), "err_r_mean": float(np.mean(er)),
                             "err_t_median": float(np.median(et)), "err_t_mean": float(np.mean(et))}
            if name != "start":
                summary[name]["improved"] = float(np.mean(er < col("start_err_r")))
                summary[name]["seconds_per_pair"] = float(np.mean(col(f"{name}_seconds")))
        summary["ours_at_least_as_close"] = float(np.mean(col("ours_err_r") <= col("o3d_err_r")))
        out[kind] = summary
    return out


def write_csv(path: str, rows: list[dict]) -> None:
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(CSV_COLUMNS)
        for r in rows:
            w.writerow([r[k] if isinstance(r[k], (int, str)) else f"{r[k]:.8g}" for k in CSV_COLUMNS])
