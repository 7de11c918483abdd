"""Image and video files of renders: PNG frames and MP4 videos, written atomically."""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from ..atomic import atomic_path
from ..errors import ValidationError, WriteError

__all__ = ["read_png", "write_png", "write_video"]


def read_png(path: str | os.PathLike) -> np.ndarray:
    """Read an image file as RGB uint8 (H, W, 3).

    Raises
    ------
    FileFormatError
        If the file is missing, truncated or cannot be decoded (:func:`pointtraj.images.read_rgb`).
    """
    from ..images import read_rgb

    return read_rgb(path)


def write_png(path: str | os.PathLike, image: np.ndarray) -> None:
    """Write an RGB image as PNG, atomically."""
    import cv2

    with atomic_path(path) as tmp:
        if not cv2.imwrite(str(tmp), np.ascontiguousarray(image[..., ::-1])):
            raise WriteError(path, "OpenCV could not write the PNG")


def write_video(path: str | os.PathLike, frames: Iterable[np.ndarray], fps: float = 30.0) -> int:
    """Write RGB frames to an MP4 (codec ``mp4v``), atomically.

    Parameters
    ----------
    path : path-like
        Destination ``.mp4``.
    frames : iterable of (H, W, 3) uint8 ndarray
        All the same size; consumed lazily, one at a time.
    fps : float

    Returns
    -------
    int
        Number of frames written (no file is written for none).
    """
    import cv2

    path = Path(path)
    writer = None
    n = 0
    with atomic_path(path) as tmp:
        try:
            for img in frames:
                if writer is None:
                    h, w = img.shape[:2]
                    writer = cv2.VideoWriter(str(tmp), cv2.VideoWriter_fourcc(*"mp4v"), fps, (w, h))
                    if not writer.isOpened():
                        raise WriteError(path, "OpenCV cannot open an mp4v video writer")
                writer.write(np.ascontiguousarray(img[..., ::-1]))
                n += 1
        finally:
            if writer is not None:
                writer.release()
        if n == 0:
            raise ValidationError(f"{path}: no frames to write")
    return n
