"""Several recognisers as one: per class, the maximum of their confidences.

The paper combines a body-part segmenter with a bounding-box object detector (Section 4.1);
``combined`` does that for any registered recognisers. Each part outputs the same K classes
(zero where it does not recognise a class); their maps are resized to a common grid (the
finest of them) and combined by the per-class maximum.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from ...errors import ValidationError
from .base import ImageContext, Recognizer

__all__ = ["CombinedRecognizer"]

logger = logging.getLogger(__name__)


class CombinedRecognizer(Recognizer):
    """Per-class maximum of several recognisers.

    Parameters
    ----------
    parts : sequence of Recognizer
        At least one; all with the same ``class_names``.
    """

    name = "combined"

    def __init__(self, parts: Sequence[Recognizer]) -> None:
        if not parts:
            raise ValidationError("combined: needs at least one recogniser")
        names = tuple(parts[0].class_names)
        for p in parts[1:]:
            if tuple(p.class_names) != names:
                raise ValidationError(
                    f"combined: {p.name!r} has other classes than {parts[0].name!r}"
                )
        self.parts = list(parts)
        self.class_names = names
        self.needs_image = any(getattr(p, "needs_image", True) for p in parts)

    @classmethod
    def from_labelset(
        cls,
        labelset,
        recognizers: Sequence[str] = ("body-parts", "object-detector"),
        options: Mapping[str, Mapping[str, Any]] | None = None,
    ) -> CombinedRecognizer:
        """Build the parts by name (``make_recognizer``) for one label set.

        Parameters
        ----------
        labelset : LabelSet
        recognizers : sequence of str
            Registered recogniser names (not ``combined``).
        options : mapping, optional
            Per recogniser name, its options (``{"body-parts": {"threads": 2}}``).
        """
        from . import make_recognizer

        options = dict(options or {})
        unknown = sorted(set(options) - set(recognizers))
        if unknown:
            raise ValidationError(
                f"combined: options for {unknown[0]!r}, which is not among the recognizers "
                f"({', '.join(recognizers)})"
            )
        if "combined" in recognizers:
            raise ValidationError("combined: cannot contain itself")
        return cls([make_recognizer(n, labelset, **dict(options.get(n, {}))) for n in recognizers])

    def recognize(self, image: np.ndarray, context: ImageContext | None = None) -> np.ndarray:
        """(h, w, K): the finest part's grid, each class the maximum over the parts."""
        return self._combine([p.recognize(image, context) for p in self.parts])

    def recognize_people(
        self, image: np.ndarray, context: ImageContext | None = None
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """The combined maps, and the person-id map of the first part that gives one."""
        results = [p.recognize_people(image, context) for p in self.parts]
        people = next((ids for _, ids in results if ids is not None), None)
        return self._combine([m for m, _ in results]), people

    def _combine(self, maps: list[np.ndarray]) -> np.ndarray:
        """(h, w, K): the finest map's grid, each class the maximum over ``maps``."""
        import cv2

        h, w = max((m.shape[:2] for m in maps), key=lambda s: s[0] * s[1])
        out = np.zeros((h, w, len(self.class_names)), np.float32)
        for m in maps:
            if m.shape[:2] != (h, w):
                # Resize channel blocks (OpenCV takes at most 512 channels at once).
                m = np.concatenate(
                    [
                        cv2.resize(
                            m[..., k : k + 256], (w, h), interpolation=cv2.INTER_LINEAR
                        ).reshape(h, w, -1)
                        for k in range(0, m.shape[2], 256)
                    ],
                    axis=2,
                )
            np.maximum(out, m, out=out)
        return out
