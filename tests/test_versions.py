"""The numerical libraries' versions: one list, pinned by the set-up, named by every report."""

from __future__ import annotations

from importlib import metadata
from pathlib import Path

import pytest

from pointtraj.versions import NUMERICAL_LIBRARIES, library_versions

CONSTRAINTS = Path(__file__).resolve().parents[1] / "scripts" / "constraints.txt"


def _pins() -> dict[str, str]:
    pins = {}
    for line in CONSTRAINTS.read_text(encoding="utf-8").splitlines():
        line = line.split("#", 1)[0].strip()
        if line:
            name, _, version = line.partition("==")
            assert version, f"{CONSTRAINTS}: {line!r} is not pinned with =="
            pins[name.strip()] = version.strip()
    return pins


def test_constraints_pin_exactly_the_numerical_libraries():
    assert list(_pins()) == [names[0] for names in NUMERICAL_LIBRARIES]


def test_library_versions_name_what_is_installed():
    got = library_versions()
    assert got["pointtraj"] and list(got)[0] == "pointtraj"
    assert got["numpy"] == metadata.version("numpy")
    assert len(got) == 1 + len(NUMERICAL_LIBRARIES)


def test_set_up_environment_has_the_pinned_versions():
    """scripts/setup.sh installs the pins: a .venv that it made holds exactly them."""
    import sys

    stamps = sorted(Path(sys.prefix).glob(".pointtraj-installed*"), key=lambda p: p.stat().st_mtime)
    if not stamps or not stamps[-1].name.endswith("-pinned"):
        pytest.skip(f"{sys.prefix} was not set up last by scripts/setup.sh with its pins")
    got = library_versions()
    assert {k: got[k] for k in _pins()} == _pins()
