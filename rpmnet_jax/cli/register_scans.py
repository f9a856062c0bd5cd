"""``rpmnet-register-scans SCAN1 SCAN2 ... | FOLDER --out-poses poses.conf``: register many scans into the frame
of the first one (:func:`rpmnet_jax.align_scans`) and write their poses as a Stanford ``.conf``.

A folder stands for its point-cloud files (sorted by name). ``poses.conf`` has one line
``bmesh NAME tx ty tz qx qy qz qw`` per placed scan (NAME its file name; world point = ``p @ R + t`` for a row
vector ``p`` with ``R`` the quaternion's matrix, as the Stanford ``bun.conf``); the first placed scan is the
identity. A scan that overlaps none of the placed scans is reported and left out of the outputs.

An E57 file with several scans is a scan set: each scan is named by its own name (when the names are unique
and have no spaces) or ``FILE.e57#i``; scans with stored poses start from them (each moved into the file's
frame first), and the poses written are then scan -> the file's frame, the first scan keeping its stored pose.

Exit codes: 0 success, 1 a Dask run that cannot finish (a task that kills the workers running it, or no
worker left for a minute: one line; ``--cache`` keeps the pairs that finished), 2 bad input or arguments (one-line
message, nothing written).
"""

from __future__ import annotations

import argparse
import os
import sys
import typing
import warnings

from rpmnet_jax.cli import runtime

PROG = "rpmnet-register-scans"


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=PROG, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("scans", nargs="+", help="scan files (.ply .pcd .xyz .txt .csv .npy .npz .las .laz .e57) or "
                   "folders of them; an E57 file with several scans gives each of them")
    p.add_argument("--out-poses", required=True, help="write the poses as a Stanford .conf")
    p.add_argument("--out-merged", default=None,
                   help="write all placed scans in the common frame as one cloud (float64; format from the extension)")
    p.add_argument("--merged-voxel", type=float, default=None,
                   help="voxel-downsample the merged cloud to this size (scans' units; default: every point, with "
                        "the scans' colours and intensity when every scan has them)")
    p.add_argument("--columns", default=None,
                   help="what the columns of every scan file are, by position, e.g. x,y,z,r,g,b (names: x y z nx ny "
                        "nz r g b or red green blue, intensity, _ to skip); default: the files' own names")
    p.add_argument("--plot", default=None, help="PNG of the merged scans, one colour per scan")
    p.add_argument("--html", default=None, help="self-contained page: the placed scans in 3-D, one colour per scan "
                   "(turn, zoom), beside the poses and edges; opens offline")
    p.add_argument("--checkpoint", default=None,
                   help="orbax training dir, .npz or official .pth (default: the shipped model)")
    p.add_argument("--voxel-size", type=float, default=None,
                   help="registration voxel size in the scans' units (default: 2%% of the median scan radius for "
                        "objects, 1%% for scans seen from inside a scene: LiDAR sweeps, scanner stations); every "
                        "other size is a multiple of it")
    p.add_argument("--refine-voxel-size", type=float, default=None,
                   help="refine on the scans prepared again at this voxel (scans' units; default the registration "
                        "voxel): a finer one makes a scene's poses more precise")
    p.add_argument("--max-correspondence-distance", type=float, default=None,
                   help="inlier threshold in the scans' units (default: 2.5 voxels)")
    p.add_argument("--viewpoints", choices=("auto", "origin", "none"), default="auto",
                   help="where each scan's sensor stood (estimated normals face it): auto (default: a scan's frame "
                        "origin when the scan surrounds it, as a LiDAR sweep or a scanner station in its own frame "
                        "does), origin (every scan is in its sensor's frame), none (objects: normals face away "
                        "from each scan's centre). An E57 scan with a stored pose, or a PCD with a VIEWPOINT, has "
                        "its sensor there")
    p.add_argument("--refine", choices=("joint", "icp", "none"), default="joint",
                   help="the final refinement over every overlapping pair: all poses together on the pairs' points "
                        "(joint, default), rounds of pairwise ICP edges in a pose graph (icp), or none")
    p.add_argument("--seed", type=int, default=0, help="seed of the samplings")
    p.add_argument("--scheduler", default=None,
                   help="run the work on scans and pairs on Dask: 'local' (or a worker count) for worker processes on "
                        "this machine, tcp://HOST:8786 for a running scheduler (default: in this process)")
    p.add_argument("--cache", default=None, metavar="DIR",
                   help="keep every finished pair result in DIR; a run again with the same DIR reuses them "
                        "(a killed run resumes; a changed scan's pairs are computed again)")
    p.add_argument("--quiet", action="store_true", help="no progress bars (there are none when stderr is not a "
                   "terminal either)")
    return p


