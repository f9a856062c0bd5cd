import json
import os

import jax
import numpy as np
import pytest

import rpmnet_jax
from experiments import campaign_curve
from rpmnet_jax.data import synthetic
from rpmnet_jax.weights import convert


def _state(path, seed):
    np.savez(path, **convert.params_to_torch(rpmnet_jax.init_params(jax.random.PRNGKey(seed))))
    return str(path)


@pytest.mark.parametrize("states, why", [("missing.npz=10", "no such file"), ("{w}", "is not PATH=STEP"),
                                         ("{w}=ten", "is not PATH=STEP"), (",", "no state given")])
def test_bad_states_are_one_line_errors_and_write_nothing(tmp_path, capsys, states, why):
    w = _state(tmp_path / "w.npz", 0)
    out = tmp_path / "curve.png"
    rc = campaign_curve.main(["--data-root", str(tmp_path), "--states", states.format(w=w), "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 2 and why in err and len(err.strip().splitlines()) == 1
    assert not out.exists() and not (tmp_path / "curve.json").exists()


def test_missing_output_folder_is_an_error(tmp_path, capsys):
    w = _state(tmp_path / "w.npz", 0)
    rc = campaign_curve.main(["--data-root", str(tmp_path), "--states", f"{w}=1",
                              "--out", str(tmp_path / "nowhere" / "c.png")])
    assert rc == 2 and "does not exist" in capsys.readouterr().err


@pytest.mark.slow  # compiles the 5-iteration registration and validates three states (~30 s)
def test_states_are_validated_on_one_set_in_step_order(tmp_path, capsys):
    root = synthetic.write_dataset(tmp_path / "syn", 8, 8, seed=0, n=256)
    a, b = _state(tmp_path / "va_step5.npz", 0), _state(tmp_path / "vb_step2.npz", 1)
    out = tmp_path / "curve.png"
    rc = campaign_curve.main(["--data-root", root, "--states", f"{a}=30,{b}=10,{a}=20", "--num-points", "64",
                              "--val-limit", "4", "--out", str(out)])
    assert rc == 0 and os.path.getsize(out) > 0
    rows = json.loads((tmp_path / "curve.json").read_text())["points"]
    assert [(r["state"], r["step"]) for r in rows] == [("vb_step2.npz", 10), ("va_step5.npz", 20),
                                                       ("va_step5.npz", 30)]
    assert all(0 <= r["err_r_deg_mean"] <= 180 for r in rows)
    assert rows[1] == dict(rows[2], step=20)  # the same params on the same set: the same metrics
    assert rows[0]["err_r_deg_mean"] != rows[1]["err_r_deg_mean"]  # other params: other answers
    assert campaign_curve._run_marks(rows) == {"vb": 10, "va": 20}
