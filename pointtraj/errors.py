"""Exceptions and the one input-validation helper used at public boundaries.

Every error a user can cause is a :class:`PointtrajError`. Those about the shape or value of an
argument are also ``ValueError`` (:class:`ValidationError`); those about a file name the file and
the field (:class:`FileFormatError`).
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from os import PathLike
from pathlib import Path

import numpy as np

__all__ = [
    "PointtrajError",
    "ValidationError",
    "FileFormatError",
    "WriteError",
    "WorkFolderError",
    "check_array",
    "os_error_message",
]

#: A temporary file of :func:`pointtraj.atomic.atomic_path`: ``.<name>.<8 random chars><suffix>``.
_ATOMIC_TEMPORARY = re.compile(r"^\.(?:ptmp\.)?(?P<name>.+)\.[a-z0-9_]{8}(\.[^.]*)?$")


class PointtrajError(Exception):
    """Base class of every error pointtraj raises on purpose."""


class ValidationError(PointtrajError, ValueError):
    """An argument has the wrong shape, type or value."""


class FileFormatError(PointtrajError, ValueError):
    """A file is missing, unreadable, or has a bad field.

    Parameters
    ----------
    path : path-like
        The offending file.
    message : str
        What is wrong, ideally naming the field.
    """

    def __init__(self, path: str | PathLike, message: str) -> None:
        self.path = str(path)
        self.message = message
        super().__init__(f"{self.path}: {message}")

    def __reduce__(self):  # pickles whole (a task's error on a Dask worker comes back as is)
        return type(self), (self.path, self.message)


class WriteError(PointtrajError):
    """An output could not be written whole (a full disk, a read-only folder, a writer that
    produced a truncated file). The previous file at that path, if any, is intact.

    Parameters
    ----------
    path : path-like
        The destination.
    message : str
        What went wrong.
    """

    def __init__(self, path: str | PathLike, message: str) -> None:
        self.path = str(path)
        self.message = message
        super().__init__(f"{self.path}: {message}")

    def __reduce__(self):  # pickles whole (a task's error on a Dask worker comes back as is)
        return type(self), (self.path, self.message)


class WorkFolderError(PointtrajError):
    """A work folder cannot be used: another run holds it, or it is not pointtraj's to change."""


def check_array(
    name: str,
    value: object,
    shape: Sequence[int | None],
    *,
    dtype: type | np.dtype | None = float,
    finite: bool = False,
) -> np.ndarray:
    """Convert ``value`` to an array and check its shape.

    Parameters
    ----------
    name : str
        The argument's name, used in the error message.
    value : array-like
        The value to check.
    shape : sequence of int or None
        The expected shape; ``None`` matches any length along that axis.
    dtype : numpy dtype or None
        Convert to this dtype (``None`` keeps the input's dtype).
    finite : bool
        Also require every element to be finite.

    Returns
    -------
    numpy.ndarray
        ``value`` as an array of ``dtype``.

    Raises
    ------
    ValidationError
        If the shape does not match, the conversion fails, or ``finite`` is violated.

    Examples
    --------
    >>> check_array("points", [[0, 0, 1]], (None, 3)).shape
    (1, 3)
    >>> check_array("points", [0, 0, 1], (None, 3))
    Traceback (most recent call last):
    ...
    pointtraj.errors.ValidationError: points: expected shape (N, 3), got (3,)
    """
    try:
        arr = np.asarray(value, dtype=dtype)
    except (TypeError, ValueError) as exc:
        raise ValidationError(f"{name}: cannot convert to an array of {dtype}: {exc}") from None
    expected = "(" + ", ".join("N" if s is None else str(s) for s in shape) + ")"
    if len(shape) == 1:
        expected = expected[:-1] + ",)"
    if arr.ndim != len(shape) or any(s is not None and s != a for s, a in zip(shape, arr.shape)):
        raise ValidationError(f"{name}: expected shape {expected}, got {arr.shape}")
    if finite and not np.all(np.isfinite(arr)):
        raise ValidationError(f"{name}: contains NaN or infinite values")
    return arr


def os_error_message(exc: OSError, fallback: str | PathLike) -> str:
    """A one-line message for an operating-system error, naming the full path of the file.

    The file an atomic write was writing is named, not its temporary
    (``/w/state/000002.npz``, not ``/w/state/.000002.npz.k2j4x9_a.npz``).

    Parameters
    ----------
    exc : OSError
    fallback : path-like
        Named when the error carries no file name (e.g. the work folder).

    Returns
    -------
    str
        ``"<absolute path>: <reason>"``.

    Examples
    --------
    >>> os_error_message(OSError(30, "Read-only file system", "/w/state/.000002.npz.k2j4x9_a.npz"), "/w")
    '/w/state/000002.npz: Read-only file system'
    """
    path = Path(exc.filename if exc.filename else fallback)
    match = _ATOMIC_TEMPORARY.match(path.name)
    if match:
        path = path.with_name(match["name"])
    return f"{path.absolute()}: {exc.strerror or exc}"
