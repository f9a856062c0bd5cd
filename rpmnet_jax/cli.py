"""``rpmnet-register SRC REF``: align two point-cloud files with RPM-Net and write the transform.

Exit codes: 0 success, 2 bad input or arguments (one-line message, nothing written).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import warnings


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="rpmnet-register", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("src", help="source cloud (.ply .pcd .xyz .txt .csv .npy .npz), moved onto the reference")
    p.add_argument("ref", help="reference cloud")
    p.add_argument("--checkpoint", default=None,
                   help="orbax training dir, .npz or official .pth (default: the shipped model)")
    p.add_argument("--out-transform", default=None, help="write the 4x4 transform (.txt or .json)")
    p.add_argument("--out-aligned", default=None, help="write the aligned source (format from the extension)")
    p.add_argument("--plot", default=None, help="PNG with source, reference and aligned source in 3-D")
    p.add_argument("--num-points", type=int, default=1024, help="points per cloud fed to the model (default 1024)")
    p.add_argument("--iters", type=int, default=5, help="registration iterations (default 5)")
    p.add_argument("--sampling", choices=("random", "fps"), default="random", help="downsampling method")
    p.add_argument("--seed", type=int, default=0, help="seed of the downsampling")
    p.add_argument("--centering", choices=("separate", "common"), default="separate",
                   help="centre each cloud on its own centroid (default) or both on their joint centroid")
    p.add_argument("--estimate-normals", action="store_true", help="re-estimate normals even if the files have them")
    return p


def plot_alignment(path: str, src, ref, aligned, max_points: int = 3000) -> None:
    """Headless 3-D scatter of source (red), reference (blue) and aligned source (green)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    rng = np.random.default_rng(0)
    sub = lambda x: x[rng.choice(len(x), min(len(x), max_points), replace=False)]
    fig = plt.figure(figsize=(10, 5))
    for i, (title, clouds) in enumerate([("before", [(src, "tab:red", "source"), (ref, "tab:blue", "reference")]),
                                         ("after", [(aligned, "tab:green", "aligned source"),
                                                    (ref, "tab:blue", "reference")])]):
        ax = fig.add_subplot(1, 2, i + 1, projection="3d")
        for pts, colour, label in clouds:
            s = sub(pts)
            ax.scatter(s[:, 0], s[:, 1], s[:, 2], s=1, c=colour, label=label)
        ax.set_title(title)
        ax.legend(loc="upper left", markerscale=6, fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    args = _parser().parse_args(argv)
    from rpmnet_jax import alignment as align_lib
    from rpmnet_jax import cloud_io, pretrained

    try:
        for out in (args.out_transform, args.out_aligned, args.plot):
            if out and not os.path.isdir(os.path.dirname(os.path.abspath(out))):
                raise ValueError(f"output folder of {out} does not exist")
        if args.out_aligned:
            cloud_io._ext(args.out_aligned)
        src, src_n = cloud_io.read_cloud(args.src)
        ref, ref_n = cloud_io.read_cloud(args.ref)
        if args.checkpoint is None and not pretrained.has_default():
            raise ValueError("no shipped model in this install; pass --checkpoint")
        t0 = time.time()
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            result = align_lib.align(src, ref, src_n, ref_n, checkpoint=args.checkpoint, num_points=args.num_points,
                                     num_iters=args.iters, sampling=args.sampling, seed=args.seed,
                                     centering=args.centering, reestimate_normals=args.estimate_normals)
        seconds = time.time() - t0
    except (ValueError, FileNotFoundError) as e:
        print(f"rpmnet-register: error: {e}", file=sys.stderr)
        return 2
    for w in caught:
        print(f"rpmnet-register: warning: {w.message}", file=sys.stderr)
    import numpy as np
    with np.printoptions(precision=6, suppress=True):
        print(result.transform)
    print(f"confidence {result.confidence:.3f}  points {result.num_points[0]}/{result.num_points[1]}  "
          f"time {seconds:.2f} s")
    if args.out_transform:
        cloud_io.write_transform(args.out_transform, result.transform, confidence=result.confidence)
    if args.out_aligned:
        aligned_n = None if src_n is None else src_n @ result.transform[:3, :3].T
        if aligned_n is not None and len(aligned_n) != len(result.aligned):
            aligned_n = None  # rows with NaNs were dropped
        cloud_io.write_cloud(args.out_aligned, result.aligned, aligned_n)
    if args.plot:
        plot_alignment(args.plot, src, ref, result.aligned)
    return 0


def entry() -> None:
    from rpmnet_jax import runtime
    runtime.use_huge_pages()
    sys.exit(main())


if __name__ == "__main__":
    entry()
