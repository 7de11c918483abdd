"""Typed TOML configuration: from_mapping / to_mapping."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import pytest

from pointtraj.config import from_mapping, load_toml, to_mapping
from pointtraj.errors import FileFormatError


@dataclass(frozen=True)
class Inner:
    cells: tuple[int, int] = (16, 12)
    scale: float = 1.0


@dataclass(frozen=True)
class Outer:
    name: str = "x"
    mode: Literal["a", "b"] = "a"
    sizes: tuple[float, ...] = (1.0,)
    path: Path | None = None
    inner: Inner = field(default_factory=Inner)


def test_fixed_length_tuple_keeps_values_in_order():
    """Regression: fixed-length tuples were coerced with values and types swapped, so
    ``grid_cells = [8, 6]`` in a TOML file became a tuple of types."""
    cfg = from_mapping(Outer, {"inner": {"cells": [8, 6]}})
    assert cfg.inner.cells == (8, 6)
    with pytest.raises(ValueError, match=r"inner\.cells: expected 2 values, got 3"):
        from_mapping(Outer, {"inner": {"cells": [1, 2, 3]}})
    with pytest.raises(ValueError, match=r"inner\.cells\[1\]: expected an integer"):
        from_mapping(Outer, {"inner": {"cells": [1, "two"]}})


def test_types_literals_and_unknown_keys():
    cfg = from_mapping(Outer, {"mode": "b", "sizes": [1, 2.5], "path": "a/b", "inner": {}})
    assert cfg == Outer(mode="b", sizes=(1.0, 2.5), path=Path("a/b"))
    with pytest.raises(ValueError, match="must be one of 'a', 'b'"):
        from_mapping(Outer, {"mode": "c"})
    with pytest.raises(ValueError, match=r"unknown key 'nmae' \(valid: inner, mode, name"):
        from_mapping(Outer, {"nmae": "y"})
    with pytest.raises(ValueError, match="expected a table"):
        from_mapping(Outer, {"inner": 3})


def test_round_trip_through_to_mapping(tmp_path):
    cfg = Outer(name="n", sizes=(2.0, 3.0), inner=Inner(cells=(4, 3), scale=0.5))
    assert from_mapping(Outer, to_mapping(cfg)) == cfg
    bad = tmp_path / "bad.toml"
    bad.write_text("a = [", encoding="utf-8")
    with pytest.raises(FileFormatError, match="bad.toml: invalid TOML"):
        load_toml(bad)
    with pytest.raises(FileFormatError, match="no such file"):
        load_toml(tmp_path / "missing.toml")
