"""Atomic writes."""

from __future__ import annotations

import os
import stat

import numpy as np
import pytest

from pointtraj.atomic import atomic_path, save_npz_atomic, write_text_atomic
from pointtraj.errors import FileFormatError


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


@pytest.mark.parametrize("compress", [False, True, 1, 9])
def test_npz_round_trips_at_every_compression(tmp_path, compress):
    from pointtraj.npzfile import load_npz

    a = np.repeat(np.arange(1000, dtype=np.float32), 10)
    b = np.array([[1, 2], [3, 4]], np.uint8)
    path = tmp_path / "x.npz"
    save_npz_atomic(path, compress=compress, a=a, b=b)
    back = load_npz(path, ("a", "b"))
    np.testing.assert_array_equal(back["a"], a)
    assert back["b"].dtype == np.uint8 and back["b"].tolist() == b.tolist()
    if compress:
        assert path.stat().st_size < a.nbytes / 4
    only = load_npz(path, ("a",), keys=["b", "c"])  # only b read; c absent is no error
    assert list(only) == ["b"]
    with pytest.raises(FileFormatError, match="missing array 'c'"):
        load_npz(path, ("c",), keys=["a"])


def test_npz_compression_level_is_checked(tmp_path):
    with pytest.raises(ValueError, match="zlib level 1-9"):
        save_npz_atomic(tmp_path / "x.npz", compress=12, a=np.zeros(2))
    assert not (tmp_path / "x.npz").exists()
