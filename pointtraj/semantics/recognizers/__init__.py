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
import logging
from typing import Any

from ...errors import ValidationError
from ...labelset import LabelSet
from .base import ImageContext, Recognizer

__all__ = ["RECOGNIZERS", "make_recognizer", "Recognizer", "ImageContext"]

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
