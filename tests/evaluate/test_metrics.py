"""Evaluation metrics against hand-computed values."""

from __future__ import annotations

import numpy as np
import pytest

from pointtraj.errors import ValidationError
from pointtraj.evaluate.metrics import (
    agreement_rate,
    disagreement_by_distance,
    label_accuracy,
)


def test_label_accuracy_weights_and_confusion():
    pred = np.array([0, 0, 1, 2, 2, -1])
    true = np.array([0, 1, 1, 2, 0, -1])  # last item ignored (no truth)
    acc = label_accuracy(pred, true, 3, weights=np.array([1, 1, 1, 1, 6, 9]))
    assert acc.overall == pytest.approx(3 / 10)
    assert acc.support.tolist() == [2, 2, 1]
    np.testing.assert_allclose(acc.per_class, [0.5, 0.5, 1.0])
    assert acc.confusion[0].tolist() == [1, 0, 1] and acc.confusion[1].tolist() == [1, 1, 0]
    with pytest.raises(ValidationError, match="num_classes"):
        label_accuracy(np.array([0]), np.array([5]), 3)


def test_disagreement_by_distance_and_agreement():
    d = np.array([0.05, 0.07, 0.15, 0.5, 2.0])
    li = np.array([0, 0, 1, 2, 0])
    lj = np.array([0, 1, 1, 3, 1])
    frac, count = disagreement_by_distance(d, li, lj, np.array([0.0, 0.1, 0.2, 1.0]))
    assert count.tolist() == [2, 1, 1]
    np.testing.assert_allclose(frac, [0.5, 0.0, 1.0])
    assert agreement_rate(np.array([1, 2, -1, 3]), np.array([1, 0, 2, -1])) == 0.5
