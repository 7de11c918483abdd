"""The one RGB image reader: a file that is missing, unreadable, truncated or corrupt is a
one-line :class:`~pointtraj.errors.FileFormatError` naming it.

libjpeg only warns about a truncated JPEG and fills the missing part grey, so a capture with a
half-written frame would be processed as if the frame were whole (``data_specs/capture.md``).
:func:`read_rgb` reads the bytes once, checks that a JPEG ends with its EOI marker and a PNG with
its IEND chunk, and decodes the same buffer.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .errors import FileFormatError

__all__ = ["read_rgb", "truncation_problem"]

_JPEG_START = b"\xff\xd8"
_JPEG_END = b"\xff\xd9"
_PNG_START = b"\x89PNG\r\n\x1a\n"
#: The whole IEND chunk: zero length, type, CRC.
_PNG_END = b"\x00\x00\x00\x00IEND\xaeB`\x82"
#: Bytes some writers pad a file with after its end marker.
_PADDING = b"\x00\t\n\r "


def truncation_problem(data: bytes) -> str | None:
    """Why an encoded JPEG or PNG is incomplete, or None if its end marker is there.

    Parameters
    ----------
    data : bytes
        The file's contents.

    Returns
    -------
    str or None
        A message for a JPEG that does not end with EOI (``FF D9``) or a PNG that does not end
        with its IEND chunk (trailing NUL or whitespace padding allowed); None for complete
        files and for other formats (left to the decoder).

    Examples
    --------
    >>> truncation_problem(b"\\xff\\xd8\\xff\\xe0 ... \\xff\\xd9\\x00\\x00") is None
    True
    >>> truncation_problem(b"\\xff\\xd8\\xff\\xe0 ...")
    'truncated JPEG (no end-of-image marker FF D9)'
    """
    if data.startswith(_JPEG_START):
        if not data.rstrip(_PADDING).endswith(_JPEG_END):
            return "truncated JPEG (no end-of-image marker FF D9)"
    elif data.startswith(_PNG_START):
        if not data.rstrip(_PADDING).endswith(_PNG_END):
            return "truncated PNG (no IEND chunk at the end)"
    return None


def read_rgb(path: str | os.PathLike, context: str = "") -> np.ndarray:
    """Read an image file, completely, as RGB.

    Parameters
    ----------
    path : path-like
        A JPEG, PNG, BMP or TIFF file.
    context : str, optional
        Prefix of error messages after the path, e.g. ``"camera 'cam0' frame 3"``.

    Returns
    -------
    (H, W, 3) uint8 ndarray
        RGB, C-contiguous.

    Raises
    ------
    FileFormatError
        Naming ``path``: missing or unreadable file, truncated JPEG or PNG, or data OpenCV
        cannot decode.
    """
    import cv2

    path = Path(path)
    prefix = f"{context}: " if context else ""
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise FileFormatError(path, f"{prefix}cannot read: {exc.strerror or exc}") from None
    problem = truncation_problem(data)
    if problem is not None:
        raise FileFormatError(path, f"{prefix}{problem}: corrupt image")
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR) if data else None
    if img is None:
        raise FileFormatError(path, f"{prefix}unreadable or corrupt image")
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
