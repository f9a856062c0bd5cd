"""The training campaign's validation curve from its committed states: every state validated on one fixed set.

    python -m experiments.campaign_curve --data-root ../shared/data/modelnet40_real_subset,../shared/data/real_meshes_train \
        --states experiments/campaign/v5_step300.npz=4446,experiments/campaign/v10_step500.npz=5246 \
        --out docs/campaign_curve.png

The campaign's runs validated on different sets (with or without synthetic shapes) and their TensorBoard logs
are not kept; this measures each state (``PATH=STEP``: the params and their step in the whole lineage) with the
training loop's own validation (``train.validate``: the split's ``val`` files, ``--val-limit`` pairs spread over
them, 5 iterations), so the points are comparable. Prints JSON; writes the PNG and the same name with ``.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys


def _parse_states(text: str) -> list[tuple[str, int]]:
    states = []
    for item in (s for s in text.split(",") if s):
        path, sep, step = item.rpartition("=")
        if not sep or not step.isdigit():
            raise ValueError(f"--states: {item!r} is not PATH=STEP")
        if not os.path.isfile(path):
            raise ValueError(f"--states: no such file {path!r}")
        states.append((path, int(step)))
    if not states:
        raise ValueError("--states: no state given")
    return sorted(states, key=lambda s: s[1])


def _run_marks(rows: list[dict]) -> dict:
    """``{run: step}`` of each run's first state (the run: a state's name before ``_step``, e.g. ``v10``)."""
    marks: dict = {}
    for r in rows:
        marks.setdefault(os.path.splitext(r["state"])[0].split("_step")[0], r["step"])
    return marks


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--data-root", required=True, help="comma-separated dataset folders (their val files are used)")
    p.add_argument("--states", required=True, help="comma-separated PATH=STEP: params (.npz/.pth/orbax) and step")
    p.add_argument("--dataset", default="partial", choices=("clean", "noisy", "partial"))
    p.add_argument("--num-points", type=int, default=1024)
    p.add_argument("--val-limit", type=int, default=60)
    p.add_argument("--out", required=True, help="PNG path; the points go to the same name with .json")
    a = p.parse_args(argv)
    try:
        states = _parse_states(a.states)
        out_dir = os.path.dirname(os.path.abspath(a.out))
        if not os.path.isdir(out_dir):
            raise ValueError(f"--out: folder {out_dir!r} does not exist")
    except ValueError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2

    from rpmnet_jax import train
    from rpmnet_jax.cli import plots
    from rpmnet_jax.train import loop
    from rpmnet_jax.weights import loading

    cfg = train.TrainConfig(dataset=a.dataset, data_root=a.data_root, num_points=a.num_points, val_limit=a.val_limit)
    _, val_set = loop.datasets(cfg)
    eval_fn = train.make_eval_fn(cfg)
    rows = []
    for path, step in states:
        summary = train.validate(loading.load_params(path), val_set, cfg, eval_fn, progress=False)
        rows.append({"state": os.path.basename(path), "step": step, **{k: round(float(v), 5) for k, v in
                                                                        summary.items()}})
        print(json.dumps(rows[-1]), flush=True)
    plots.plot_validation_curve(a.out, [r["step"] for r in rows], [r["err_r_deg_mean"] for r in rows],
                                marks=_run_marks(rows))
    with open(os.path.splitext(a.out)[0] + ".json", "w") as f:
        json.dump({"data_root": a.data_root, "dataset": a.dataset, "val_limit": a.val_limit, "points": rows}, f,
                  indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
