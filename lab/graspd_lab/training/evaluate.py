"""Evaluate grasp classifiers as the IJRR paper does: accuracy, precision-recall curve, recall at 99%
precision (RA99P), on the test part of the view split and of the object split, optionally per category;
and how well the scores are calibrated (expected calibration error, reliability bins).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

#: The precision at which the paper reports recall.
TARGET_PRECISION = 0.99


def pr_curve(scores: NDArray[np.floating[Any]], labels: NDArray[Any]
             ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """(precision, recall, thresholds) over every distinct score, thresholds descending.

    Point i counts the exemplars with score >= thresholds[i] as predicted grasps.
    """
    scores = np.asarray(scores, np.float64).reshape(-1)
    truth = np.asarray(labels).reshape(-1).astype(bool)
    if scores.shape != truth.shape:
        raise ValueError(f"scores and labels must have the same length, got {scores.shape} and {truth.shape}")
    if len(scores) == 0:
        return np.zeros(0), np.zeros(0), np.zeros(0)
    order = np.argsort(-scores, kind="stable")
    s, t = scores[order], truth[order]
    tp = np.cumsum(t)
    fp = np.cumsum(~t)
    last = np.r_[np.flatnonzero(np.diff(s) != 0), len(s) - 1]  # last row of each run of equal scores
    positives = max(int(t.sum()), 1)
    precision = tp[last] / (tp[last] + fp[last])
    recall = tp[last] / positives
    return precision, recall, s[last]


def recall_at_precision(scores: NDArray[np.floating[Any]], labels: NDArray[Any],
                        precision: float = TARGET_PRECISION) -> tuple[float, float]:
    """(largest recall with precision >= the target, the score threshold that reaches it); (0, inf) if none."""
    prec, rec, thr = pr_curve(scores, labels)
    ok = prec >= precision
    if not ok.any():
        return 0.0, float("inf")
    i = int(np.argmax(np.where(ok, rec, -1.0)))
    return float(rec[i]), float(thr[i])


def average_precision(scores: NDArray[np.floating[Any]], labels: NDArray[Any]) -> float:
    """Area under the precision-recall curve (step-wise, as sum over recall increments)."""
    prec, rec, _ = pr_curve(scores, labels)
    if len(rec) == 0:
        return 0.0
    return float(np.sum(np.diff(np.r_[0.0, rec]) * prec))


def _bin_index(scores: NDArray[np.float64], bins: int) -> NDArray[np.int64]:
    if bins < 1:
        raise ValueError(f"bins must be >= 1, got {bins}")
    return np.clip(np.floor(scores * bins), 0, bins - 1).astype(np.int64)


def _scores_and_truth(scores: NDArray[np.floating[Any]], labels: NDArray[Any]
                      ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    s = np.asarray(scores, np.float64).reshape(-1)
    t = np.asarray(labels).reshape(-1).astype(bool).astype(np.float64)
    if s.shape != t.shape:
        raise ValueError(f"scores and labels must have the same length, got {s.shape} and {t.shape}")
    return s, t


def expected_calibration_error(scores: NDArray[np.floating[Any]], labels: NDArray[Any], bins: int = 10) -> float:
    """Mean |positive fraction - mean score| over equal-width score bins on [0, 1], weighted by the bin counts:
    0 when a score of p means a grasp p of the time (what thresholds and J(h) ranking assume)."""
    s, t = _scores_and_truth(scores, labels)
    if len(s) == 0:
        return 0.0
    idx = _bin_index(s, bins)
    count = np.bincount(idx, minlength=bins)
    gap = np.abs(np.bincount(idx, t, minlength=bins) - np.bincount(idx, s, minlength=bins))
    return float(gap.sum() / count.sum())


def reliability_bins(scores: NDArray[np.floating[Any]], labels: NDArray[Any], bins: int = 10
                     ) -> list[dict[str, float | int | None]]:
    """Per equal-width score bin: lower, upper, count, mean score and positive fraction (None when empty),
    the points of a reliability diagram."""
    s, t = _scores_and_truth(scores, labels)
    idx = _bin_index(s, bins)
    out: list[dict[str, float | int | None]] = []
    for b in range(bins):
        mask = idx == b
        n = int(mask.sum())
        out.append({"lower": b / bins, "upper": (b + 1) / bins, "count": n,
                    "mean_score": float(s[mask].mean()) if n else None,
                    "positive_fraction": float(t[mask].mean()) if n else None})
    return out


def classification_metrics(scores: NDArray[np.floating[Any]], labels: NDArray[Any],
                           threshold: float = 0.5) -> dict[str, float | int]:
    """Accuracy, precision and recall at a threshold, RA99P (and its threshold), average precision, and the
    expected calibration error (10 bins)."""
    scores = np.asarray(scores, np.float64).reshape(-1)
    truth = np.asarray(labels).reshape(-1).astype(bool)
    pred = scores >= threshold
    tp = int(np.sum(pred & truth))
    ra99p, thr99 = recall_at_precision(scores, truth)
    return {
        "n": int(len(truth)),
        "positives": int(truth.sum()),
        "accuracy": float(np.mean(pred == truth)) if len(truth) else 0.0,
        "precision": tp / max(int(pred.sum()), 1),
        "recall": tp / max(int(truth.sum()), 1),
        "ra99p": ra99p,
        "threshold_99p": thr99,
        "average_precision": average_precision(scores, truth),
        "ece": expected_calibration_error(scores, truth),
    }


#: Smallest Platt slope fit_platt returns: a > 0 keeps the ranking (and RA99P, AP) of the scores.
PLATT_MIN_SLOPE = 1e-3


def fit_platt(z: NDArray[np.floating[Any]], labels: NDArray[Any], steps: int = 100) -> tuple[float, float]:
    """(a, b) minimising the mean negative log-likelihood of p = sigmoid(a z + b) on labels (Platt scaling of a
    logit difference z): Newton's method with step halving, a kept >= PLATT_MIN_SLOPE."""
    zz, y = _scores_and_truth(z, labels)
    if len(zz) == 0:
        raise ValueError("fit_platt needs at least one score")
    x = np.stack([zz, np.ones_like(zz)], axis=1)

    def nll(t: NDArray[np.float64]) -> float:
        s = x @ t
        return float(np.mean(np.logaddexp(0.0, s) - y * s))

    theta = np.array([1.0, 0.0])
    f = nll(theta)
    for _ in range(steps):
        p = np.exp(-np.logaddexp(0.0, -(x @ theta)))  # sigmoid, without overflow
        grad = x.T @ (p - y) / len(y)
        hess = (x.T * (p * (1.0 - p))) @ x / len(y) + 1e-9 * np.eye(2)
        step = np.linalg.solve(hess, grad)
        t = 1.0
        while t > 1e-8:
            cand = theta - t * step
            cand[0] = max(cand[0], PLATT_MIN_SLOPE)
            fc = nll(cand)
            if fc <= f:
                break
            t *= 0.5
        else:
            break
        moved = float(np.max(np.abs(cand - theta)))
        theta, f = cand, fc
        if moved < 1e-10:
            break
    return float(theta[0]), float(theta[1])
