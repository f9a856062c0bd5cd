"""Figures of the command-line tools (matplotlib, headless)."""

from __future__ import annotations

import numpy as np


def check_available() -> None:
    """Raises ``ValueError`` (one line naming the extra) when matplotlib is not installed: call it before
    anything is computed."""
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        raise ValueError("--plot needs matplotlib, which is not installed: pip install 'rpmnet_jax[viz]'") from None


def _pyplot():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def plot_alignment(path: str, src, ref, aligned, max_points: int = 3000) -> None:
    """Headless 3-D scatter of source (red), reference (blue) and aligned source (green); rows with NaN/inf
    are left out."""
    plt = _pyplot()

    rng = np.random.default_rng(0)

    def sub(x):
        x = np.asarray(x)[np.all(np.isfinite(x), axis=1)]
        return x[rng.choice(len(x), min(len(x), max_points), replace=False)]
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


def plot_chamfer(path, curves: dict) -> None:
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(5, 3.5))
    for name, values in curves.items():
        ax.plot(np.arange(1, len(values) + 1), values, marker="o", label=name)
    ax.set_xlabel("iteration")
    ax.set_ylabel("mean modified Chamfer distance")
    ax.set_yscale("log")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_examples(path, samples, transforms) -> None:
    plt = _pyplot()
    n = len(samples)
    fig = plt.figure(figsize=(4 * n, 4))
    for i, (s, t) in enumerate(zip(samples, transforms)):
        ax = fig.add_subplot(1, n, i + 1, projection="3d")
        src, ref = s["points_src"][:, :3], s["points_ref"][:, :3]
        t = np.asarray(t, np.float64)
        moved = src @ t[:3, :3].T + t[:3, 3]
        for pts, colour, label in ((src, "tab:red", "source"), (ref, "tab:blue", "reference"),
                                   (moved, "tab:green", "aligned")):
            ax.scatter(pts[:, 0], pts[:, 1], pts[:, 2], s=1, c=colour, label=label)
        ax.set_title(f"pair {int(s['idx'])}")
        ax.set_axis_off()
    ax.legend(loc="lower right", markerscale=6, fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def plot_validation_curve(path: str, steps, values, label: str = "validation mean isotropic rotation error (°)",
                          marks: dict | None = None) -> None:
    """Line plot of a validation metric against the training step; ``marks``: ``{name: step}`` vertical lines."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6, 3.5))
    ax.plot(steps, values, marker="o", ms=3)
    for name, step in (marks or {}).items():
        ax.axvline(step, color="grey", ls="--", lw=0.8)
        ax.text(step, max(values), f" {name}", fontsize=8, va="top")
    ax.set_xlabel("training step")
    ax.set_ylabel(label)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_scans(path: str, panels: dict, names, max_points: int = 2500) -> None:
    """Headless 3-D scatter of scans in a common frame, one colour per scan: ``panels`` maps a title to a list
    of ``(N_i, 3)`` clouds (``None`` for a scan left out), one panel each, side by side."""
    plt = _pyplot()
    rng = np.random.default_rng(0)
    colours = plt.get_cmap("tab10" if len(names) <= 10 else "tab20")
    fig = plt.figure(figsize=(5.5 * len(panels), 5.5))
    for k, (title, clouds) in enumerate(panels.items()):
        ax = fig.add_subplot(1, len(panels), k + 1, projection="3d", computed_zorder=False)  # scan order
        for i, (name, pts) in enumerate(zip(names, clouds)):
            if pts is None:
                continue
            s = pts[rng.choice(len(pts), min(len(pts), max_points), replace=False)]
            ax.scatter(s[:, 0], s[:, 1], s[:, 2], s=0.5, color=colours(i % colours.N), label=name)
        ax.text2D(0.5, 0.97, title, transform=ax.transAxes, ha="center", va="top")
        ax.set_axis_off()
        ax.view_init(elev=15, azim=20, vertical_axis="y")  # y up, as in camera frames and the Stanford scans
    fig.axes[0].legend(loc="upper left", markerscale=10, fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
