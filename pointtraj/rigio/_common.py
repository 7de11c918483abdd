"""Helpers shared by the rig format modules: field checks that name the file, a TOML writer."""

from __future__ import annotations

import json
import math
import os
import re
import shutil
import tempfile
import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from ..camera import Camera
from ..errors import FileFormatError, ValidationError

__all__ = [
    "read_toml",
    "dump_toml",
    "field_array",
    "field_value",
    "make_camera",
    "replace_folder_files",
    "temp_folder_beside",
    "trim_dist",
]


def read_toml(path: str | os.PathLike) -> dict[str, Any]:
    """Parse a TOML file, raising :class:`FileFormatError` when it is missing or malformed."""
    path = Path(path)
    if not path.is_file():
        raise FileFormatError(path, "no such file")
    try:
        with open(path, "rb") as f:
            return tomllib.load(f)
    except tomllib.TOMLDecodeError as exc:
        raise FileFormatError(path, f"not valid TOML ({exc})") from None
    except UnicodeDecodeError as exc:
        raise FileFormatError(path, f"not a UTF-8 text file ({exc})") from None


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


# -- TOML writing ----------------------------------------------------------------------------
_BARE_KEY = re.compile(r"^[A-Za-z0-9_-]+$")


def _key(k: str) -> str:
    return k if _BARE_KEY.match(k) else json.dumps(k)


def _value(v: Any) -> str:
    if isinstance(v, bool | np.bool_):
        return "true" if v else "false"
    if isinstance(v, int | np.integer):
        return str(int(v))
    if isinstance(v, float | np.floating):
        f = float(v)
        if math.isnan(f):
            return "nan"
        if math.isinf(f):
            return "inf" if f > 0 else "-inf"
        return repr(f)  # shortest string that reads back to the same double
    if isinstance(v, str):
        return json.dumps(v, ensure_ascii=False)
    if isinstance(v, np.ndarray):
        return _value(v.tolist())
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    if isinstance(v, Mapping):
        return "{" + ", ".join(f"{_key(str(k))} = {_value(x)}" for k, x in v.items()) + "}"
    raise TypeError(f"cannot write {type(v).__name__} to TOML")


def dump_toml(data: Mapping[str, Any]) -> str:
    """Serialise nested mappings to TOML text (tables for mappings, inline values otherwise).

    Floats are written with ``repr`` so that they read back bit-exactly.

    Examples
    --------
    >>> print(dump_toml({"a": 1, "cam_0": {"size": [4, 3], "x": 0.1}}).strip())
    a = 1
    <BLANKLINE>
    [cam_0]
    size = [4, 3]
    x = 0.1
    """
    lines: list[str] = []
    _dump_table(data, [], lines)
    return "\n".join(lines).lstrip("\n") + "\n"


def _dump_table(data: Mapping[str, Any], prefix: list[str], lines: list[str]) -> None:
    scalars = {k: v for k, v in data.items() if not isinstance(v, Mapping)}
    tables = {k: v for k, v in data.items() if isinstance(v, Mapping)}
    if prefix and (scalars or not tables):
        lines.append("")
        lines.append("[" + ".".join(_key(p) for p in prefix) + "]")
    for k, v in scalars.items():
        lines.append(f"{_key(str(k))} = {_value(v)}")
    for k, v in tables.items():
        _dump_table(v, [*prefix, str(k)], lines)


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
