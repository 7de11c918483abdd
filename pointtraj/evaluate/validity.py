"""Predictive validity on held-out cameras: the paper's cross-validation (Section 7, Figure 7).

Label each trajectory from a subset of the cameras, project it into a held-out camera, and count
how often its label agrees with the recognition there. It needs no ground truth, so it runs on
real captures. We gather the per-camera samples of a random subset of trajectories in one
streaming pass (:func:`collect_camera_samples`), after which every camera subset is a cheap
pooling over columns (:func:`predictive_validity`).

Labels here are the argmax of the pooled-then-time-averaged L3D (the 3D semantic map), so the
study compares poolings directly, as the paper's figure does.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from ..errors import ValidationError
from ..executor import Executor, SerialExecutor
from ..trajectories import Trajectories, dequantize_visibility

__all__ = [
    "CameraSamples",
    "CaptureRecognizer",
    "collect_camera_samples",
    "predictive_validity",
    "camera_counts",
]

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class CameraSamples:
    """Per-camera confidences of a subset of point-frames.

    Attributes
    ----------
    track : (S,) int64 ndarray
        Trajectory of each sample (index into the full store).
    frame : (S,) int64 ndarray
    L : (S, C, K) float16 ndarray
        Confidences sampled at the projection in each camera (0 outside the image).
    V : (S, C) float32 ndarray
        Visibility from the trajectory store.
    in_image : (S, C) bool ndarray
    observed : (S, C) int16 ndarray
        The recogniser's label at the projection: argmax of L where its maximum reaches
        ``min_confidence``, else -1 (nothing recognised there).
    camera_names : list of str
    """

    track: np.ndarray
    frame: np.ndarray
    L: np.ndarray
    V: np.ndarray
    in_image: np.ndarray
    observed: np.ndarray
    camera_names: list[str]


def collect_camera_samples(
    trajectories: Trajectories,
    rig,
    recognize: Callable[[int, int], np.ndarray],
    num_classes: int,
    max_tracks: int = 3000,
    frame_stride: int = 1,
    min_confidence: float = 0.5,
    seed: int = 0,
    progress: Callable[[int], None] | None = None,
    visibility: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None,
    executor: Executor | None = None,
) -> CameraSamples:
    """Sample every camera's confidences at a random subset of trajectories, frame by frame.

    Parameters
    ----------
    trajectories : Trajectories
    rig : CameraRig
        Cameras in the store's order.
    recognize : callable ``(camera_index, frame) -> (h, w, K) L2D``
        Runs the recogniser on one image (the map is sampled, then dropped). On a Dask
        executor it must pickle (:class:`CaptureRecognizer`).
    num_classes : int
        K.
    max_tracks : int
        Trajectories sampled (all when there are fewer).
    frame_stride : int
        Use every n-th frame of :attr:`Trajectories.occupied_frames`.
    min_confidence : float
        Below this maximum confidence a projection counts as "nothing recognised".
    seed : int
    progress : callable, optional
        Called with the number of frames done after each frame.
    visibility : callable ``(xyz (N, 3), V (N, C)) -> (N, C)``, optional
        The visibility that pooling uses, from all of a frame's points and their stored
        visibility (e.g. :func:`pointtraj.semantics.semantic_map.geometric_visibility`);
        default: the stored visibility.
    executor : Executor, optional
        Where the frames' recognition and sampling run, one task a frame (default: serially,
        here).

    Returns
    -------
    CameraSamples
    """
    if len(rig) != trajectories.num_cameras:
        raise ValidationError(
            f"rig has {len(rig)} cameras, the trajectories {trajectories.num_cameras}"
        )
    M = trajectories.num_trajectories
    rng = np.random.default_rng(seed)
    chosen = np.zeros(M, bool)
    chosen[rng.choice(M, size=min(M, max_tracks), replace=False)] = True
    parts: dict[str, list[np.ndarray]] = {k: [] for k in ("track", "frame", "L", "V", "inimg")}
    items = []  # (frame, the chosen trajectories' points there): one task each
    for t in trajectories.occupied_frames[::frame_stride]:
        rows = trajectories.frame_rows(t)
        keep = chosen[trajectories.row_track[rows]]
        V_rows = None
        if visibility is not None and keep.any():
            V_all = dequantize_visibility(trajectories.visibility[rows])
            V_rows = visibility(trajectories.xyz[rows], V_all)[keep]
        rows = rows[keep]
        if len(rows):
            items.append((int(t), trajectories.xyz[rows]))
            parts["track"].append(trajectories.row_track[rows])
            parts["frame"].append(np.full(len(rows), t, np.int64))
            parts["V"].append(
                dequantize_visibility(trajectories.visibility[rows]) if V_rows is None else V_rows
            )
        elif progress is not None:
            progress(1)
    executor = executor or SerialExecutor()
    for L, in_image in executor.map(
        _frame_samples,
        items,
        label="predictive validity",
        context=(rig, recognize, num_classes),
    ):
        parts["L"].append(L)
        parts["inimg"].append(in_image)
        if progress is not None:
            progress(1)
    if not parts["track"]:
        raise ValidationError("no trajectory point-frames to sample")
    L = np.concatenate(parts["L"])
    Lf = L.astype(np.float32)
    observed = np.where(Lf.max(axis=2) >= min_confidence, Lf.argmax(axis=2), -1).astype(np.int16)
    return CameraSamples(
        track=np.concatenate(parts["track"]),
        frame=np.concatenate(parts["frame"]),
        L=L,
        V=np.concatenate(parts["V"]),
        in_image=np.concatenate(parts["inimg"]),
        observed=observed,
        camera_names=list(rig.names),
    )


def _frame_samples(context: tuple, item: tuple) -> tuple[np.ndarray, np.ndarray]:
    """One frame of :func:`collect_camera_samples` (an executor task).

    ``context`` is (rig, recognize, K), ``item`` (frame, (n, 3) points). Returns the (n, C, K)
    float16 confidences at the points' projections (0 outside the image) and the (n, C)
    in-image mask.
    """
    from ..semantics.sampling import sample_confidences

    rig, recognize, K = context
    t, xyz = item
    proj = rig.project(np.asarray(xyz))
    L = np.zeros((len(xyz), len(rig), K), np.float16)
    for c in range(len(rig)):
        if proj.in_image[c].any():
            L[:, c] = sample_confidences(recognize(c, t), proj.pixels[c], rig[c].size)
    return L, proj.in_image.T


class CaptureRecognizer:
    """``recognize(camera_index, frame)`` of :func:`collect_camera_samples` from a capture and
    a recogniser: unlike a closure, it can be sent to executor workers.

    Parameters
    ----------
    capture : Capture
        The open capture (pickled to each worker, it reads its own files there).
    names : sequence of str
        The cameras, in the store's order.
    recognizer : Recognizer or RecognizerSpec
        On a Dask cluster give the spec, as the semantics stage does: each worker then makes
        the recogniser once (:meth:`~pointtraj.semantics.recognizers.RecognizerSpec.cached`).
    """

    def __init__(self, capture, names: Sequence[str], recognizer) -> None:
        self.capture = capture
        self.names = list(names)
        self.recognizer = recognizer

    def __call__(self, c: int, t: int) -> np.ndarray:
        from ..semantics.recognizers import ImageContext, RecognizerSpec

        recognizer = self.recognizer
        if isinstance(recognizer, RecognizerSpec):
            recognizer = recognizer.cached()
        name = self.names[c]
        image = self.capture.read(name, t) if getattr(recognizer, "needs_image", True) else None
        return recognizer.recognize(image, ImageContext(name, t, os.fspath(self.capture.path)))


def camera_counts(num_cameras: int) -> list[int]:
    """The paper's x-axis: 1, 2, 5, 10, 20, ... up to all but the held-out camera.

    Examples
    --------
    >>> camera_counts(4), camera_counts(69)
    ([1, 2, 3], [1, 2, 5, 10, 20, 30, 40, 50, 60, 68])
    """
    top = num_cameras - 1
    base = [1, 2, 5, 10, 20] + list(range(30, top, 10))
    return sorted({n for n in base if n < top} | {top}) if top >= 1 else []


def _track_labels(inverse: np.ndarray, num_tracks: int, pooled: np.ndarray) -> np.ndarray:
    """Argmax of the time-averaged pooled confidences per trajectory (NaN rows skipped).

    Parameters
    ----------
    inverse : (S,) int ndarray
        Each sample's trajectory, numbered 0 .. num_tracks - 1.
    num_tracks : int
    pooled : (S, K) float ndarray

    Returns
    -------
    (num_tracks,) int64 ndarray
        Class index; -1 where no sample has a positive confidence.
    """
    ok = np.all(np.isfinite(pooled), axis=1)
    inv = inverse[ok]
    sums = np.stack(
        [
            np.bincount(inv, weights=pooled[ok, k], minlength=num_tracks)
            for k in range(pooled.shape[1])
        ],
        axis=1,
    )  # (T, K): one bincount a class, summed in sample order
    return np.where(sums.max(axis=1) > 0, sums.argmax(axis=1), -1)


def predictive_validity(
    samples: CameraSamples,
    eps_e: float,
    poolings: Sequence[str] = ("view", "average"),
    counts: Sequence[int] | None = None,
    held_out: Sequence[int] | None = None,
    draws: int = 3,
    seed: int = 0,
    support: dict[int, dict[str, int]] | None = None,
) -> dict[str, dict[int, float]]:
    """Agreement of labels from n cameras with the recognition in a held-out camera.

    Parameters
    ----------
    samples : CameraSamples
    eps_e : float
        Visibility threshold: the held-out camera counts a sample only when ``V > eps_e`` there;
        pooling uses it too.
    poolings : sequence of str
        Pooling methods (see :func:`pointtraj.semantics.pooling.pool_views`).
    counts : sequence of int, optional
        Numbers of labelling cameras (default :func:`camera_counts`).
    held_out : sequence of int, optional
        Cameras held out in turn (default: all, at most 8 spread evenly).
    draws : int
        Random camera subsets per (held-out camera, count).
    seed : int
    support : dict, optional
        Filled with what each figure rests on: ``support[n]`` = ``{"point_frames": distinct
        samples compared at least once, "trajectories": their distinct trajectories,
        "comparisons": (sample, held-out camera, draw) comparisons, the figure's denominator}``.
        A figure is computed only where the held-out camera sees the point and recognises a
        class there, and every pooling labels it, so it can rest on a small part of the samples.

    Returns
    -------
    dict
        ``{pooling: {n: mean agreement}}``, averaged over held-out cameras and draws
        (weighted by the number of evaluated samples). Only samples whose trajectory every
        pooling labels from the subset count, so that the poolings are compared on the same
        samples.
    """
    from ..semantics.pooling import pool_views

    C = len(samples.camera_names)
    if C < 2:
        raise ValidationError("predictive validity needs at least 2 cameras")
    counts = list(counts) if counts is not None else camera_counts(C)
    if held_out is None:
        held_out = np.unique(np.linspace(0, C - 1, min(C, 8)).round().astype(int)).tolist()
    rng = np.random.default_rng(seed)
    # cameras first, each camera's samples contiguous: a subset of cameras is one block copy
    L = np.ascontiguousarray(samples.L.transpose(1, 0, 2), dtype=np.float32)  # (C, S, K)
    V = np.ascontiguousarray(samples.V.T)  # (C, S)
    in_image = np.ascontiguousarray(samples.in_image.T)  # (C, S)
    tracks, inverse = np.unique(samples.track, return_inverse=True)
    out: dict[str, dict[int, float]] = {p: {} for p in poolings}
    for n in counts:
        hits = dict.fromkeys(poolings, 0.0)
        total = dict.fromkeys(poolings, 0.0)
        compared = np.zeros(len(samples.track), bool)  # (S,) compared at least once
        for h in held_out:
            evaluate = (samples.V[:, h] > eps_e) & (samples.observed[:, h] >= 0)
            if not evaluate.any():
                continue
            others = np.array([c for c in range(C) if c != h])
            if n > len(others):
                continue
            obs = samples.observed[evaluate, h]
            for _ in range(draws if n < len(others) else 1):
                subset = np.sort(rng.choice(others, size=n, replace=False))
                L_sub, V_sub, in_sub = L[subset], V[subset].T, in_image[subset]
                pred = {}
                for p in poolings:
                    pooled = pool_views(L_sub, V_sub, eps_e, p, in_image=in_sub, camera_axis=0)
                    labels = _track_labels(inverse, len(tracks), pooled)
                    pred[p] = labels[inverse[evaluate]]
                # Compare the poolings on the same samples: those every pooling labels (a
                # pooling that keeps only visible cameras labels fewer trajectories).
                both = np.all([pred[p] >= 0 for p in poolings], axis=0)
                compared[np.flatnonzero(evaluate)[both]] = True
                for p in poolings:
                    hits[p] += float(np.sum(pred[p][both] == obs[both]))
                    total[p] += float(both.sum())
        for p in poolings:
            out[p][n] = hits[p] / total[p] if total[p] else float("nan")
        if support is not None:
            support[n] = {
                "point_frames": int(compared.sum()),
                "trajectories": int(len(np.unique(samples.track[compared]))),
                "comparisons": int(next(iter(total.values()), 0.0)),
            }
    return out
