"""Typed configuration: TOML tables parsed into dataclasses, unknown keys rejected; and the one
TOML reader and writer.

Every stage keeps its parameters in one frozen dataclass with the paper's defaults (for example
``TriangulationConfig``). :func:`from_mapping` builds such a dataclass from a TOML table, checking
each value's type and naming the file, table and key of any mistake, so raw dicts never travel
into library code.

Every TOML file pointtraj reads goes through :func:`load_toml`, and every one it writes
(``rig.toml``, ``camera_array.toml``, ``capture.toml``, ``labels.toml``, ``work.toml``,
``gt/synth.toml``) through :func:`dump_toml` / :func:`save_toml`, which use ``tomli_w``.
"""

from __future__ import annotations

import dataclasses
import os
import tomllib
import types
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Any, TypeVar

from .errors import FileFormatError

__all__ = ["from_mapping", "to_mapping", "load_toml", "dump_toml", "save_toml"]

T = TypeVar("T")


def load_toml(path: str | os.PathLike) -> dict[str, Any]:
    """Read a TOML file.

    Parameters
    ----------
    path : path-like

    Returns
    -------
    dict
        The parsed document.

    Raises
    ------
    FileFormatError
        If the file is missing, is not valid TOML or is not UTF-8 text (naming the file).
    """
    path = Path(path)
    if not path.is_file():
        raise FileFormatError(path, "no such file")
    try:
        with open(path, "rb") as f:
            return tomllib.load(f)
    except tomllib.TOMLDecodeError as exc:
        raise FileFormatError(path, f"invalid TOML: {exc}") from None
    except UnicodeDecodeError as exc:
        raise FileFormatError(path, f"not a UTF-8 text file ({exc})") from None


def _plain(value: Any) -> Any:
    """``value`` with numpy scalars and arrays as Python numbers and lists, tuples as lists and
    mapping keys as strings (what ``tomli_w`` writes)."""
    import numpy as np

    if isinstance(value, np.ndarray):
        return _plain(value.tolist())
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, tuple | list):
        return [_plain(v) for v in value]
    return value


def dump_toml(data: Mapping[str, Any], comment: str = "") -> str:
    """TOML text of nested mappings (tables for mappings, arrays of tables for lists of them).

    Floats are written exactly (the shortest ``repr`` that reads back to the same double;
    ``nan`` and ``inf`` as TOML's), and numpy values as plain numbers and lists.

    Parameters
    ----------
    data : mapping
        Strings, numbers, booleans, and lists, tuples, numpy arrays and mappings of them.
    comment : str
        Text written first as ``#`` comment lines (one per line of ``comment``).

    Returns
    -------
    str

    Raises
    ------
    TypeError
        If a value cannot be written as TOML (e.g. None).

    Examples
    --------
    >>> print(dump_toml({"a": 1, "cam_0": {"x": 0.1}}, comment="made by hand").strip())
    # made by hand
    a = 1
    <BLANKLINE>
    [cam_0]
    x = 0.1
    """
    import tomli_w

    head = "".join(f"# {line}\n" if line else "#\n" for line in comment.splitlines())
    return head + tomli_w.dumps(_plain(data))


def save_toml(path: str | os.PathLike, data: Mapping[str, Any], comment: str = "") -> None:
    """Write :func:`dump_toml` ``(data, comment)`` to ``path`` atomically (UTF-8).

    Raises
    ------
    TypeError
        If a value cannot be written as TOML (nothing is written then).
    WriteError
        If the file cannot be written.
    """
    from .atomic import write_text_atomic

    write_text_atomic(path, dump_toml(data, comment))


