"""Evaluation metrics against hand-computed values."""

from __future__ import annotations

import numpy as np
import pytest

from pointtraj.errors import ValidationError
from pointtraj.evaluate.metrics import (
    agreement_rate,
    disagreement_by_distance,
    label_accuracy,
    normalized_correlation,
    temporal_consistency,
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


def test_normalized_correlation_properties():
    rng = np.random.default_rng(0)
    a = rng.random((50, 8))
    np.testing.assert_allclose(normalized_correlation(a, a), 1.0)
    np.testing.assert_allclose(normalized_correlation(a, 3 * a + 1), 1.0)
    np.testing.assert_allclose(normalized_correlation(a, -a), -1.0)
    ref = np.array([np.corrcoef(x, y)[0, 1] for x, y in zip(a, a[::-1])])
    np.testing.assert_allclose(normalized_correlation(a, a[::-1]), ref)
    assert np.isnan(normalized_correlation(np.ones((1, 3)), a[:1, :3]))[0]


def test_temporal_consistency_lags():
    fps = 2.0
    K = 4
    # Trajectory 0: constant confidences for 10 frames -> NC 1 at every lag it reaches.
    # Trajectory 1: switches to an anti-correlated vector after 2 frames (1 s).
    v = np.array([1.0, 0.0, 0.0, 0.0])
    w = np.array([0.0, 1.0, 1.0, 1.0])
    track = np.r_[np.zeros(10, int), np.ones(6, int)]
    frame = np.r_[np.arange(10), np.arange(3, 9)]
    pooled = np.r_[np.tile(v, (10, 1)), np.tile(v, (2, 1)), np.tile(w, (4, 1))]
    pooled[13, :] = np.nan  # a missing sample (trajectory 1, frame 6)
    out = temporal_consistency(track, frame, pooled, fps, seconds=(1, 2, 4, 9))
    mean1, _, n1 = out[1]
    assert n1 == 2 and mean1 == pytest.approx((1.0 + -1.0) / 2)
    assert out[2][2] == 2  # trajectory 1 reaches lag 4 frames at frame 7
    assert out[4] == (1.0, 0.0, 1)  # only trajectory 0 lives 8 frames
    assert out[9][2] == 0 and np.isnan(out[9][0])
    assert pooled.shape == (16, K)


def test_disagreement_by_distance_and_agreement():
    d = np.array([0.05, 0.07, 0.15, 0.5, 2.0])
    li = np.array([0, 0, 1, 2, 0])
    lj = np.array([0, 1, 1, 3, 1])
    frac, count = disagreement_by_distance(d, li, lj, np.array([0.0, 0.1, 0.2, 1.0]))
    assert count.tolist() == [2, 1, 1]
    np.testing.assert_allclose(frac, [0.5, 0.0, 1.0])
    assert agreement_rate(np.array([1, 2, -1, 3]), np.array([1, 0, 2, -1])) == 0.5
