"""Atomic writes."""

from __future__ import annotations

import os
import stat

import numpy as np
import pytest

from pointtraj.atomic import atomic_path, save_npz_atomic, write_text_atomic


def test_outputs_get_plain_file_permissions(tmp_path):
    """Regression: files were left with mkstemp's private mode 0600, so other users of a shared
    work folder could not read a stage's outputs."""
    write_text_atomic(tmp_path / "a.txt", "x")
    save_npz_atomic(tmp_path / "b.npz", a=np.arange(3))
    mask = os.umask(0o022)
    os.umask(mask)
    for name in ("a.txt", "b.npz"):
        mode = stat.S_IMODE((tmp_path / name).stat().st_mode)
        assert mode == 0o666 & ~mask


def test_failure_leaves_the_old_file_and_no_temporary(tmp_path):
    path = tmp_path / "sub" / "c.txt"
    write_text_atomic(path, "old")
    with pytest.raises(RuntimeError):
        with atomic_path(path) as tmp:
            tmp.write_text("half")
            raise RuntimeError("crash")
    assert path.read_text() == "old"
    assert sorted(p.name for p in path.parent.iterdir()) == ["c.txt"]