def _scan_paths(args) -> list:
    from rpmnet_jax.io import clouds as cloud_io

    paths = []
    for arg in args:
        if os.path.isdir(arg):
            found = sorted(os.path.join(arg, f) for f in os.listdir(arg)
                           if os.path.splitext(f)[1].lower() in cloud_io.FORMATS)
            if not found:
                raise ValueError(f"{arg}: no point-cloud files ({', '.join(cloud_io.FORMATS)}) in this folder")
            paths += found
        else:
            paths.append(arg)
    return paths


def _read_scans(paths: list, columns) -> tuple:
    """``(labels, clouds, stored poses (4, 4) or None, notes)``: one scan per file, or per scan of a multi-scan E57
    file (label ``FILE.e57#i`` or the scan's name), moved by its stored pose when it has one."""
    import numpy as np

    from rpmnet_jax.io import clouds as cloud_io, e57

    labels, clouds, stored, notes = [], [], [], []
    for path in paths:
        scans = e57.read_scans(path) if path.lower().endswith(".e57") and columns is None else []
        if len(scans) < 2:
            labels.append(path)
            clouds.append(cloud_io.read(path, columns=columns))
            stored.append(None)
            continue
        names = [s.name for s in scans]
        usable = len(set(names)) == len(names) and all(n and n.split() == [n] and "/" not in n for n in names)
        labels += [os.path.join(os.path.dirname(path), n) if usable else f"{path}#{i}" for i, n in enumerate(names)]
        clouds += [s.cloud if s.pose is None else s.cloud.moved(s.pose) for s in scans]
        stored += [s.pose for s in scans]
        posed = sum(s.pose is not None for s in scans)
        if posed:
            notes.append(f"{os.path.basename(path)}: {posed} of {len(scans)} scans have stored poses; starting from "
                         "them (poses written in the file's frame)")
    if len(labels) < 2:
        raise ValueError(f"need at least two scans, got {len(labels)}")
    names = [os.path.basename(p) for p in labels]
    repeated = sorted({n for n in names if names.count(n) > 1})
    if repeated:
        raise ValueError(f"duplicate scan names {repeated}: the .conf names scans by file name; rename them")
    return labels, clouds, stored, notes


def _viewpoints(scans: "_Scans", rule: str) -> list:
    """Per scan: its stored pose's origin (an E57 scan moved into the file's frame: the scanner stood there), else
    the viewpoint its file gives (a PCD's ``VIEWPOINT``), else ``rule``."""
    import numpy as np

    return [np.asarray(pose, np.float64)[:3, 3] if pose is not None
            else (rule if c.viewpoint is None else c.viewpoint) for pose, c in zip(scans.stored, scans.clouds)]


def _engine(args) -> tuple:
    """``(scheduler, PairCache or None)`` of ``--scheduler`` and ``--cache``, checked before anything runs."""
    from rpmnet_jax.pair_edges import pair_cache, pair_engine

    try:
        scheduler = pair_engine.check_scheduler(args.scheduler)
    except ValueError:
        raise ValueError(f"--scheduler must be 'local', a worker count >= 1 or a scheduler address like "
                         f"tcp://HOST:8786, got {args.scheduler!r}") from None
    return scheduler, pair_cache.PairCache(args.cache) if args.cache else None


def main(argv=None) -> int:
    """Read → align → write → report; ``0``, or ``2`` (bad input: one line, nothing written), ``1`` (a pair task
    that kills its workers, or no Dask worker left)."""
    args = _parser().parse_args(argv)
    from rpmnet_jax import stopwatch
    from rpmnet_jax.pair_edges import pair_engine

    clock = stopwatch.Stopwatch()
    try:
        scheduler, cache = _check_outputs(args)
        scans = _read(args)
        t_read = clock.elapsed()
        result, caught = _align(args, scans, scheduler, cache)
    except (ValueError, OSError) as e:  # bad input, or a file that is missing, a folder, or unreadable
        print(f"{PROG}: error: {e}", file=sys.stderr)
        return 2
    except pair_engine.PairTaskError as e:  # a pair that kills the workers running it, or no worker left
        print(f"{PROG}: error: {e}", file=sys.stderr)
        return 1
    _say(scans, result, caught, clock.elapsed(), t_read)
    if cache is not None:
        print(f"cache {args.cache}: {cache.reused} pair results reused, {cache.written} computed and written")
    moved = _write(args, scans, result)
    if args.plot:
        from rpmnet_jax.cli import plots
        plots.plot_scans(args.plot, {"registered scans": [moved.get(s) for s in range(len(scans.names))]},
                         scans.names)
    if args.html:
        from rpmnet_jax.report import pages
        pages.scans_report(args.html, [moved.get(s) for s in range(len(scans.names))], scans.names,
                           _report_numbers(result, scans.names, scans.clouds, clock.elapsed()),
                           alerts=_alerts(result, scans.names))
    return 0


