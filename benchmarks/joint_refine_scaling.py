"""How joint refinement (:func:`rpmnet_jax.pose_graphs.joint_refine.refine_jointly`) grows with the number of scans:
time and peak memory of its sparse normal equations, beside the dense (6S × 6S) solve it replaced.

    python benchmarks/joint_refine_scaling.py [--sizes 100,300,1000] [--dense-sizes 100,300] [--points 500]
        [--host-busy] [--out-jsonl results.jsonl]

Synthetic scans on a path: patches of one bumpy height field along a strip, each ``--points`` points (1 × 1 in
the field's units, a step of 0.4 apart), in its own frame (a random pose), each scan paired with its next two
(pairs = 2S − 3), the poses perturbed by 0.5° (about each patch's centre) and 0.01, scan 0 the anchor. Per size
and solver one JSON line: ``seconds`` of the whole refinement (no tracing), ``solve_seconds`` of its linear solves
alone, the iterations, ``peak_mb``: the tracemalloc peak of one Gauss–Newton step (correspondences, normal
equations, solve; every step allocates the same), ``lu_nnz``: the non-zeros of the sparse LU factors (SuperLU
allocates them outside tracemalloc's view: 12 bytes each), the worst rotation error before and after, and the
worst after between neighbouring scans. The dense rows also give their poses' largest difference from the sparse
ones (rotation in radians; translation over the scans' radius). The dense baseline lives here only: the same
blocks written into a ``(6S, 6S)`` array and solved by ``np.linalg.solve``, as the module did before.
``--host-busy`` records that other work shared the CPUs (the times are then rough; the memory is not affected).
"""

from __future__ import annotations

import argparse
import datetime
import os
import sys
import time
import tracemalloc
from unittest import mock

import numpy as np

import bench_utils

STEP = 0.4  # between neighbouring patches' centres; a patch is 1 × 1, so the next two overlap it
MAX_DISTANCE = 0.03  # twice the start's largest displacement (0.016); 500 points a patch lie 0.045 apart (0.05 at
# 300 points: worst scan of 100 at 0.12 deg after against 0.09 deg here, 0.15: worse than the start at its first gate)


def height(xy, waves):
    """``(z (N,), dz/dxy (N, 2))`` of the field ``Σ a sin(k · xy + φ)`` at ``xy (N, 2)``; ``waves (W, 4)``:
    ``(a, kx, ky, φ)``."""
    phase = xy @ waves[:, 1:3].T + waves[:, 3]  # (N, W)
    return np.sin(phase) @ waves[:, 0], (np.cos(phase) * waves[:, 0]) @ waves[:, 1:3]


def site(num_scans: int, points: int, seed: int = 0):
    """``(scans, truth (S, 4, 4), start (S, 4, 4), pairs)``: patches of one height field along a strip, each in
    its own frame (truth: scan → field), the start perturbed by 0.5° about each patch's centre and moved by 0.01
    (but scan 0)."""
    from rpmnet_jax.ops import se3
    from rpmnet_jax.pair_edges import edges

    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(seed)
    wavelengths = rng.uniform(0.3, 1.5, 8)
    angles = rng.uniform(0, np.pi, 8)
    waves = np.stack([rng.uniform(0.02, 0.06, 8), 2 * np.pi / wavelengths * np.cos(angles),
                      2 * np.pi / wavelengths * np.sin(angles), rng.uniform(0, 2 * np.pi, 8)], axis=1)
    scans, truth, start = [], np.tile(np.eye(4), (num_scans, 1, 1)), np.tile(np.eye(4), (num_scans, 1, 1))
    for s in range(num_scans):
        xy = rng.uniform(-0.5, 0.5, (points, 2)) + [s * STEP, 0.0]
        z, grad = height(xy, waves)
        world = np.concatenate([xy, z[:, None]], axis=1)
        normals = np.concatenate([-grad, np.ones((points, 1))], axis=1)
        normals /= np.linalg.norm(normals, axis=1, keepdims=True)
        truth[s, :3, :3] = Rotation.from_rotvec(rng.normal(size=3) * 0.5).as_matrix()
        truth[s, :3, 3] = world.mean(axis=0) + rng.normal(size=3) * 0.1
        own = np.linalg.inv(truth[s])
        scans.append(edges.make_scan(se3.apply(own, world), se3.rotate(own, normals)))
        step = np.eye(4)  # about the patch's centre
        if s:
            centre = world.mean(axis=0)
            step[:3, :3] = Rotation.from_rotvec(_unit(rng.normal(size=3)) * np.radians(0.5)).as_matrix()
            step[:3, 3] = centre - step[:3, :3] @ centre + _unit(rng.normal(size=3)) * 0.01
        start[s] = step @ truth[s]
    pairs = [(i, j) for i in range(num_scans) for j in (i + 1, i + 2) if j < num_scans]
    return scans, truth, start, pairs


