"""Labelled examples for the likely-wrong model (:mod:`rpmnet_jax.pairwise.doubt`): ``align`` run on dataset pairs,
each answer kept as a JSON-safe record of what :func:`doubt.features` reads plus its true rotation error, so the
features can be recomputed (and the model re-fitted) without running ``align`` again."""

from __future__ import annotations

import json
import os
import time
import types
from typing import Callable, NamedTuple

import numpy as np

from rpmnet_jax import metrics
from rpmnet_jax.pairwise import alignment, doubt, options


def record(a: alignment.Alignment, transform_gt, **meta) -> dict:
    """A JSON-safe record of alignment ``a`` and its errors against ``transform_gt (3, 4)`` (maps source onto
    reference): ``error_deg`` of the answer, ``candidate_errors_deg`` of each distinct candidate, ``meta``."""
    centre, radius = doubt.lever(a)
    err = lambda t: float(metrics.transform_errors(np.asarray(t)[:3], np.asarray(transform_gt))[0])
    cands = [{"transform": np.asarray(c.transform).tolist(), "score": c.score, "fitness": c.fitness,
              "inlier_rmse": c.inlier_rmse, "init": c.init, "support": list(c.support)} for c in a.candidates]
    return {**meta, "error_deg": err(a.transform), "candidate_errors_deg": [err(c.transform) for c in a.candidates],
            "candidates": cands, "fitness": float(a.fitness), "inlier_rmse": float(a.inlier_rmse),
            "max_correspondence_distance": float(a.max_correspondence_distance),
            "information": np.asarray(a.information).tolist(), "confidence": float(a.confidence), "init": a.init,
            "stages": list(a.stages), "converged": bool(a.converged), "num_iterations": int(a.num_iterations),
            "ambiguous": bool(a.ambiguous), "centre": np.asarray(centre).tolist(), "radius": float(radius),
            "p_wrong": float(a.p_wrong)}


def alignment_of(rec: dict):
    """What :func:`doubt.features` reads, rebuilt from a :func:`record`."""
    cands = tuple(alignment.Answer(np.asarray(c["transform"]), c["score"], c["fitness"], c["inlier_rmse"], c["init"],
                                   tuple(c["support"])) for c in rec["candidates"])
    fields = {k: rec[k] for k in ("fitness", "inlier_rmse", "max_correspondence_distance", "confidence", "init",
                                  "stages", "converged", "ambiguous")}
    return types.SimpleNamespace(candidates=cands, information=np.asarray(rec["information"]), **fields)


def features(records) -> np.ndarray:
    """``(R, F)`` :data:`doubt.FEATURES` of records."""
    return np.stack([doubt.features(alignment_of(r), np.asarray(r["centre"]), r["radius"]) for r in records])


def labels(records) -> np.ndarray:
    """``(R,)`` bool: the answer is more than ``doubt.WRONG_DEG`` off."""
    return np.array([r["error_deg"] > doubt.WRONG_DEG for r in records])


def read(path: str) -> list:
    """The records of a JSON-lines file (none when it does not exist)."""
    if not os.path.exists(path):
        return []
    with open(path) as f:
        return [json.loads(line) for line in f if line.strip()]


def key(rec: dict) -> tuple:
    return tuple(rec.get(k) for k in ("set", "split", "protocol", "rot_mag", "seed", "setting", "idx"))


class Job(NamedTuple):
    """One pair for :func:`collect_jobs`: its record's ``meta`` (``key(meta)`` names it) and ``load()``, called only
    for a pair not yet recorded, returning ``(src (N, 3), ref (M, 3), src_normals or None, ref_normals or None,
    transform_gt (3 or 4, 4), align keywords, extra record fields)``."""

    meta: dict
    load: Callable[[], tuple]


def collect_jobs(jobs, params, path: str, *, progress: bool = True, total: int | None = None, desc: str = "",
                 deadline: float | None = None) -> list:
    """Runs the default ``align`` (with each job's keywords) on every :class:`Job` and appends one :func:`record` per
    pair to the JSON-lines ``path``, flushed as it goes; pairs already there (same :func:`key`) are skipped, and
    nothing more starts after ``deadline`` (``time.time()``). Returns the new records."""
    from tqdm.auto import tqdm

    done = {key(r) for r in read(path)}
    out = []
    with open(path, "a") as f:
        for job in tqdm(jobs, total=total, disable=not progress, desc=desc):
            if key(job.meta) in done:
                continue
            if deadline is not None and time.time() > deadline:
                break
            src, ref, src_normals, ref_normals, gt, kwargs, extra = job.load()
            t0 = time.perf_counter()
            a = alignment.align(src, ref, src_normals, ref_normals, params=params, **kwargs)
            rec = record(a, np.asarray(gt)[:3], **job.meta, **extra, seconds=time.perf_counter() - t0)
            f.write(json.dumps(rec) + "\n")
            f.flush()
            out.append(rec)
    return out


def collect(ds, indices, params, path: str, progress: bool = True, **meta) -> list:
    """:func:`collect_jobs` on pairs ``indices`` of dataset ``ds`` (``align`` at the dataset's number of points,
    with its normals)."""

    def job(i):
        def load():
            d = ds[i]
            s, r = np.asarray(d["points_src"], np.float64), np.asarray(d["points_ref"], np.float64)
            network = options.NetworkOptions(points=max(len(s), len(r)))
            return (s[:, :3], r[:, :3], s[:, 3:6], r[:, 3:6], d["transform_gt"], {"network_options": network},
                    {"label": ds.class_names[int(d["label"])]})

        return Job({**meta, "protocol": ds.protocol, "rot_mag": float(ds.rot_mag), "idx": i}, load)

    indices = [int(i) for i in indices]
    return collect_jobs(map(job, indices), params, path, progress=progress, total=len(indices),
                        desc=str(meta.get("setting", "")))
