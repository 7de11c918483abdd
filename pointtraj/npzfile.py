"""The one way pointtraj reads an ``.npz`` file: every failure is a one-line FileFormatError.

A missing file, a truncated or corrupt zip, a file that is not an npz, a permission error and a
missing required array all become :class:`~pointtraj.errors.FileFormatError` naming the file,
never a traceback from inside numpy or zipfile.
"""

from __future__ import annotations

import os
import zipfile
import zlib
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from .errors import FileFormatError

__all__ = ["load_npz"]


def _reason(exc: BaseException) -> str:
    """A short description of why reading failed (no path: the caller names the file)."""
    if isinstance(exc, PermissionError):
        return "permission denied"
    if isinstance(exc, OSError) and exc.strerror:
        return exc.strerror.lower()
    if isinstance(exc, zipfile.BadZipFile | EOFError | zlib.error):
        return "truncated or corrupt (not a complete .npz archive)"
    return str(exc) or type(exc).__name__


def load_npz(
    path: str | os.PathLike,
    required: Sequence[str] = (),
    what: str = "an .npz file",
    *,
    hint: str = "",
    keys: Sequence[str] | None = None,
) -> dict[str, np.ndarray]:
    """Read the arrays of an ``.npz`` file into memory (every one, or only ``keys``).

    Parameters
    ----------
    path : path-like
        The file.
    required : sequence of str
        Arrays that must be present.
    what : str
        What the file should be, for the messages (e.g. ``"a semantic map"``).
    hint : str, optional
        Appended to the message of a missing file, e.g. ``"run `pointtraj label` first"``.
    keys : sequence of str, optional
        Read only these arrays (those present; the others are neither read nor decompressed).
        ``required`` is checked against the file's arrays either way.

    Returns
    -------
    dict of str to numpy.ndarray
        The arrays read, by name.

    Raises
    ------
    FileFormatError
        Naming ``path``: the file is missing or unreadable (permission, I/O error), is not a
        complete npz archive (truncated, corrupt, a plain ``.npy``), or lacks a required array.
    """
    path = Path(path)
    if not path.is_file():
        raise FileFormatError(path, f"no such file ({hint})" if hint else "no such file")
    try:
        # Open the file ourselves: np.load(path) leaks it when the zip is corrupt.
        with open(path, "rb") as f:
            z = np.load(f, allow_pickle=False)
            if not isinstance(z, np.lib.npyio.NpzFile):
                raise ValueError("a single .npy array, not an .npz archive")
            with z:
                names = list(z.files)
                wanted = names if keys is None else [k for k in names if k in set(keys)]
                data = {k: z[k] for k in wanted}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error) as exc:
        raise FileFormatError(path, f"not a readable .npz file: {_reason(exc)}") from None
    missing = [k for k in required if k not in names]
    if missing:
        raise FileFormatError(
            path,
            f"missing array {', '.join(repr(k) for k in missing)}: not {what}, or damaged",
        )
    return data
