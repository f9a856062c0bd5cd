"""How well ``a.p_wrong`` / ``a.likely_wrong`` (:mod:`rpmnet_jax.pairwise.doubt`) know a wrong answer, on the
TEST files (``--split val`` of ``experiments.eval``: never used to fit the model).

    python -m experiments.eval_doubt [--cache /tmp/rpmnet_doubt/val.jsonl] [--collect-only] [--plot docs/doubt_reliability.png]

Runs the default ``align`` on every pair of both public sets' test files, partial and noisy, ±45° and any
orientation (8 rows, the pairs of ``docs/results.md``'s table; records cached in ``--cache``, resumable), then
prints per row: pairs, wrong answers (> 5°), the share of wrong answers flagged ``likely_wrong`` and of right ones,
AUROC and the expected calibration error (10 bins) of ``p_wrong``, as a markdown table; ``--plot`` draws the
reliability diagram of all rows together (and of the any-orientation rows). ``--kinds RECORDS`` prints instead,
per kind of real data, the flags of the shipped model and of ``--model`` on records of ``experiments.fit_doubt
collect-real --part report`` (the real-scan benchmark's report pairs and the room's seed-1 stations).
"""

from __future__ import annotations

import argparse
import os

import numpy as np

DATA_ROOTS = "../shared/data/modelnet40_real_subset,../shared/data/real_meshes_train"
ROWS = (("partial", 45.0), ("partial", 180.0), ("noisy", 45.0), ("noisy", 180.0))


def collect(a) -> None:
    from rpmnet_jax import data
    from rpmnet_jax.evaluation import doubt_records
    from rpmnet_jax.weights import loading
    params = loading.load_params(None)
    for root in a.data_roots.split(","):
        for protocol, rot in ROWS:
            ds = data.ModelNet40(root, "val", protocol, rot_mag=rot)
            doubt_records.collect(ds, range(len(ds)), params, a.cache, progress=False,
                                  set=os.path.basename(os.path.normpath(root)), split="val", seed=None,
                                  setting="std")


def report(a) -> None:
    from rpmnet_jax.evaluation import calibration, doubt_records
    from rpmnet_jax.pairwise import doubt
    rows = doubt_records.read(a.cache)
    model = doubt.load(a.model) if a.model else doubt.load()
    p = model.probability(doubt_records.features(rows))
    y = doubt_records.labels(rows)
    print("| set | protocol | rotations | pairs | wrong (> 5°) | wrong flagged | right flagged | AUROC | ECE (10 bins) |")
    print("|---|---|---|---|---|---|---|---|---|")
    groups = [(s, pr, rot) for s in dict.fromkeys(r["set"] for r in rows) for pr, rot in ROWS]
    groups += [("all", "partial+noisy", 180.0), ("all", "partial+noisy", 45.0)]
    for s, protocol, rot in groups:
        m = np.array([(s in ("all", r["set"])) and r["protocol"] in protocol.split("+") and r["rot_mag"] == rot
                      for r in rows])
        if not m.any():
            continue
        ym, pm = y[m], p[m]
        flag = pm >= model.threshold
        fw = f"{flag[ym].sum()} / {ym.sum()}" if ym.any() else "–"
        print(f"| {s} | {protocol} | {'any' if rot == 180 else '±45°'} | {m.sum()} | {ym.sum()} | {fw} | "
              f"{flag[~ym].sum()} / {(~ym).sum()} ({100 * flag[~ym].mean():.1f}%) | "
              f"{calibration.auroc(pm, ym):.3f} | {calibration.ece(pm, ym):.4f} |")
    amb = np.array([r["ambiguous"] for r in rows])
    print(f"\nambiguous flags {amb[y].sum()} of {y.sum()} wrong answers and {amb[~y].sum()} of {(~y).sum()} right ones")
    if a.plot:
        _plot(a.plot, p, y, np.array([r["rot_mag"] == 180.0 for r in rows]))


def report_kinds(a) -> None:
    """Per kind of data (``setting`` of records from ``experiments.fit_doubt collect-real``): pairs, wrong answers,
    and the wrong and right ones flagged ``likely_wrong``, by the shipped model and by ``--model``."""
    from rpmnet_jax.evaluation import doubt_records
    from rpmnet_jax.pairwise import doubt
    rows = doubt_records.read(a.kinds)
    x, y = doubt_records.features(rows), doubt_records.labels(rows)
    models = {"shipped": doubt.load()} | ({"--model": doubt.load(a.model)} if a.model else {})
    print("| kind | pairs | wrong (> 5°) | " + " | ".join(f"{n}: wrong flagged | {n}: right flagged" for n in models)
          + " |")
    print("|---|---|---|" + "---|---|" * len(models))
    kinds = np.array([r["setting"] for r in rows])
    for kind in [*dict.fromkeys(kinds), "all"]:
        m = (kinds == kind) | (kind == "all")
        cells = []
        for model in models.values():
            flag = model.probability(x[m]) >= model.threshold
            cells.append(f"{flag[y[m]].sum()} / {y[m].sum()}" if y[m].any() else "–")
            cells.append(f"{flag[~y[m]].sum()} / {(~y[m]).sum()}")
        print(f"| {kind} | {m.sum()} | {y[m].sum()} | " + " | ".join(cells) + " |")


def _plot(path, p, y, any_orientation) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from rpmnet_jax.evaluation import calibration
    fig, (ax, hist) = plt.subplots(1, 2, figsize=(9, 4))
    ax.plot([0, 1], [0, 1], "k:", lw=1, label="perfect")
    for m, label in ((np.ones_like(y), "all 8 rows"), (any_orientation, "any orientation")):
        count, mean_p, freq = calibration.bins(p[m], y[m])
        full = count > 0
        ax.plot(mean_p[full], freq[full], "o-", label=f"{label} (ECE {calibration.ece(p[m], y[m]):.3f})")
    ax.set(xlabel="mean p_wrong in bin", ylabel="share wrong (> 5°)", title="reliability, test files", xlim=(0, 1),
           ylim=(0, 1))
    ax.legend(fontsize=8)
    hist.hist([p[~y], p[y]], bins=np.linspace(0, 1, 11), label=["right", "wrong"], log=True)
    hist.set(xlabel="p_wrong", ylabel="pairs", title="p_wrong of right and wrong answers")
    hist.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--cache", default="/tmp/rpmnet_doubt/val.jsonl")
    p.add_argument("--data-roots", default=DATA_ROOTS)
    p.add_argument("--collect-only", action="store_true")
    p.add_argument("--model", default=None, help="a doubt model JSON (default the shipped one)")
    p.add_argument("--plot", default=None)
    p.add_argument("--kinds", default=None, help="only the per-kind table of these real-scan records "
                   "(experiments.fit_doubt collect-real)")
    a = p.parse_args(argv)
    if a.kinds:
        return report_kinds(a)
    os.makedirs(os.path.dirname(os.path.abspath(a.cache)), exist_ok=True)
    collect(a)
    if not a.collect_only:
        report(a)


if __name__ == "__main__":
    main()
