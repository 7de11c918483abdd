"""Evaluation metrics over plain arrays: the paper's three studies and ground-truth accuracy.

All functions are vectorised and take no file paths; :mod:`pointtraj.evaluate.study` gathers
their inputs from a work folder.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ValidationError, check_array

__all__ = [
    "LabelAccuracy",
    "label_accuracy",
    "normalized_correlation",
    "temporal_consistency",
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


def normalized_correlation(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise normalised correlation (Pearson) of two sets of K-vectors.

    Parameters
    ----------
    a, b : (N, K) float ndarray

    Returns
    -------
    (N,) float ndarray
        In [-1, 1]; NaN where either row is constant or has NaN.

    Examples
    --------
    >>> normalized_correlation(np.array([[1.0, 0.0, 0.0]]), np.array([[0.9, 0.1, 0.0]])).round(3)
    array([0.995])
    """
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if a.shape != b.shape or a.ndim != 2:
        raise ValidationError(f"normalized_correlation: shapes {a.shape} and {b.shape} differ")
    a = a - a.mean(axis=1, keepdims=True)
    b = b - b.mean(axis=1, keepdims=True)
    den = np.sqrt(np.sum(a * a, axis=1) * np.sum(b * b, axis=1))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(den > 0, np.sum(a * b, axis=1) / den, np.nan)


def temporal_consistency(
    track: np.ndarray,
    frame: np.ndarray,
    pooled: np.ndarray,
    fps: float,
    seconds: tuple[int, ...] = (1, 3, 5, 7, 9, 11, 13, 15),
    tolerance_frames: int = 0,
) -> dict[int, tuple[float, float, int]]:
    """The paper's Table 1: NC between a trajectory's first pooled confidence and ``s`` seconds later.

    Parameters
    ----------
    track : (S,) int ndarray
        Trajectory of each sample.
    frame : (S,) int ndarray
        Frame of each sample.
    pooled : (S, K) float ndarray
        Pooled confidences per sample (NaN rows: no camera above the visibility threshold).
    fps : float
        Frame rate, to turn seconds into frames.
    seconds : tuple of int
        Lags.
    tolerance_frames : int
        Accept a sample up to this many frames after the exact lag (when the exact frame has no
        valid sample).

    Returns
    -------
    dict
        ``{s: (mean NC, std NC, number of trajectories)}``; NaN mean where no trajectory lives
        that long.
    """
    track = np.asarray(track, np.int64)
    frame = np.asarray(frame, np.int64)
    pooled = np.asarray(pooled, np.float64)
    valid = np.all(np.isfinite(pooled), axis=1)
    track, frame, pooled = track[valid], frame[valid], pooled[valid]
    order = np.lexsort((frame, track))
    track, frame, pooled = track[order], frame[order], pooled[order]
    if len(track) == 0:
        return {s: (float("nan"), float("nan"), 0) for s in seconds}
    first_idx = np.concatenate([[0], np.nonzero(np.diff(track))[0] + 1])
    first_of = np.full(track.max() + 1, -1, np.int64)
    first_of[track[first_idx]] = first_idx
    start = first_of[track]  # (S,) index of each sample's trajectory start
    lag = frame - frame[start]
    out = {}
    for s in seconds:
        target = int(round(s * fps))
        hit = (lag >= target) & (lag <= target + tolerance_frames)
        # Keep the earliest hit per trajectory.
        idx = np.nonzero(hit)[0]
        if len(idx) == 0:
            out[s] = (float("nan"), float("nan"), 0)
            continue
        _, first = np.unique(track[idx], return_index=True)
        idx = idx[first]
        nc = normalized_correlation(pooled[start[idx]], pooled[idx])
        nc = nc[np.isfinite(nc)]
        out[s] = (
            (float(nc.mean()), float(nc.std()), len(nc))
            if len(nc)
            else (float("nan"), float("nan"), 0)
        )
    return out


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
