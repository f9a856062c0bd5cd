"""AUROC, expected calibration error and the reliability bins against hand-worked cases."""

import numpy as np
import pytest

from rpmnet_jax.evaluation import calibration


def test_auroc_orders_pairs_and_counts_ties_half():
    assert calibration.auroc([0.9, 0.8, 0.1, 0.2], [1, 1, 0, 0]) == 1.0
    assert calibration.auroc([0.1, 0.2, 0.9, 0.8], [1, 1, 0, 0]) == 0.0
    assert calibration.auroc([0.5, 0.5], [1, 0]) == 0.5
    # 1 positive above 2 of 3 negatives, tied with none: 2/3
    assert calibration.auroc([0.5, 0.9, 0.1, 0.2], [1, 0, 0, 0]) == pytest.approx(2 / 3)
    assert np.isnan(calibration.auroc([0.1, 0.2], [0, 0]))


def test_ece_is_zero_when_frequencies_match_and_the_gap_otherwise():
    p = np.r_[np.full(10, 0.05), np.full(10, 0.75)]
    y = np.r_[np.zeros(10), np.r_[np.ones(7), np.zeros(3)]]  # bin [0.7, 0.8): 70% against 0.75
    assert calibration.ece(p, y) == pytest.approx(0.5 * 0.05 + 0.5 * 0.05)
    assert calibration.ece(np.r_[np.zeros(5), np.ones(5)], np.r_[np.zeros(5), np.ones(5)]) == 0.0
    count, mean_p, freq = calibration.bins(p, y)
    assert count.sum() == 20 and count[0] == 10 and count[7] == 10
    assert freq[7] == pytest.approx(0.7) and mean_p[0] == pytest.approx(0.05) and np.isnan(freq[3])


def test_lowest_bar_flags_at_most_the_share_asked():
    p = np.array([0.05, 0.12, 0.33, 0.41, 0.72, 0.97])
    right = np.array([True, True, True, True, False, False])
    assert calibration.lowest_bar(p, right, 0.25) == 0.35  # 0.3 flags 2 of 4 right rows, 0.35 flags 1
    assert calibration.lowest_bar(p, right, 0.0) == 0.45
    assert calibration.lowest_bar(np.ones(6), right, 0.0) == 0.95  # no bar on the grid does: the top one


def test_the_fit_ranks_a_separable_feature_and_held_out_probabilities_follow_it():
    pytest.importorskip("sklearn")
    rng = np.random.default_rng(0)
    x = rng.normal(size=(400, 2))
    y = x[:, 0] + 0.3 * rng.normal(size=400) > 0
    groups = np.arange(400) % 8
    fitted = calibration.fit_logistic_platt(x, y, groups, 4, 1.0, 1000)
    assert set(fitted.fold) == {0, 1, 2, 3} and fitted.scores.shape == (400,)
    assert abs(fitted.lr.coef_[0, 0]) > 5 * abs(fitted.lr.coef_[0, 1])  # the label's feature, not the noise
    p = calibration.held_out_platt(fitted.scores, y, fitted.fold)
    assert calibration.auroc(p, y) > 0.9 and np.all((p >= 0) & (p <= 1))
    assert set(fitted.spec()) == {"mean", "scale", "coef", "intercept", "platt_a", "platt_b"}
