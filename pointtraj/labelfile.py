"""``labels.npz`` and ``labels.csv``: the label of every trajectory (``data_specs/labels.md``)."""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .errors import FileFormatError, ValidationError

__all__ = ["TrajectoryLabels", "save_labels", "load_labels", "FORMAT_VERSION"]

FORMAT_VERSION = 1


@dataclass(eq=False)
class TrajectoryLabels:
    """The labelling stage's result for M trajectories over K classes.

    Attributes
    ----------
    labels : (M,) int64 ndarray
        Class index per trajectory (order of ``class_names``).
    confidence : (M,) float32 ndarray
        Normalised L3D of the assigned label (``L3D[l] / sum L3D``; 0 without semantics).
    argmax : (M,) int64 ndarray
        Argmax of L3D, the initial labelling.
    class_names : tuple of K str
    energy : (S + 1,) float64 ndarray
        Energy at the start and after each sweep (non-increasing).
    pooling : str
        The L3D pooling labelled.
    params : dict
        The labelling parameters used.
    instance : (M,) int64 ndarray or None
        Person id per trajectory (0 the largest person; -1: on no person), from
        :func:`pointtraj.instances.assign_instances`; None in files written before instances.
    """

    labels: np.ndarray
    confidence: np.ndarray
    argmax: np.ndarray
    class_names: tuple[str, ...]
    energy: np.ndarray = field(default_factory=lambda: np.zeros(0))
    pooling: str = "view"
    params: dict[str, Any] = field(default_factory=dict)
    instance: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.class_names = tuple(str(n) for n in self.class_names)
        self.labels = np.asarray(self.labels, np.int64)
        M = self.labels.shape[0]
        self.confidence = np.asarray(self.confidence, np.float32)
        self.argmax = np.asarray(self.argmax, np.int64)
        self.energy = np.asarray(self.energy, np.float64)
        for name in ("labels", "confidence", "argmax"):
            arr = getattr(self, name)
            if arr.shape != (M,):
                raise ValidationError(f"{name}: expected shape ({M},), got {arr.shape}")
        if self.instance is not None:
            self.instance = np.asarray(self.instance, np.int64)
            if self.instance.shape != (M,):
                raise ValidationError(f"instance: expected shape ({M},), got {self.instance.shape}")
            if M and self.instance.min() < -1:
                raise ValidationError("instance: ids must be >= -1 (-1: on no person)")
        K = len(self.class_names)
        if M and (self.labels.min() < -1 or self.labels.max() >= K):
            raise ValidationError(f"labels: must lie in [-1, {K}), the {K} classes")

    def __len__(self) -> int:
        return int(self.labels.shape[0])

    def names(self) -> np.ndarray:
        """(M,) str ndarray: the class name of each trajectory ("" where unlabelled)."""
        table = np.array([*self.class_names, ""], dtype=str)
        return table[np.where(self.labels >= 0, self.labels, len(self.class_names))]


def save_labels(
    labels: TrajectoryLabels,
    path: str | os.PathLike,
    first_frame: np.ndarray | None = None,
    lengths: np.ndarray | None = None,
) -> None:
    """Write ``labels.npz`` and, beside it, ``labels.csv``, both atomically.

    Parameters
    ----------
    labels : TrajectoryLabels
    path : path-like
        The ``.npz`` file; the CSV takes the same name with ``.csv``.
    first_frame, lengths : (M,) int ndarray, optional
        Per trajectory, for the CSV's ``first_frame`` and ``length`` columns (empty if absent).
    """
    from .atomic import save_npz_atomic, write_text_atomic

    path = Path(path)
    save_npz_atomic(
        path,
        format_version=np.int64(FORMAT_VERSION),
        labels=labels.labels,
        confidence=labels.confidence,
        argmax=labels.argmax,
        class_names=np.array(labels.class_names, dtype=str),
        energy=labels.energy,
        pooling=np.array(labels.pooling),
        params=np.array(json.dumps(labels.params, sort_keys=True)),
        **({} if labels.instance is None else {"instance": labels.instance}),
    )
    M = len(labels)
    ff = [""] * M if first_frame is None else np.asarray(first_frame).tolist()
    ln = [""] * M if lengths is None else np.asarray(lengths).tolist()
    inst = [-1] * M if labels.instance is None else labels.instance.tolist()
    lines = ["track_id,label,label_name,confidence,first_frame,length,instance"]
    lines += [
        f"{m},{lab},{name},{c:.4f},{f},{n},{i}"
        for m, lab, name, c, f, n, i in zip(
            range(M),
            labels.labels.tolist(),
            labels.names(),
            labels.confidence.tolist(),
            ff,
            ln,
            inst,
        )
    ]
    write_text_atomic(path.with_suffix(".csv"), "\n".join(lines) + "\n")


def load_labels(path: str | os.PathLike) -> TrajectoryLabels:
    """Read ``labels.npz``.

    Raises
    ------
    FileFormatError
        Missing file, missing array, other format version or inconsistent shapes.
    """
    from .npzfile import load_npz

    path = Path(path)
    arrays = load_npz(
        path,
        ("format_version", "labels", "class_names"),
        "a labels file",
        hint="run `pointtraj label` first",
    )
    if int(arrays["format_version"]) != FORMAT_VERSION:
        raise FileFormatError(
            path, f"format_version {int(arrays['format_version'])} (expected {FORMAT_VERSION})"
        )
    labels = arrays["labels"]
    try:
        params = json.loads(str(arrays["params"])) if "params" in arrays else {}
        return TrajectoryLabels(
            labels=labels,
            confidence=arrays.get("confidence", np.zeros(len(labels), np.float32)),
            argmax=arrays.get("argmax", labels),
            class_names=tuple(str(n) for n in arrays["class_names"]),
            energy=arrays.get("energy", np.zeros(0)),
            pooling=str(arrays.get("pooling", "view")),
            params=params,
            instance=arrays.get("instance"),
        )
    except (ValidationError, json.JSONDecodeError) as exc:
        raise FileFormatError(path, str(exc)) from None