def _coerce(value: Any, tp: Any, where: str) -> Any:
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if tp is Any:
        return value
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        errors = []
        for a in args:
            if a is type(None):
                continue
            try:
                return _coerce(value, a, where)
            except ValueError as exc:
                errors.append(str(exc))
        raise ValueError(errors[0] if errors else f"{where}: bad value {value!r}")
    if origin is typing.Literal:
        if value not in args:
            raise ValueError(f"{where}: must be one of {', '.join(map(repr, args))}, got {value!r}")
        return value
    if origin in (tuple, list):
        if not isinstance(value, list | tuple):
            raise ValueError(f"{where}: expected a list, got {value!r}")
        if origin is tuple and args and args[-1] is not Ellipsis:
            if len(args) != len(value):
                raise ValueError(f"{where}: expected {len(args)} values, got {len(value)}")
            return tuple(
                _coerce(v, a, f"{where}[{i}]") for i, (v, a) in enumerate(zip(value, args))
            )
        inner = args[0] if args else Any
        seq = [_coerce(v, inner, f"{where}[{i}]") for i, v in enumerate(value)]
        return tuple(seq) if origin is tuple else seq
    if origin is dict:
        if not isinstance(value, Mapping):
            raise ValueError(f"{where}: expected a table, got {value!r}")
        inner = args[1] if len(args) == 2 else Any
        return {str(k): _coerce(v, inner, f"{where}.{k}") for k, v in value.items()}
    if dataclasses.is_dataclass(tp):
        if not isinstance(value, Mapping):
            raise ValueError(f"{where}: expected a table, got {value!r}")
        return from_mapping(tp, value, where=where)
    if tp is bool:
        if not isinstance(value, bool):
            raise ValueError(f"{where}: expected true or false, got {value!r}")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ValueError(f"{where}: expected an integer, got {value!r}")
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ValueError(f"{where}: expected a number, got {value!r}")
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            raise ValueError(f"{where}: expected a string, got {value!r}")
        return value
    if tp is Path:
        if not isinstance(value, str):
            raise ValueError(f"{where}: expected a path string, got {value!r}")
        return Path(value)
    return value


def from_mapping(cls: type[T], data: Mapping[str, Any], where: str = "config") -> T:
    """Build dataclass ``cls`` from a mapping, with type checks and no unknown keys.

    Parameters
    ----------
    cls : dataclass type
        Target type; fields missing from ``data`` keep their defaults.
    data : mapping
        For example a table of a parsed TOML file.
    where : str
        Prefix of error messages, e.g. ``"pipeline.toml [affinity]"``.

    Returns
    -------
    cls instance

    Raises
    ------
    ValueError
        Naming the key: unknown keys (with the valid ones listed), wrong types, missing
        required fields. Fields with ``metadata={"internal": True}`` are not keys.

    Examples
    --------
    >>> from dataclasses import dataclass
    >>> @dataclass(frozen=True)
    ... class Demo:
    ...     sigma: float = 1.0
    ...     iterations: int = 50
    >>> from_mapping(Demo, {"sigma": 2})
    Demo(sigma=2.0, iterations=50)
    >>> from_mapping(Demo, {"sigmaa": 2})
    Traceback (most recent call last):
    ...
    ValueError: config: unknown key 'sigmaa' (valid: iterations, sigma)
    """
    if not dataclasses.is_dataclass(cls):
        raise TypeError(f"{cls!r} is not a dataclass")
    hints = typing.get_type_hints(cls)
    fields = {
        f.name: f for f in dataclasses.fields(cls) if f.init and not f.metadata.get("internal")
    }
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise ValueError(
            f"{where}: unknown key {unknown[0]!r} (valid: {', '.join(sorted(fields))})"
        )
    kwargs = {k: _coerce(v, hints[k], f"{where}.{k}") for k, v in data.items()}
    missing = [
        n
        for n, f in fields.items()
        if n not in kwargs
        and f.default is dataclasses.MISSING
        and f.default_factory is dataclasses.MISSING
    ]
    if missing:
        raise ValueError(f"{where}: missing required key {missing[0]!r}")
    return cls(**kwargs)


def to_mapping(obj: Any) -> dict[str, Any]:
    """A dataclass as a TOML-friendly dict (tuples become lists, paths strings, None dropped)."""

    def conv(v: Any) -> Any:
        if dataclasses.is_dataclass(v):
            return {
                f.name: conv(getattr(v, f.name))
                for f in dataclasses.fields(v)
                if getattr(v, f.name) is not None
            }
        if isinstance(v, tuple | list):
            return [conv(x) for x in v]
        if isinstance(v, Mapping):
            return {str(k): conv(x) for k, x in v.items() if x is not None}
        if isinstance(v, Path):
            return str(v)
        return v

    return conv(obj)