def _unit(v):
    return v / np.linalg.norm(v)


def rotation_errors(poses, truth):
    """``(S,)`` radians: each pose's rotation against the truth's (``atan2(sin, cos)``: exact near 0)."""
    rel = np.einsum("sji,sjk->sik", poses[:, :3, :3], truth[:, :3, :3])
    sin = 0.5 * np.linalg.norm(np.stack([rel[:, 2, 1] - rel[:, 1, 2], rel[:, 0, 2] - rel[:, 2, 0],
                                         rel[:, 1, 0] - rel[:, 0, 1]], axis=1), axis=1)
    return np.arctan2(sin, (np.trace(rel, axis1=1, axis2=2) - 1) / 2)


def neighbour_errors(poses, truth):
    """``(S − 1,)`` radians: the rotation error of each scan relative to the next one (what a path without a loop
    closure fixes; the absolute error adds them up along it)."""
    return rotation_errors(np.linalg.inv(poses[:-1]) @ poses[1:], np.linalg.inv(truth[:-1]) @ truth[1:])


def dense_twists(blocks, g, used):
    """The replaced solve: ``blocks`` written into the whole ``(6S, 6S)`` matrix, cut to ``used``, damped, solved
    densely: ``(U, 6)``."""
    from rpmnet_jax.pose_graphs import joint_refine

    h = _dense_matrix(blocks, len(g))
    cols = np.concatenate([np.arange(6 * s, 6 * s + 6) for s in used])
    a = h[np.ix_(cols, cols)]
    a[np.diag_indices_from(a)] += joint_refine.DAMPING * max(np.trace(a) / len(a), 1e-12)
    return np.linalg.solve(a, -g.reshape(-1)[cols]).reshape(-1, 6)


def _dense_matrix(blocks, num_scans):
    """``(6S, 6S)``, as the module's dense normal equations returned it."""
    h = np.zeros((num_scans, num_scans, 6, 6))
    for (i, j), block in blocks.items():
        h[i, j] = block
    return h.transpose(0, 2, 1, 3).reshape(6 * num_scans, 6 * num_scans)


