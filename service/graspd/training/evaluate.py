"""Evaluate grasp classifiers as the IJRR paper does: accuracy, precision-recall curve, recall at 99%
precision (RA99P), on the test part of the view split and of the object split, optionally per category.
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


def classification_metrics(scores: NDArray[np.floating[Any]], labels: NDArray[Any],
                           threshold: float = 0.5) -> dict[str, float | int]:
    """Accuracy, precision and recall at a threshold, RA99P (and its threshold), average precision."""
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
    }
