"""Helpers shared by the rig format modules: field checks that name the file, folder outputs."""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from ..camera import Camera
from ..errors import FileFormatError, ValidationError

__all__ = [
    "field_array",
    "field_value",
    "make_camera",
    "replace_folder_files",
    "temp_folder_beside",
    "trim_dist",
]


def field_value(path: str | os.PathLike, table: Mapping[str, Any], key: str, where: str) -> Any:
    """``table[key]``, or a :class:`FileFormatError` naming the file and ``where.key``."""
    if key not in table:
        raise FileFormatError(path, f"{where}: missing field {key!r}")
    return table[key]


def field_array(
    path: str | os.PathLike,
    table: Mapping[str, Any],
    key: str,
    where: str,
    shapes: tuple[tuple[int, ...], ...],
) -> np.ndarray:
    """A finite float array field with one of the allowed ``shapes``.

    Parameters
    ----------
    path : path-like
        The file, for the error message.
    table : mapping
        The parsed table holding the field.
    key : str
        The field name.
    where : str
        The table's name in the file (e.g. ``"[cam_0]"``).
    shapes : tuple of shapes
        Accepted shapes (e.g. ``((3, 3),)`` or ``((3,), (3, 1))``).

    Returns
    -------
    float ndarray
        The field, with its shape as found.

    Raises
    ------
    FileFormatError
        If the field is missing, not numeric, has another shape or a NaN/infinite value.
    """
    value = field_value(path, table, key, where)
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise FileFormatError(
            path, f"{where}.{key}: expected numbers of shape {_shapes(shapes)}, got {value!r}"
        ) from None
    if arr.shape not in shapes:
        raise FileFormatError(
            path, f"{where}.{key}: expected shape {_shapes(shapes)}, got {arr.shape}"
        )
    if not np.all(np.isfinite(arr)):
        raise FileFormatError(path, f"{where}.{key}: contains NaN or infinite values")
    return arr


def _shapes(shapes: tuple[tuple[int, ...], ...]) -> str:
    return " or ".join(str(s) for s in shapes)


def make_camera(
    path: str | os.PathLike,
    where: str,
    name: str,
    K: np.ndarray,
    R: np.ndarray,
    t: np.ndarray,
    size: object,
    dist: np.ndarray,
) -> Camera:
    """``Camera.from_extrinsics`` whose validation errors become file errors naming ``where``."""
    try:
        w, h = (int(v) for v in np.asarray(size).ravel())
    except (TypeError, ValueError):
        raise FileFormatError(
            path, f"{where}.size: expected [width, height], got {size!r}"
        ) from None
    try:
        return Camera.from_extrinsics(name, K, R, t, (w, h), dist)
    except ValidationError as exc:
        raise FileFormatError(path, f"{where}: {exc}") from None


def trim_dist(dist: np.ndarray) -> list[float]:
    """The 5 OpenCV coefficients ``k1 k2 p1 p2 k3`` when ``k4..k6`` are zero, else all 8."""
    d = np.asarray(dist, dtype=float)
    return [float(v) for v in (d[:5] if not np.any(d[5:]) else d)]


# -- folder outputs --------------------------------------------------------------------------
def replace_folder_files(src: Path, dst: Path) -> None:
    """Move every file of folder ``src`` into folder ``dst`` (each move atomic), then drop ``src``."""
    dst.mkdir(parents=True, exist_ok=True)
    for f in sorted(src.iterdir()):
        os.replace(f, dst / f.name)
    shutil.rmtree(src, ignore_errors=True)


def temp_folder_beside(path: Path) -> Path:
    """A new empty folder next to ``path`` (same file system, so moves out of it are atomic)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    return Path(tempfile.mkdtemp(prefix=f".{path.name}.", dir=path.parent))
