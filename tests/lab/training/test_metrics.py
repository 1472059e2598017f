"""Precision-recall, RA99P and accuracy on hand-checkable score lists."""

import numpy as np
import pytest

from graspd_lab.training.evaluate import (
    average_precision,
    classification_metrics,
    expected_calibration_error,
    pr_curve,
    recall_at_precision,
    reliability_bins,
)


def test_pr_curve_counts_each_distinct_threshold() -> None:
    scores = np.array([0.9, 0.8, 0.7, 0.6])
    labels = np.array([1, 0, 1, 0])
    prec, rec, thr = pr_curve(scores, labels)
    np.testing.assert_allclose(thr, [0.9, 0.8, 0.7, 0.6])
    np.testing.assert_allclose(prec, [1.0, 0.5, 2 / 3, 0.5])
    np.testing.assert_allclose(rec, [0.5, 0.5, 1.0, 1.0])


def test_tied_scores_form_one_point() -> None:
    prec, rec, thr = pr_curve(np.array([0.5, 0.5, 0.2]), np.array([1, 0, 1]))
    np.testing.assert_allclose(thr, [0.5, 0.2])
    np.testing.assert_allclose(prec, [0.5, 2 / 3])
    np.testing.assert_allclose(rec, [0.5, 1.0])


def test_recall_at_99_precision() -> None:
    # 100 positives ranked first except one negative at rank 51: precision stays >= 0.99 only up to rank 50.
    scores = np.linspace(1.0, 0.0, 200)
    labels = np.r_[np.ones(50), 0, np.ones(50), np.zeros(99)].astype(int)
    ra, thr = recall_at_precision(scores, labels)
    assert ra == pytest.approx(1.0)  # 100/101 = 0.990 precision at full recall
    labels2 = np.r_[np.ones(50), 0, 0, np.ones(50), np.zeros(98)].astype(int)
    ra2, thr2 = recall_at_precision(scores, labels2)
    assert ra2 == pytest.approx(0.5)
    assert thr2 == pytest.approx(scores[49])


def test_no_threshold_reaches_precision() -> None:
    ra, thr = recall_at_precision(np.array([0.9, 0.1]), np.array([0, 1]))
    assert ra == 0.0 and thr == float("inf")


def test_perfect_and_inverted_rankings() -> None:
    labels = np.r_[np.ones(10), np.zeros(10)]
    good = classification_metrics(np.r_[np.full(10, 0.9), np.full(10, 0.1)], labels)
    assert good["accuracy"] == 1.0 and good["ra99p"] == 1.0 and good["average_precision"] == 1.0
    bad = classification_metrics(np.r_[np.full(10, 0.1), np.full(10, 0.9)], labels)
    assert bad["accuracy"] == 0.0 and bad["ra99p"] == 0.0
    assert average_precision(np.r_[np.full(10, 0.1), np.full(10, 0.9)], labels) == pytest.approx(0.5)


def test_length_mismatch_is_an_error() -> None:
    with pytest.raises(ValueError, match="same length"):
        pr_curve(np.zeros(3), np.zeros(2))


def test_expected_calibration_error_by_hand() -> None:
    # bin [0.1, 0.2): scores 0.15 x4, one positive -> |0.25 - 0.15|; bin [0.9, 1.0]: 0.95 and 1.0, both positive
    scores = np.array([0.15, 0.15, 0.15, 0.15, 0.95, 1.0])
    labels = np.array([1, 0, 0, 0, 1, 1])
    expected = (4 * 0.10 + 2 * abs(1.0 - 0.975)) / 6
    assert expected_calibration_error(scores, labels) == pytest.approx(expected)
    assert classification_metrics(scores, labels)["ece"] == pytest.approx(expected)
    assert expected_calibration_error(np.r_[np.zeros(5), np.ones(5)], np.r_[np.zeros(5), np.ones(5)]) == 0.0
    assert expected_calibration_error(np.zeros(0), np.zeros(0)) == 0.0


def test_reliability_bins_by_hand() -> None:
    bins = reliability_bins(np.array([0.05, 0.45, 0.55, 0.5, 1.0]), np.array([0, 1, 0, 1, 1]), bins=2)
    assert [(b["lower"], b["upper"], b["count"]) for b in bins] == [(0.0, 0.5, 2), (0.5, 1.0, 3)]
    assert bins[0]["mean_score"] == pytest.approx(0.25) and bins[0]["positive_fraction"] == pytest.approx(0.5)
    assert bins[1]["mean_score"] == pytest.approx(2.05 / 3) and bins[1]["positive_fraction"] == pytest.approx(2 / 3)
    empty = reliability_bins(np.array([0.95]), np.array([1]), bins=10)
    assert empty[0]["count"] == 0 and empty[0]["mean_score"] is None and empty[9]["count"] == 1
