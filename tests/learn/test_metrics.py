"""Metrics: equal to scikit-learn's on random data, right by hand on a tiny case, and the
stated convention for classes absent from a scene."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from sklearn.metrics import (
    accuracy_score, balanced_accuracy_score, cohen_kappa_score, confusion_matrix, jaccard_score, recall_score,
)

from bimscan.learn.metrics import compute_confusion, compute_metrics


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(1, 400),
    classes=st.integers(2, 7),
    skew=st.floats(0.0, 3.0),
)
def test_metrics_equal_scikit_learn_on_random_labels(seed: int, n: int, classes: int, skew: float) -> None:
    rng = np.random.default_rng(seed)
    weights = np.exp(-skew * np.arange(classes))  # skewed: some classes are often absent
    truth = rng.choice(classes, size=n, p=weights / weights.sum())
    noise = rng.random(n) < 0.4
    prediction = np.where(noise, rng.choice(classes, size=n), truth)

    metrics = compute_metrics(compute_confusion(truth, prediction, num_classes=classes))

    present = np.union1d(truth, prediction)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # sklearn warns about classes only predicted
        assert metrics.oa == pytest.approx(accuracy_score(truth, prediction))
        assert metrics.miou == pytest.approx(jaccard_score(truth, prediction, labels=present, average="macro"))
        assert metrics.fwiou == pytest.approx(jaccard_score(truth, prediction, labels=present, average="weighted"))
        assert metrics.macc == pytest.approx(balanced_accuracy_score(truth, prediction))
        expected_kappa = cohen_kappa_score(truth, prediction)
        per_class = jaccard_score(truth, prediction, labels=present, average=None)
    if math.isnan(expected_kappa):  # one class only, predicted perfectly: our convention is 1
        assert metrics.kappa == 1.0
    else:
        assert metrics.kappa == pytest.approx(expected_kappa)
    np.testing.assert_allclose(metrics.iou[present], per_class)
    assert np.isnan(np.delete(metrics.iou, present)).all()


@pytest.mark.parametrize("seed", range(8))
def test_per_class_iou_accuracy_and_confusion_equal_scikit_learn_with_absent_classes(seed: int) -> None:
    rng = np.random.default_rng(seed)
    classes = 6
    # class 5 never occurs; class 4 is only predicted (a false alarm); the rest occur at random
    truth = rng.choice(4, size=300, p=rng.dirichlet(np.ones(4)))
    prediction = np.where(rng.random(300) < 0.35, rng.choice(5, size=300), truth)
    labels = list(range(classes))

    confusion = compute_confusion(truth, prediction, num_classes=classes)
    metrics = compute_metrics(confusion)

    np.testing.assert_array_equal(confusion, confusion_matrix(truth, prediction, labels=labels))
    present = np.isin(labels, np.union1d(truth, prediction))
    assert not present[5]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # sklearn warns about classes without ground truth
        expected_iou = jaccard_score(truth, prediction, labels=labels, average=None, zero_division=0)
        expected_acc = recall_score(truth, prediction, labels=labels, average=None, zero_division=np.nan)
    np.testing.assert_allclose(metrics.iou[present], expected_iou[present])
    assert np.isnan(metrics.iou[~present]).all()  # absent: NaN here, 0 (zero_division) in scikit-learn
    assert (expected_iou[~present] == 0.0).all()
    np.testing.assert_allclose(metrics.acc, expected_acc)  # NaN where no ground truth, in both
    assert metrics.iou[4] == 0.0 if present[4] else math.isnan(metrics.iou[4])
    np.testing.assert_array_equal(metrics.support, np.bincount(truth, minlength=classes))


def test_confusion_matrix_equals_scikit_learn_and_skips_unlabelled_points() -> None:
    rng = np.random.default_rng(3)
    truth = rng.integers(0, 5, size=500)
    prediction = rng.integers(0, 5, size=500)
    truth_with_gaps = truth.copy()
    truth_with_gaps[:50] = 255  # unlabelled
    valid = np.ones(500, dtype=bool)
    valid[50:80] = False  # padding

    confusion = compute_confusion(truth_with_gaps, prediction, num_classes=5, valid=valid)

    expected = confusion_matrix(truth[80:], prediction[80:], labels=range(5))
    np.testing.assert_array_equal(confusion, expected)


def test_metrics_match_hand_computed_values_on_a_tiny_case() -> None:
    # class 0: 4 points, 3 right, 1 taken for class 1; class 1: 2 points, both right;
    # class 2: 1 point, taken for class 0
    confusion = np.array([[3, 1, 0], [0, 2, 0], [1, 0, 0]])

    m = compute_metrics(confusion)

    assert m.oa == pytest.approx(5 / 7)
    np.testing.assert_allclose(m.iou, [3 / 5, 2 / 3, 0.0])
    assert m.miou == pytest.approx((3 / 5 + 2 / 3 + 0.0) / 3)
    np.testing.assert_allclose(m.acc, [3 / 4, 1.0, 0.0])
    assert m.macc == pytest.approx((3 / 4 + 1.0 + 0.0) / 3)
    assert m.fwiou == pytest.approx(4 / 7 * 3 / 5 + 2 / 7 * 2 / 3)
    # p_o = 35/49, p_e = (4*4 + 2*3 + 1*0)/49 = 22/49 -> kappa = 13/27
    assert m.kappa == pytest.approx(13 / 27)
    assert m.support.tolist() == [4, 2, 1]


def test_classes_absent_from_ground_truth_and_prediction_are_left_out_of_the_means() -> None:
    confusion = np.array([[5, 1, 0], [1, 3, 0], [0, 0, 0]])  # class 2 neither true nor predicted

    m = compute_metrics(confusion)

    assert m.present.tolist() == [True, True, False]
    assert math.isnan(m.iou[2]) and math.isnan(m.acc[2])
    assert m.miou == pytest.approx((5 / 7 + 3 / 5) / 2)
    assert m.macc == pytest.approx((5 / 6 + 3 / 4) / 2)


def test_a_class_predicted_but_absent_from_the_ground_truth_counts_as_zero_iou() -> None:
    confusion = np.array([[4, 0, 1], [0, 5, 0], [0, 0, 0]])  # class 2 only predicted (a false alarm)

    m = compute_metrics(confusion)

    assert m.present.tolist() == [True, True, True]
    assert m.iou[2] == 0.0
    assert m.miou == pytest.approx((4 / 5 + 1.0 + 0.0) / 3)
    assert math.isnan(m.acc[2])  # recall needs ground truth: not in mAcc
    assert m.macc == pytest.approx((4 / 5 + 1.0) / 2)


def test_kappa_is_one_for_a_single_class_scene_predicted_perfectly() -> None:
    m = compute_metrics(np.array([[0, 0], [0, 9]]))

    assert (m.oa, m.miou, m.kappa) == (1.0, 1.0, 1.0)


def test_no_counted_points_give_nan_metrics() -> None:
    m = compute_metrics(np.zeros((5, 5), dtype=np.int64))

    assert all(math.isnan(v) for v in m.scalars().values())
    assert m.total == 0


def test_predictions_outside_the_classes_are_rejected() -> None:
    with pytest.raises(ValueError, match="predictions must lie in 0..2"):
        compute_confusion(np.array([0, 1]), np.array([0, 3]), num_classes=3)


def test_kappa_is_exact_on_huge_confusion_matrices() -> None:
    # p_o = p_e = 1 - 1e-12: chance agreement, kappa 0 (a float test of p_e == 1 took it for 1)
    chance = compute_metrics(np.array([[10**12, 1], [0, 0]], dtype=np.int64))
    single = compute_metrics(np.array([[0, 0], [0, 4 * 10**18]], dtype=np.int64))  # N**2 overflows int64
    skewed = np.array([[10**13, 10**6, 0], [3 * 10**6, 5 * 10**9, 7], [0, 11, 10**4]], dtype=np.int64)

    assert chance.kappa == 0.0
    assert single.kappa == 1.0
    n = skewed.sum()
    p_o = np.trace(skewed) / n
    p_e = float(np.sum(skewed.sum(axis=0).astype(float) * skewed.sum(axis=1).astype(float)) / float(n) ** 2)
    assert compute_metrics(skewed).kappa == pytest.approx((p_o - p_e) / (1 - p_e), rel=1e-4)
