import json

import numpy as np
import pytest

from experiments import compare_states
from rpmnet_jax.evaluation import paired


def _errors(seed, n=150):
    """Heavy-tailed rotation errors (deg): most pairs ~1.4 deg, a few far misses, like a partial test file."""
    rng = np.random.default_rng(seed)
    err = rng.gamma(4.0, 0.35, n)
    far = rng.random(n) < 0.08
    err[far] = rng.uniform(6.0, 50.0, far.sum())
    return err


def test_a_uniform_improvement_is_resolved_and_sized():
    a = _errors(0)
    b = a * 0.7  # every pair 30% better
    r = paired.compare(a, b, resamples=2000)
    assert r["mean"]["b_minus_a"] == pytest.approx(-0.3 * a.mean())
    lo, hi = r["mean"]["interval"]
    assert lo <= r["mean"]["b_minus_a"] <= hi < 0 and r["mean"]["resolved"]
    assert r["median"]["resolved"] and r["median"]["interval"][1] < 0


def test_reshuffled_tails_are_not_resolved():
    """Two models that miss different pairs equally often: the interval holds 0."""
    rng = np.random.default_rng(1)
    a = _errors(2)
    b = a.copy()
    swap = rng.permutation(len(a))[:40]
    b[swap] = a[rng.permutation(swap)]
    r = paired.compare(a, b, resamples=2000)
    for stat in ("mean", "median", "share_under"):
        lo, hi = r[stat]["interval"]
        assert lo <= 0.0 <= hi and not r[stat]["resolved"]


def test_each_model_interval_contains_its_statistic_and_share_counts_the_threshold():
    a, b = _errors(3), _errors(4)
    r = paired.compare(a, b, resamples=2000, threshold=5.0)
    assert r["share_under"]["a"] == pytest.approx(np.mean(a < 5.0))
    for side in ("a", "b"):
        lo, hi = r["mean"][f"{side}_interval"]
        assert lo <= r["mean"][side] <= hi


@pytest.mark.parametrize("a, b, why", [
    (np.ones(3), np.ones(4), "equal-length"), (np.ones((2, 2)), np.ones((2, 2)), "1-D"),
    (np.array([1.0, np.nan]), np.ones(2), "finite"), (np.ones(0), np.ones(0), "equal-length")])
def test_bad_errors_raise(a, b, why):
    with pytest.raises(ValueError, match=why):
        paired.compare(a, b)


def _write_csv(path, idx, err):
    with open(path, "w") as f:
        f.write("idx,label,err_r_deg\n")
        for i, e in zip(idx, err):
            f.write(f"{i},0,{e:.8g}\n")
    return str(path)


def test_cli_matches_pairs_by_idx(tmp_path, capsys):
    a = _errors(5, 60)
    order = np.random.default_rng(0).permutation(60)
    fa = _write_csv(tmp_path / "a.csv", np.arange(60), a)
    fb = _write_csv(tmp_path / "b.csv", order, a[order] + 1.0)  # B: 1 deg worse on every pair, rows shuffled
    assert compare_states.main([fa, fb, "--resamples", "500"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["pairs"] == 60
    assert out["mean"]["b_minus_a"] == pytest.approx(1.0, abs=1e-6)
    assert out["mean"]["interval"] == pytest.approx([1.0, 1.0], abs=1e-6)


@pytest.mark.parametrize("case, why", [("missing", "no such file"), ("other_pairs", "different pairs"),
                                       ("no_column", "needs the columns"), ("few", "at least 100")])
def test_cli_errors_are_one_line(tmp_path, capsys, case, why):
    fa = _write_csv(tmp_path / "a.csv", range(5), np.ones(5))
    fb = {"missing": str(tmp_path / "none.csv"),
          "other_pairs": _write_csv(tmp_path / "b.csv", range(1, 6), np.ones(5)),
          "no_column": str(tmp_path / "c.csv"), "few": fa}[case]
    if case == "no_column":
        (tmp_path / "c.csv").write_text("idx,label,err_t\n0,0,1\n")
    extra = ["--resamples", "10"] if case == "few" else []
    assert compare_states.main([fa, fb, *extra]) == 2
    err = capsys.readouterr().err
    assert why in err and len(err.strip().splitlines()) == 1


def test_cli_rejects_a_repeated_pair(tmp_path, capsys):
    fa = _write_csv(tmp_path / "a.csv", [0, 1, 1], np.ones(3))
    fb = _write_csv(tmp_path / "b.csv", [0, 1, 1], np.ones(3))
    assert compare_states.main([fa, fb]) == 2
    err = capsys.readouterr().err
    assert "more than once" in err and len(err.strip().splitlines()) == 1