class _Scans(typing.NamedTuple):
    names: list  # file names (a multi-scan E57's scans: their own names or FILE.e57#i)
    clouds: list  # io.columns.Cloud of each scan, in a multi-scan E57 file's frame when it has poses
    stored: list  # (4, 4) each scan's stored pose, or None
    notes: list  # lines to print


def _check_outputs(args) -> tuple:
    """Every output path and option checked before anything is read: ``(scheduler, PairCache or None)``."""
    from rpmnet_jax.io import clouds as cloud_io

    if args.plot:
        from rpmnet_jax.cli import plots
        plots.check_available()
    if args.html:
        from rpmnet_jax.report import pages
        pages.check_path(args.html)
    runtime.check_outputs(args.out_poses, args.out_merged, args.plot, args.html)
    engine = _engine(args)
    if args.out_merged:
        cloud_io.check_format(args.out_merged)
    if args.merged_voxel is not None and not args.merged_voxel > 0:
        raise ValueError(f"--merged-voxel must be > 0, got {args.merged_voxel}")
    return engine


def _read(args) -> _Scans:
    """The scans of the command line, and a model to register them with."""
    from rpmnet_jax.weights import loading

    paths, clouds, stored, notes = _read_scans(_scan_paths(args.scans), args.columns)
    if args.checkpoint is None and not loading.has_default():
        raise ValueError("no shipped model in this install; pass --checkpoint")
    return _Scans([os.path.basename(p) for p in paths], clouds, stored, notes)


def _align(args, scans: _Scans, scheduler, cache) -> tuple:
    """:func:`rpmnet_jax.align_scans` with progress bars: ``(ScanAlignment, the warnings it gave)``."""
    from rpmnet_jax.multiway import options as options_lib, scan_alignment

    options = options_lib.ScanOptions(voxel_size=args.voxel_size, refine=args.refine, seed=args.seed,
                                      max_correspondence_distance=args.max_correspondence_distance,
                                      refine_voxel_size=args.refine_voxel_size)
    bars = runtime.ProgressBars(args.quiet)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            result = scan_alignment.align_scans([c.points for c in scans.clouds], [c.normals for c in scans.clouds],
                                                options=options, viewpoints=_viewpoints(scans, args.viewpoints),
                                                checkpoint=args.checkpoint, progress=bars, scheduler=scheduler,
                                                cache=cache)
        finally:
            bars.close()
    return result, caught


def _say(scans: _Scans, result, caught, seconds: float, t_read: float) -> None:
    """The notes, warnings (scans flagged or left out, by name), the poses table and the times, on the terminal."""
    import numpy as np

    from rpmnet_jax.multiway import scan_alignment
    from rpmnet_jax.ops import se3
    from rpmnet_jax.report import formats

    names = scans.names
    for note in scans.notes:
        print(note)
    for w in caught:
        if not issubclass(w.category, scan_alignment.LeftOutWarning):  # said below, by name
            print(f"{PROG}: warning: {w.message}", file=sys.stderr)
    for s in result.likely_wrong:
        print(f"{PROG}: warning: {names[s]} was placed by a registration flagged likely wrong (p_wrong at or above "
              "the threshold); check its pose", file=sys.stderr)
    for s in result.left_out:
        print(f"{PROG}: warning: {names[s]} overlaps none of the placed scans; left out of the outputs",
              file=sys.stderr)
    print(f"{'scan':<24} {'rotation deg':>12} {'translation':>12} {'edges':>5}")
    for s in _placed(result, names):
        degree = sum(s in (e.source, e.target) for e in result.edges)
        print(f"{names[s]:<24} {formats.number(se3.rotation_angle_deg(result.poses[s, :3, :3])):>12} "
              f"{formats.number(np.linalg.norm(result.poses[s, :3, 3])):>12} {degree:>5}")
    for e in result.rejected:
        print(f"rejected edge {names[e.source]} -> {names[e.target]} ({e.stage}, fitness {formats.number(e.fitness)})")
    stages = "  ".join(f"{k} {v:.2f}" for k, v in result.timings.items() if k != "total")
    print(f"{len(result.edges)} edges, {len(result.rejected)} rejected; voxel {formats.number(result.voxel_size)}, "
          f"max_correspondence_distance {formats.number(result.max_correspondence_distance)}; time {seconds:.2f} s "
          f"(read {t_read:.2f}  {stages})")