def measure(scans, truth, start, pairs, dense: bool) -> dict:
    """One solver's run: timed refinement, then one traced step; ``poses`` kept for the comparison."""
    from scipy.sparse import linalg as sparse_linalg

    from rpmnet_jax.pose_graphs import joint_refine

    solve = dense_twists if dense else joint_refine._twists
    solve_seconds, factored = [0.0], []

    def timed_solve(*args):
        t0 = time.perf_counter()
        out = solve(*args)
        solve_seconds[0] += time.perf_counter() - t0
        return out

    def kept_splu(a, *args, **kwargs):
        factored[:] = [a]
        return splu(a, *args, **kwargs)

    splu = sparse_linalg.splu
    with mock.patch.object(joint_refine, "_twists", timed_solve):
        t0 = time.perf_counter()
        out = joint_refine.refine_jointly(scans, start, pairs, MAX_DISTANCE, anchor=0)
        seconds = time.perf_counter() - t0
    with mock.patch.object(joint_refine, "_twists", solve), mock.patch.object(sparse_linalg, "splu", kept_splu):
        tracemalloc.start()
        tracemalloc.reset_peak()
        joint_refine.refine_jointly(scans, start, pairs, MAX_DISTANCE, anchor=0, gates=(1.0,), max_iterations=1)
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
    lu = splu(factored[0]) if factored else None
    return {"impl": "dense" if dense else "sparse", "scans": len(scans), "pairs": len(pairs),
            "seconds": round(seconds, 3), "solve_seconds": round(solve_seconds[0], 4),
            "iterations": out.iterations, "converged": out.converged,
            "seconds_per_iteration": round(seconds / max(out.iterations, 1), 4),
            "peak_mb": round(peak / 2**20, 2), "lu_nnz": None if lu is None else int(lu.L.nnz + lu.U.nnz),
            "rotation_error_deg_before": round(float(np.degrees(rotation_errors(start, truth).max())), 4),
            "rotation_error_deg_after": round(float(np.degrees(rotation_errors(out.poses, truth).max())), 4),
            "neighbour_rotation_error_deg_after": round(float(np.degrees(neighbour_errors(out.poses, truth).max())), 4),
            "poses": out.poses}


def differences(poses, reference, scans) -> dict:
    """Largest rotation (radians) and translation (over the scans' radius) between two sets of poses."""
    from rpmnet_jax.ops import se3

    placed = np.concatenate([se3.apply(p, s.points) for p, s in zip(reference, scans)])
    radius = float(np.max(np.linalg.norm(placed - placed.mean(axis=0), axis=1)))
    return {"max_rotation_difference_rad": float(rotation_errors(poses, reference).max()),
            "max_translation_difference_rel": float(np.abs(poses[:, :3, 3] - reference[:, :3, 3]).max() / radius)}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--sizes", default="100,300,1000", help="scans per run, comma-separated")
    p.add_argument("--dense-sizes", default="100,300", help="the sizes also run with the dense solve")
    p.add_argument("--points", type=int, default=500, help="points per scan")
    p.add_argument("--host-busy", action="store_true", help="other work shared the CPUs: the times are rough")
    p.add_argument("--out-jsonl", help="also append the lines to this file")
    a = p.parse_args(argv)
    import scipy

    args = sys.argv[1:] if argv is None else list(argv)
    if "--out-jsonl" in args:
        del args[args.index("--out-jsonl"):args.index("--out-jsonl") + 2]
    common = {"date": datetime.date.today().isoformat(), "commit": bench_utils.commit(),
              "cpu": bench_utils.cpu_model(), "cpus": bench_utils.available_cpus(), "host_busy": a.host_busy,
              "load_average": round(os.getloadavg()[0], 2), "numpy": np.__version__, "scipy": scipy.__version__,
              "command": " ".join(["python", "benchmarks/joint_refine_scaling.py",
                                   *(x for x in args if not x.startswith("--out-jsonl="))]),
              "points_per_scan": a.points}
    dense_sizes = {int(s) for s in a.dense_sizes.split(",") if s}
    for num_scans in (int(s) for s in a.sizes.split(",")):
        scans, truth, start, pairs = site(num_scans, a.points)
        sparse_run = measure(scans, truth, start, pairs, dense=False)
        sparse_poses = sparse_run.pop("poses")
        bench_utils.emit(dict(common, **sparse_run), a.out_jsonl)
        if num_scans in dense_sizes:
            dense_run = measure(scans, truth, start, pairs, dense=True)
            diff = differences(sparse_poses, dense_run.pop("poses"), scans)
            bench_utils.emit(dict(common, **dense_run, **diff), a.out_jsonl)
    return 0


if __name__ == "__main__":
    sys.exit(main())
