"""Evaluation metrics over plain arrays: the paper's studies and ground-truth accuracy.

All functions are vectorised and take no file paths; :mod:`pointtraj.evaluate.study` gathers
their inputs from a work folder. The temporal-consistency study (the paper's normalised
correlation, NC) is :meth:`pointtraj.semantics.SemanticMap.temporal_consistency`, over
:func:`pointtraj.semantics.normalized_correlation`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ValidationError, check_array

__all__ = [
    "LabelAccuracy",
    "label_accuracy",
    "disagreement_by_distance",
    "agreement_rate",
]


@dataclass(frozen=True)
class LabelAccuracy:
    """Accuracy of predicted labels against ground truth.

    Attributes
    ----------
    overall : float
        Fraction of items whose prediction equals the truth (NaN if there are none).
    per_class : (K,) float ndarray
        Recall per true class (NaN for classes absent from the truth).
    support : (K,) int ndarray
        Items per true class.
    confusion : (K, K) int ndarray
        ``confusion[true, predicted]``; predictions outside [0, K) are not counted there.
    """

    overall: float
    per_class: np.ndarray
    support: np.ndarray
    confusion: np.ndarray


def label_accuracy(
    predicted: np.ndarray, truth: np.ndarray, num_classes: int, weights: np.ndarray | None = None
) -> LabelAccuracy:
    """Compare predicted and true labels.

    Parameters
    ----------
    predicted : (M,) int ndarray
        Predicted class per item (-1 = no prediction, counted as wrong).
    truth : (M,) int ndarray
        True class per item; items with truth < 0 are ignored.
    num_classes : int
        K.
    weights : (M,) float ndarray, optional
        Item weights for ``overall`` (e.g. trajectory lengths); default 1.

    Returns
    -------
    LabelAccuracy

    Examples
    --------
    >>> acc = label_accuracy(np.array([0, 1, 1, -1]), np.array([0, 1, 0, 1]), 2)
    >>> acc.overall, acc.per_class.tolist(), acc.confusion.tolist()
    (0.5, [0.5, 0.5], [[1, 1], [0, 1]])
    """
    p = check_array("predicted", predicted, (None,), dtype=np.int64)
    t = check_array("truth", truth, (p.shape[0],), dtype=np.int64)
    w = np.ones(len(p)) if weights is None else check_array("weights", weights, (len(p),))
    keep = t >= 0
    p, t, w = p[keep], t[keep], w[keep]
    if np.any(t >= num_classes):
        raise ValidationError(f"truth has labels >= num_classes ({num_classes})")
    correct = p == t
    overall = float(np.sum(w * correct) / np.sum(w)) if len(t) else float("nan")
    support = np.bincount(t, minlength=num_classes)
    hits = np.bincount(t[correct], minlength=num_classes)
    with np.errstate(invalid="ignore", divide="ignore"):
        per_class = np.where(support > 0, hits / np.maximum(support, 1), np.nan)
    valid = (p >= 0) & (p < num_classes)
    confusion = np.zeros((num_classes, num_classes), np.int64)
    np.add.at(confusion, (t[valid], p[valid]), 1)
    return LabelAccuracy(overall, per_class, support, confusion)


def disagreement_by_distance(
    distance: np.ndarray, label_i: np.ndarray, label_j: np.ndarray, bins: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Fraction of pairs with different labels, per distance bin (the paper's Figure 6).

    Parameters
    ----------
    distance : (Q,) float ndarray
        Distance between the two trajectories of each pair, metres.
    label_i, label_j : (Q,) int ndarray
        Their labels.
    bins : (B + 1,) float ndarray
        Bin edges.

    Returns
    -------
    fraction : (B,) float ndarray
        NaN for empty bins.
    count : (B,) int ndarray
    """
    d = np.asarray(distance, float)
    b = np.digitize(d, bins) - 1
    ok = (b >= 0) & (b < len(bins) - 1)
    diff = (np.asarray(label_i) != np.asarray(label_j))[ok]
    count = np.bincount(b[ok], minlength=len(bins) - 1)
    bad = np.bincount(b[ok], weights=diff.astype(float), minlength=len(bins) - 1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, bad / np.maximum(count, 1), np.nan), count


def agreement_rate(predicted: np.ndarray, observed: np.ndarray) -> float:
    """Fraction of items where two label arrays agree, ignoring items where either is < 0."""
    p = np.asarray(predicted)
    o = np.asarray(observed)
    ok = (p >= 0) & (o >= 0)
    return float(np.mean(p[ok] == o[ok])) if ok.any() else float("nan")