def _alerts(result, names) -> list:
    """The page's banner: the scans resting on a likely wrong registration, the kept edges flagged likely wrong,
    the scans left out."""
    from rpmnet_jax.multiway import edge_doubt
    from rpmnet_jax.report import alerts

    bar = edge_doubt.load().threshold
    return alerts.scans([names[s] for s in result.likely_wrong], [names[s] for s in result.left_out],
                        [(names[e.source], names[e.target], e.p_wrong) for e in result.edges if e.p_wrong >= bar])


def _placed(result, names) -> list:
    return [s for s in range(len(names)) if s not in result.left_out]


def _write(args, scans: _Scans, result) -> dict:
    """The poses (``.conf``) and, with ``--out-merged``, the placed scans as one cloud (every finite row, its
    normals, colours and intensity when every placed scan has them): ``{scan: (N_s, 3) moved points}``."""
    import numpy as np

    from rpmnet_jax.geometry import sampling
    from rpmnet_jax.io import clouds as cloud_io, poses as poses_io

    placed, clouds = _placed(result, scans.names), scans.clouds
    poses_io.write_poses(args.out_poses, [scans.names[s] for s in placed],
                         [result.poses[s] @ (np.eye(4) if scans.stored[s] is None else scans.stored[s])
                          for s in placed])
    finite = {s: np.all(np.isfinite(clouds[s].points), axis=1) for s in placed}  # rows align_scans dropped too
    moved = {s: clouds[s].points[finite[s]] @ result.poses[s, :3, :3].T + result.poses[s, :3, 3] for s in placed}
    if not args.out_merged:
        return moved
    points, normals = np.concatenate([moved[s] for s in placed]), None
    if all(clouds[s].normals is not None for s in placed):
        normals = np.concatenate([clouds[s].normals[finite[s]] @ result.poses[s, :3, :3].T for s in placed])
        normals = normals if np.all(np.isfinite(normals)) else None
    extras = {k: np.concatenate([getattr(clouds[s], k)[finite[s]] for s in placed])
              for k in ("colours", "intensity") if all(getattr(clouds[s], k) is not None for s in placed)}
    if args.merged_voxel:
        points, normals = sampling.voxel_downsample(points, normals, args.merged_voxel)
        extras = {}  # one point per voxel: colours and intensity are not averaged
    cloud_io.write_cloud(args.out_merged, points, normals, **extras)
    return moved


def _report_numbers(result, names, clouds, seconds: float) -> dict:
    """What the ``--html`` page shows beside the scans."""
    import numpy as np

    from rpmnet_jax.ops import se3

    placed = [s for s in range(len(names)) if s not in result.left_out]

    def edges(found):
        return [{"source": names[e.source], "target": names[e.target], "stage": e.stage, "fitness": e.fitness,
                 "inlier RMSE": e.inlier_rmse, "p_wrong": e.p_wrong} for e in found]
    scans = [{"scan": names[s], "points": len(clouds[s].points),
              "rotation (deg)": float(se3.rotation_angle_deg(result.poses[s, :3, :3])),
              "translation": float(np.linalg.norm(result.poses[s, :3, 3])),
              "edges": sum(s in (e.source, e.target) for e in result.edges)} for s in placed]
    return {"scans placed": f"{len(placed)} of {len(names)}",
            "left out (overlap none of the placed)": ", ".join(names[s] for s in result.left_out) or "none",
            "edges": len(result.edges), "rejected edges": len(result.rejected), "voxel": result.voxel_size,
            "correspondence distance": result.max_correspondence_distance, "time (s)": round(seconds, 2),
            "scans": scans, "poses (scan onto the first scan's frame)": {names[s]: result.poses[s] for s in placed},
            "pose-graph edges": edges(result.edges) or "none", "rejected": edges(result.rejected) or "none"}


def entry() -> None:
    """Console script ``rpmnet-register-scans``."""
    runtime.run(main)


if __name__ == "__main__":
    entry()
