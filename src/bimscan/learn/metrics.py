"""Segmentation metrics from one confusion matrix: OA, mIoU, mAcc, FWIoU, Cohen's kappa.

The confusion matrix ``cm`` is (C, C) int64, rows = ground truth, columns = prediction, as in
scikit-learn. Points whose ground truth is outside 0..C-1 (padding, the unlabelled id 255) are
not counted.

Convention for classes absent from a scene (stated here, tested in tests/learn/test_metrics.py):

- A class is *present* when it has ground truth or prediction (row or column sum > 0).
- IoU_c = TP / (TP + FP + FN) for present classes; NaN for absent ones. mIoU is the mean over
  present classes: a class predicted but absent from the ground truth counts with IoU 0 (a
  false alarm is an error), a class neither in the ground truth nor predicted is left out.
  This equals ``sklearn.metrics.jaccard_score(average="macro", labels=present)``.
- Acc_c (recall) = TP / (TP + FN) for classes with ground truth; mAcc is their mean, equal to
  ``sklearn.metrics.balanced_accuracy_score`` (which also skips classes without ground truth).
- FWIoU = sum_c (support_c / total) IoU_c, support from the ground truth; equals
  ``jaccard_score(average="weighted")``.
- kappa = (p_o - p_e) / (1 - p_e). When p_e = 1 (one single class in both ground truth and
  prediction, hence p_o = 1 too) kappa is taken as 1.0, where scikit-learn returns NaN.
- With no counted points at all, every metric is NaN.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

METRIC_NAMES = ("oa", "miou", "macc", "fwiou", "kappa")


def compute_confusion(
    target: np.ndarray, prediction: np.ndarray, *, num_classes: int, valid: np.ndarray | None = None,
) -> np.ndarray:
    """Confusion matrix (C, C) int64 of integer arrays of equal shape.

    Points with ``target`` outside 0..C-1 or with ``valid`` False are skipped. ``prediction``
    must lie in 0..C-1 where counted.
    """
    target = np.asarray(target).reshape(-1).astype(np.int64)
    prediction = np.asarray(prediction).reshape(-1).astype(np.int64)
    if target.shape != prediction.shape:
        raise ValueError(f"target and prediction differ in size: {target.shape} vs {prediction.shape}")
    keep = (target >= 0) & (target < num_classes)
    if valid is not None:
        keep &= np.asarray(valid).reshape(-1).astype(bool)
    target, prediction = target[keep], prediction[keep]
    if len(prediction) and (prediction.min() < 0 or prediction.max() >= num_classes):
        raise ValueError(f"predictions must lie in 0..{num_classes - 1}, got {prediction.min()}..{prediction.max()}")
    counts = np.bincount(target * num_classes + prediction, minlength=num_classes * num_classes)
    return counts.reshape(num_classes, num_classes).astype(np.int64)


@dataclass(frozen=True)
class SegmentationMetrics:
    """Metrics of one confusion matrix (see the module docstring for the conventions).

    Scalars are fractions in 0..1 (kappa in -1..1). Per-class arrays are (C,) float64:
    ``iou`` (NaN for absent classes), ``acc`` (recall, NaN without ground truth); ``present``
    (C,) bool; ``support`` (C,) int64 ground-truth points per class.
    """

    oa: float
    miou: float
    macc: float
    fwiou: float
    kappa: float
    iou: np.ndarray
    acc: np.ndarray
    present: np.ndarray
    support: np.ndarray
    total: int

    def scalars(self) -> dict[str, float]:
        """The five headline metrics by name (``METRIC_NAMES``)."""
        return {name: float(getattr(self, name)) for name in METRIC_NAMES}


def compute_metrics(confusion: np.ndarray) -> SegmentationMetrics:
    """OA, mIoU, mAcc, FWIoU, kappa and per-class IoU/recall of a (C, C) confusion matrix."""
    cm = np.asarray(confusion, dtype=np.float64)
    if cm.ndim != 2 or cm.shape[0] != cm.shape[1]:
        raise ValueError(f"confusion matrix must be square (C, C), got shape {cm.shape}")
    support = cm.sum(axis=1)
    predicted = cm.sum(axis=0)
    tp = np.diag(cm)
    total = float(cm.sum())
    present = (support + predicted) > 0
    union = support + predicted - tp
    with np.errstate(invalid="ignore", divide="ignore"):
        iou = np.where(present, tp / np.where(union > 0, union, 1.0), np.nan)
        acc = np.where(support > 0, tp / np.where(support > 0, support, 1.0), np.nan)
    if total == 0:
        nan = math.nan
        return SegmentationMetrics(nan, nan, nan, nan, nan, iou, acc, present, support.astype(np.int64), 0)
    oa = float(tp.sum() / total)
    miou = float(np.mean(iou[present]))
    macc = float(np.mean(acc[support > 0]))
    fwiou = float(np.sum((support / total)[support > 0] * iou[support > 0]))
    kappa = _cohen_kappa(np.asarray(confusion), cm)
    return SegmentationMetrics(
        oa=oa, miou=miou, macc=macc, fwiou=fwiou, kappa=kappa, iou=iou, acc=acc,
        present=present, support=support.astype(np.int64), total=int(total),
    )


def _cohen_kappa(counts: np.ndarray, cm: np.ndarray) -> float:
    """kappa = (N * agree - chance) / (N**2 - chance), chance = sum_c support_c * predicted_c.

    Integer counts are summed as Python integers, so p_e = 1 (one class in ground truth and
    prediction, kappa taken as 1) is tested exactly and kappa is correctly rounded whatever N
    (N**2 overflows int64 past 3e9 points). A tolerance on a float p_e took near-chance
    predictions on huge matrices (p_e = 1 - 1e-12) for perfect ones.
    """
    if counts.dtype.kind in "iu":
        support = [int(v) for v in counts.sum(axis=1)]
        predicted = [int(v) for v in counts.sum(axis=0)]
        n, agree = sum(support), sum(int(counts[c, c]) for c in range(len(support)))
    else:  # float counts (not produced by bimscan): the same formula in float64
        support, predicted = cm.sum(axis=1).tolist(), cm.sum(axis=0).tolist()
        n, agree = float(cm.sum()), float(np.trace(cm))
    chance = sum(s * p for s, p in zip(support, predicted, strict=True))
    if chance == n * n:
        return 1.0
    return float((n * agree - chance) / (n * n - chance))
