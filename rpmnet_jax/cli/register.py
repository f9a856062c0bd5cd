"""``rpmnet-register SRC REF``: align two point-cloud files with RPM-Net and write the transform.

Exit codes: 0 success, 2 bad input or arguments (one-line message, nothing written).
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings

from rpmnet_jax.cli import runtime


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="rpmnet-register", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("src", help="source cloud (.ply .pcd .xyz .txt .csv .npy .npz .las .laz .e57), moved onto the "
                   "reference")
    p.add_argument("ref", help="reference cloud")
    p.add_argument("--checkpoint", default=None,
                   help="orbax training dir, .npz or official .pth (default: the shipped model)")
    p.add_argument("--out-transform", default=None, help="write the 4x4 transform (.txt or .json)")
    p.add_argument("--out-aligned", default=None, help="write the aligned source (format from the extension)")
    p.add_argument("--out-candidates", default=None,
                   help="write the distinct answers, best first, with their scores and the information matrix (.json)")
    p.add_argument("--plot", default=None, help="PNG with source, reference and aligned source in 3-D")
    p.add_argument("--html", default=None, help="self-contained page: the clouds in 3-D (turn, zoom; before / "
                   "after) beside the numbers; opens offline")
    p.add_argument("--num-points", type=int, default=1024, help="points per cloud fed to the model (default 1024)")
    p.add_argument("--iters", type=int, default=5, help="registration iterations (default 5)")
    p.add_argument("--sampling", choices=("random", "fps"), default="random", help="downsampling method")
    p.add_argument("--seed", type=int, default=0, help="seed of the downsampling")
    p.add_argument("--centering", choices=("separate", "common"), default="separate",
                   help="centre each cloud on its own centroid (default) or both on their joint centroid")
    p.add_argument("--estimate-normals", action="store_true", help="re-estimate normals even if the files have them")
    p.add_argument("--viewpoints", choices=("auto", "origin", "none"), default="auto",
                   help="where each cloud's sensor stood (estimated normals face it; with both known, an answer that "
                        "puts one cloud where the other's sensor saw through loses): auto (default: the frame origin "
                        "when both clouds look taken from it), origin (each cloud is in its sensor's frame), none "
                        "(objects). A PCD with a VIEWPOINT has its sensor there (the other cloud then follows this "
                        "rule as rpmnet-register-scans applies it to one scan)")
    p.add_argument("--columns", default=None,
                   help="what the columns of the input files are, by position, e.g. x,y,z,r,g,b (names: x y z nx ny nz "
                        "r g b or red green blue, intensity, _ to skip); default: the files' own names (PLY, PCD, a "
                        "text header), else 3 columns x y z, 4 x y z intensity, 6 x y z and unit normals")
    p.add_argument("--ref-columns", default=None, help="the reference's columns when they differ from --columns")
    p.add_argument("--init", choices=("auto", "local", "global", "classical"), default="auto",
                   help="starts: auto (FPFH + RANSAC hypotheses; the network from the identity when the best "
                        "fits poorly or is ambiguous, its global search when still none fits well; default), "
                        "local (the network from the identity), "
                        "global (the network from rotations covering every orientation, plus the hypotheses), "
                        "classical (the hypotheses alone, no network)")
    p.add_argument("--refine", choices=("icp", "none"), default="icp",
                   help="robust point-to-plane ICP on denser samples (default), or none (the winning start as it is; "
                        "with --init local the raw network)")
    p.add_argument("--max-correspondence-distance", type=float, default=None,
                   help="inlier threshold in the clouds' units (default: 5%% of the clouds' radius)")
    p.add_argument("--low-fitness", type=float, default=0.3,
                   help="warn when the fitness of the answer is below this (default 0.3)")
    return p


def main(argv=None) -> int:
    args = _parser().parse_args(argv)
    from rpmnet_jax.cli import plots
    from rpmnet_jax.io import clouds as cloud_io
    from rpmnet_jax.ops import se3
    from rpmnet_jax.pairwise import alignment as align_lib, options
    from rpmnet_jax.report import alerts, formats, pages
    from rpmnet_jax.weights import loading

    try:
        if args.plot:
            plots.check_available()
        if args.html:
            pages.check_path(args.html)
        runtime.check_outputs(args.out_transform, args.out_aligned, args.plot, args.out_candidates, args.html)
        if args.out_candidates and not args.out_candidates.lower().endswith(".json"):
            raise ValueError(f"--out-candidates must name a .json file, got {args.out_candidates}")
        if args.out_aligned:
            cloud_io.check_format(args.out_aligned)
        source = cloud_io.read(args.src, columns=args.columns)  # colours and intensity go to --out-aligned
        src, src_n = source.points, source.normals
        ref_columns = args.columns if args.ref_columns is None else args.ref_columns
        target = cloud_io.read(args.ref, columns=ref_columns)
        ref, ref_n = target.points, target.normals
        stored = [c.viewpoint for c in (source, target)]  # a PCD's VIEWPOINT; else the rule of --viewpoints
        viewpoints = args.viewpoints if all(v is None for v in stored) else tuple(
            args.viewpoints if v is None else v for v in stored)
        if args.checkpoint is None and not loading.has_default():
            raise ValueError("no shipped model in this install; pass --checkpoint")
        t0 = time.time()
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            network = options.NetworkOptions(points=args.num_points, iters=args.iters, sampling=args.sampling,
                                             centering=args.centering)
            result = align_lib.align(src, ref, src_n, ref_n, checkpoint=args.checkpoint, seed=args.seed,
                                     init=args.init, refine=args.refine, network_options=network,
                                     reestimate_normals=args.estimate_normals, viewpoints=viewpoints,
                                     max_correspondence_distance=args.max_correspondence_distance)
        seconds = time.time() - t0
    except (ValueError, OSError) as e:  # bad input, or a file that is missing, a folder, or unreadable
        print(f"rpmnet-register: error: {e}", file=sys.stderr)
        return 2
    for w in caught:
        print(f"rpmnet-register: warning: {w.message}", file=sys.stderr)
    n = formats.number  # as the --html page writes them
    print(formats.matrix(result.transform))
    print(f"fitness {n(result.fitness)}  inlier_rmse {n(result.inlier_rmse)}  "
          f"max_correspondence_distance {n(result.max_correspondence_distance)}  start {result.init}  "
          f"icp_iterations {result.num_iterations}{'' if result.converged else ' (not converged)'}")
    stages = "  ".join(f"{k} {n(v)}" for k, v in result.timings.items() if k != "total")
    print(f"confidence {n(result.confidence)}  p_wrong {n(result.p_wrong)}  points {result.num_points[0]}/"
          f"{result.num_points[1]}  time {n(seconds)} s ({stages})")
    if result.fitness < args.low_fitness:
        print(f"rpmnet-register: warning: low fitness {n(result.fitness)}: only this share of the source has a "
              "reference point within the correspondence distance; the answer is likely wrong (try --init global, "
              "or a larger --max-correspondence-distance if the clouds are sparse or noisy)", file=sys.stderr)
    if result.ambiguous:
        second = result.candidates[1]
        angle = float(se3.rotation_angle_deg(second.transform[:3, :3] @ result.transform[:3, :3].T))
        print(f"rpmnet-register: warning: ambiguous: another answer {angle:.0f} deg away scores "
              f"{n(second.score / result.candidates[0].score)} of the best ({len(result.candidates)} distinct "
              "answers); the shape may fit itself in several poses (symmetric), so the answer may be any of them"
              f"{'' if args.out_candidates else ' (--out-candidates writes them)'}", file=sys.stderr)
    if result.likely_wrong:
        print(f"rpmnet-register: warning: likely wrong: p_wrong {n(result.p_wrong)} (the calibrated probability "
              "that the rotation is more than 5 deg off); check the answer (--html shows it), or try --init global",
              file=sys.stderr)
    if args.out_candidates:
        cloud_io.write_candidates(args.out_candidates, result.candidates, result.information,
                                  ambiguous=result.ambiguous, p_wrong=result.p_wrong,
                                  likely_wrong=result.likely_wrong)
    if args.out_transform:
        cloud_io.write_transform(args.out_transform, result.transform, confidence=result.confidence,
                                 fitness=result.fitness, inlier_rmse=result.inlier_rmse, start=result.init,
                                 max_correspondence_distance=result.max_correspondence_distance,
                                 timings=result.timings, p_wrong=result.p_wrong, likely_wrong=result.likely_wrong)
    if args.out_aligned:  # row for row as the source file (NaN rows stay NaN)
        aligned_n = None if src_n is None else src_n @ result.transform[:3, :3].T
        cloud_io.write_cloud(args.out_aligned, result.aligned, aligned_n, source.colours, source.intensity)
    if args.plot:
        plots.plot_alignment(args.plot, src, ref, result.aligned)
    if args.html:
        pages.pair_report(args.html, src, ref, result.aligned, _report_numbers(args, result, seconds),
                          alerts=alerts.pair(result.fitness, args.low_fitness, result.p_wrong, result.likely_wrong,
                                             result.ambiguous))
    return 0


def _report_numbers(args, result, seconds: float) -> dict:
    """What the ``--html`` page shows beside the clouds."""
    import os

    from rpmnet_jax.ops import se3

    best = result.candidates[0] if result.candidates else None
    candidates = [{"init": c.init, "deg from best": float(se3.rotation_angle_deg(c.transform[:3, :3] @
                                                                                  best.transform[:3, :3].T)),
                   "score / best": c.score / best.score if best.score else float("nan"), "fitness": c.fitness,
                   "inlier RMSE": c.inlier_rmse} for c in result.candidates]
    return {"source": os.path.basename(args.src), "reference": os.path.basename(args.ref),
            "transform (source onto reference)": result.transform, "fitness": result.fitness,
            "inlier RMSE": result.inlier_rmse, "correspondence distance": result.max_correspondence_distance,
            "init": result.init, "ICP iterations": f"{result.num_iterations}"
                                                    f"{'' if result.converged else ' (not converged)'}",
            "confidence": result.confidence, "points used": f"{result.num_points[0]} / {result.num_points[1]}",
            "time (s)": seconds, "ambiguous": result.ambiguous, "p_wrong": result.p_wrong,
            "likely wrong": result.likely_wrong, "candidates": candidates}


def entry() -> None:
    """Console script ``rpmnet-register``."""
    runtime.run(main)


if __name__ == "__main__":
    entry()
