"""2D recognisers: each turns an image into per-pixel class confidences L2D (h, w, K).

Recognisers are registered by name in :data:`RECOGNIZERS` as ``"module:attribute"`` strings and
imported only when made, so heavy dependencies (onnxruntime, mediapipe) load on demand.
:func:`make_recognizer` builds one for a label set: a class with a ``from_labelset(labelset,
**options)`` classmethod is built through it; any other class is called as
``cls(labelset.names, **options)``, with ``mapping=`` (from ``[recognizers.<name>] map`` in
labels.toml) and the table's other keys added unless ``options`` already sets them.
"""

from __future__ import annotations

import importlib
import json
import logging
import os
from dataclasses import dataclass, field
from typing import Any

from ...errors import ValidationError
from ...labelset import LabelSet
from .base import ImageContext, Recognizer

__all__ = ["RECOGNIZERS", "make_recognizer", "Recognizer", "RecognizerSpec", "ImageContext"]

logger = logging.getLogger(__name__)

#: Recogniser name -> "module:attribute" of its class (or factory).
RECOGNIZERS: dict[str, str] = {
    "simulated": "pointtraj.semantics.recognizers.simulated:SimulatedRecognizer",
    "precomputed": "pointtraj.semantics.recognizers.precomputed:PrecomputedRecognizer",
    "onnx-segmentation": "pointtraj.semantics.recognizers.onnx:OnnxSegmentationRecognizer",
    "onnx-detection": "pointtraj.semantics.recognizers.onnx:OnnxDetectionRecognizer",
    "body-parts": "pointtraj.semantics.recognizers.bodyparts:BodyPartRecognizer",
    "object-detector": "pointtraj.semantics.recognizers.detector:ObjectDetectorRecognizer",
    "charuco-board": "pointtraj.semantics.recognizers.board:CharucoBoardRecognizer",
    "combined": "pointtraj.semantics.recognizers.combined:CombinedRecognizer",
}


def make_recognizer(name: str, labelset: LabelSet, **options: Any) -> Recognizer:
    """Build the recogniser registered as ``name`` for a label set.

    Parameters
    ----------
    name : str
        A key of :data:`RECOGNIZERS`.
    labelset : LabelSet
        The capture's classes; the recogniser outputs one channel per class.
    **options
        Recogniser-specific keyword options.

    Returns
    -------
    Recognizer

    Raises
    ------
    ValidationError
        If ``name`` is unknown (the valid names are listed) or its module cannot be imported.

    Examples
    --------
    >>> rec = make_recognizer("simulated", LabelSet.default(), noise="low")
    >>> rec.name, len(rec.class_names)
    ('simulated', 16)
    """
    if name not in RECOGNIZERS:
        raise ValidationError(
            f"recognizer: unknown name {name!r} (valid: {', '.join(sorted(RECOGNIZERS))})"
        )
    module_name, attr = RECOGNIZERS[name].split(":")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise ValidationError(f"recognizer {name!r} is not available: {exc}") from None
    factory = getattr(module, attr)
    if hasattr(factory, "from_labelset"):
        recognizer = factory.from_labelset(labelset, **options)
    else:
        kwargs = dict(labelset.options(name))
        mapping = labelset.mapping(name)
        if mapping:
            kwargs["mapping"] = mapping
        kwargs.update(options)
        recognizer = factory(labelset.names, **kwargs)
    logger.info("recogniser %s with %d classes", name, len(labelset))
    return recognizer


@dataclass(frozen=True)
class RecognizerSpec:
    """How to make a recogniser: what travels to a Dask worker instead of the recogniser.

    A worker makes it on its first task and keeps it for the next ones (:meth:`cached`), so a
    model is loaded once per worker process.

    Attributes
    ----------
    name : str
        A key of :data:`RECOGNIZERS`.
    labels : str or None
        The capture's ``labels.toml`` (None: the default label set).
    options : dict
        The recogniser's keyword options.
    """

    name: str
    labels: str | None = None
    options: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.name not in RECOGNIZERS:
            raise ValidationError(
                f"recognizer: unknown name {self.name!r} (valid: {', '.join(sorted(RECOGNIZERS))})"
            )

    @property
    def labelset(self) -> LabelSet:
        """The label set (its names are the recogniser's classes)."""
        return LabelSet.default() if self.labels is None else LabelSet.load(self.labels)

    @property
    def class_names(self) -> tuple[str, ...]:
        """The recogniser's K classes."""
        return tuple(self.labelset.names)

    def make(self) -> Recognizer:
        """A new recogniser.

        Raises
        ------
        ValidationError
            On an option the recogniser does not take, or a recogniser that cannot be imported.
        """
        try:
            return make_recognizer(self.name, self.labelset, **self.options)
        except TypeError as exc:  # an option the recogniser does not take
            raise ValidationError(f"recognizer {self.name!r}: {exc}") from None

    def cached(self) -> Recognizer:
        """The recogniser, made once per process (:func:`pointtraj.executor.worker_cache`)."""
        from ...executor import worker_cache

        stamp = None
        if self.labels is not None:
            st = os.stat(self.labels)
            stamp = (st.st_size, st.st_mtime_ns)
        key = (
            "recognizer",
            self.name,
            self.labels,
            stamp,
            json.dumps(self.options, sort_keys=True, default=str),
        )
        return worker_cache(key, self.make)
