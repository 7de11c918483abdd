"""Confidence maps computed elsewhere, read from files.

Layout: ``<directory>/<camera>/<frame:06d>.npz`` holding an array ``L2D`` of shape (h, w, K)
(float16 or float32, values in [0, 1]), or ``<directory>/<camera>/<frame:06d>.npy`` holding that
array directly. K must equal the number of label-set classes, in labels.toml order.
"""

from __future__ import annotations

import logging
import os
import zipfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ...errors import FileFormatError, ValidationError
from ...npzfile import load_npz
from .base import ImageContext, Recognizer

__all__ = ["PrecomputedRecognizer", "confidence_map_path", "save_confidence_map"]

logger = logging.getLogger(__name__)


def confidence_map_path(directory: str | os.PathLike, camera: str, frame: int) -> Path:
    """The ``.npz`` path of one map (``<directory>/<camera>/<frame:06d>.npz``)."""
    return Path(directory) / camera / f"{int(frame):06d}.npz"


def save_confidence_map(
    directory: str | os.PathLike, camera: str, frame: int, L2D: np.ndarray
) -> Path:
    """Write one map as float16 ``.npz`` (atomically), in the layout this recogniser reads.

    Parameters
    ----------
    directory : path-like
    camera : str
    frame : int
    L2D : (h, w, K) float ndarray

    Returns
    -------
    pathlib.Path
        The written file.
    """
    from ...atomic import save_npz_atomic

    L2D = np.asarray(L2D)
    if L2D.ndim != 3:
        raise ValidationError(f"L2D: expected shape (h, w, K), got {L2D.shape}")
    path = confidence_map_path(directory, camera, frame)
    save_npz_atomic(path, compress=True, L2D=L2D.astype(np.float16))
    return path


class PrecomputedRecognizer(Recognizer):
    """Reads L2D maps from ``<directory>/<camera>/<frame:06d>.npz`` (or ``.npy``).

    Parameters
    ----------
    class_names : sequence of K str
        The label set's classes; every map must have K channels.
    directory : path-like
        Root folder of the maps.
    """

    name = "precomputed"
    #: The image is not looked at; callers may skip decoding it.
    needs_image = False

    def __init__(
        self, class_names: Sequence[str], directory: str | os.PathLike | None = None, **_: Any
    ) -> None:
        if _:
            raise ValidationError(
                f"precomputed recogniser: unknown option {sorted(_)[0]!r} (valid: directory)"
            )
        if directory is None:
            raise ValidationError("precomputed recogniser: needs directory= (the maps' folder)")
        self.directory = Path(directory)
        if not self.directory.is_dir():
            raise FileFormatError(self.directory, "no such folder of confidence maps")
        self.class_names = tuple(class_names)

    def recognize(
        self, image: np.ndarray | None, context: ImageContext | None = None
    ) -> np.ndarray:
        """The stored map (h, w, K) float32 of the image named by ``context``.

        Raises
        ------
        ValidationError
            Without a context.
        FileFormatError
            If the file is missing or unreadable, has no ``L2D`` array, or has the wrong shape.
        """
        if context is None:
            raise ValidationError("precomputed recogniser: needs an ImageContext (camera, frame)")
        npz = confidence_map_path(self.directory, context.camera, context.frame)
        npy = npz.with_suffix(".npy")
        try:
            if npz.is_file():
                L = load_npz(npz, ["L2D"], "a confidence map")["L2D"]
                path = npz
            elif npy.is_file():
                L = np.load(npy, allow_pickle=False)
                path = npy
            else:
                raise FileFormatError(
                    npz,
                    f"missing confidence map of camera {context.camera!r} frame "
                    f"{context.frame} (nor {npy.name})",
                )
        except (OSError, ValueError, zipfile.BadZipFile) as exc:
            if isinstance(exc, FileFormatError):
                raise
            raise FileFormatError(npz if npz.is_file() else npy, f"unreadable: {exc}") from None
        K = len(self.class_names)
        if L.ndim != 3 or L.shape[2] != K:
            raise FileFormatError(path, f"L2D: expected shape (h, w, {K}), got {L.shape}")
        if image is not None:
            H, W = np.shape(image)[:2]
            if L.shape[0] > H or L.shape[1] > W:
                raise FileFormatError(
                    path, f"L2D: map {L.shape[:2]} is larger than the image ({H}, {W})"
                )
        return np.asarray(L, dtype=np.float32)
