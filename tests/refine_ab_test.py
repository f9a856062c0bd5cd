"""Refinement A/B: our side is align's own refinement, starts are what they say, the summary counts right."""

import jax
import numpy as np
import pytest

import rpmnet_jax
from conftest import asymmetric_shape, rotation_about, rotation_error_deg
from rpmnet_jax.evaluation import refine_ab


def _pair(seed=0):
    pts, nrm = asymmetric_shape(seed, 1400)
    rot = rotation_about([0.3, 1.0, -0.2], 20.0)
    src = np.concatenate([pts[::2], nrm[::2]], 1)
    ref = np.concatenate([pts[1::2] @ rot.T + [0.1, -0.2, 0.05], nrm[1::2] @ rot.T], 1)
    gt = np.eye(4)
    gt[:3, :3], gt[:3, 3] = rot, [0.1, -0.2, 0.05]
    return src, ref, gt


def test_ours_is_aligns_refinement_from_the_network_start():
    params = rpmnet_jax.init_params(jax.random.PRNGKey(0))
    src, ref, _ = _pair()
    prepared = refine_ab.Prepared(src, ref)
    ours = prepared.refine(prepared.network_start(params, num_iters=2))
    a = rpmnet_jax.align(src[:, :3], ref[:, :3], src[:, 3:], ref[:, 3:], params=params,
                         network_options=rpmnet_jax.NetworkOptions(len(src), 2), init="local")
    np.testing.assert_allclose(ours.transform, a.transform, atol=1e-12)
    assert (ours.converged, ours.num_iterations) == (a.converged, a.num_iterations)


def test_unit_frame_round_trip_and_a_near_start_is_refined():
    src, ref, gt = _pair(1)
    prepared = refine_ab.Prepared(src, ref)
    t = refine_ab.perturbed_start(gt[:3], np.random.default_rng(0))
    np.testing.assert_allclose(prepared.pair.to_callers_units(refine_ab._to_unit(prepared.pair, t)[:3]), t,
                               atol=1e-12)
    assert rotation_error_deg(prepared.refine(t).transform[:3, :3], gt[:3, :3]) < 0.1


@pytest.mark.parametrize("seed", range(3))
def test_perturbed_starts_are_3_to_10_degrees_and_at_most_002_off(seed):
    gt = np.eye(4)[:3]
    t = refine_ab.perturbed_start(gt, np.random.default_rng(seed))
    assert 3.0 <= rotation_error_deg(t[:3, :3], np.eye(3)) <= 10.0
    # the perturbation is applied after the truth: t = delta @ gt, so with gt = I its translation is delta's
    assert np.linalg.norm(t[:3, 3]) <= 0.02


def test_summary():
    rows = [dict(start="perturbed", start_err_r=5.0, start_err_t=0.1, ours_err_r=r1, ours_err_t=0.0,
                 o3d_err_r=r2, o3d_err_t=0.0, ours_seconds=0.1, o3d_seconds=0.2, ours_iterations=3)
            for r1, r2 in ((0.1, 0.2), (0.3, 0.3), (6.0, 0.4))]
    s = refine_ab.summarize(rows)["perturbed"]
    assert s["pairs"] == 3 and s["ours"]["err_r_median"] == pytest.approx(0.3)
    assert s["ours"]["improved"] == pytest.approx(2 / 3) and s["o3d"]["improved"] == 1.0
    assert s["ours_at_least_as_close"] == pytest.approx(2 / 3)
    assert s["o3d"]["seconds_per_pair"] == pytest.approx(0.2)
