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
