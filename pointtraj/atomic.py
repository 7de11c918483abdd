"""Atomic, verified file writes: a stage's output appears whole or not at all.

Every output goes through :func:`atomic_path`: the writer writes a temporary file beside the
destination, the file is checked (the writer's own error channel is not trusted: Open3D returns
True after RPly write errors, and ``cv2.imwrite`` returned True for a truncated PNG on a full
disk), flushed to disk, and only then renamed over the destination. On any failure the previous
file is kept and a :class:`~pointtraj.errors.WriteError` names the destination.

Temporary files are named ``.ptmp.<name>.<random><suffix>``, so a later run can recognise and
remove the ones a killed run left behind (:func:`remove_stale_temporaries`) without touching a
user's files.

A folder may be *owned* for a while (:func:`owner`, used by the work folder's lock): every
file installed below it is then reported to a callback, which records it in the folder's
manifest, so that a restart removes only files pointtraj wrote.
"""

from __future__ import annotations

import contextlib
import errno
import os
import re
import struct
import tempfile
import threading
import zipfile
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

from .errors import WriteError

__all__ = [
    "atomic_path",
    "save_npz_atomic",
    "write_text_atomic",
    "verify_file",
    "owner",
    "record_installed",
    "remove_stale_temporaries",
    "TEMP_PREFIX",
]

#: Prefix of every temporary file :func:`atomic_path` makes.
TEMP_PREFIX = ".ptmp."

# Temporaries of versions before TEMP_PREFIX: ".<our output name>.<8 mkstemp chars><ext>".
_LEGACY_TEMP = re.compile(
    r"^\.(\d{6}\.(?:ply|npz|png)|trajectories\.npz|semantic_map\.npz|affinity\.npz|labels\.npz"
    r"|labels\.csv|work\.toml|pipeline\.json|timings\.json|legend\.png|index\.md|metrics\.json)"
    r"\.[a-z0-9_]{8}(\.[a-z0-9]+)?$"
)


def _read_umask() -> int:
    """The process's file-creation mask (read once, at import: reading it means setting it,
    which is not thread-safe)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


_UMASK = _read_umask()

_owners_lock = threading.Lock()
_owners: dict[Path, Callable[[Path], None]] = {}


@contextlib.contextmanager
def owner(root: str | os.PathLike, record: Callable[[Path], None]) -> Iterator[None]:
    """While active, report every file :func:`atomic_path` installs below ``root``.

    Parameters
    ----------
    root : path-like
        The owned folder.
    record : callable
        ``record(path)`` with the installed file's absolute path.
    """
    key = Path(root).resolve()
    with _owners_lock:
        _owners[key] = record
    try:
        yield
    finally:
        with _owners_lock:
            _owners.pop(key, None)


def record_installed(path: str | os.PathLike) -> None:
    """Report a file that another process installed (a worker of the executor) to the owner of
    its folder (:func:`owner`), as if it had been installed here.

    Parameters
    ----------
    path : path-like
    """
    _report_installed(Path(path))


def _report_installed(path: Path) -> None:
    if not _owners:
        return
    resolved = path.resolve()
    with _owners_lock:
        targets = [rec for root, rec in _owners.items() if resolved.is_relative_to(root)]
    for rec in targets:
        rec(resolved)


# -- verification ---------------------------------------------------------------------------------
_PLY_SIZES = {
    "char": 1, "uchar": 1, "int8": 1, "uint8": 1, "short": 2, "ushort": 2, "int16": 2,
    "uint16": 2, "int": 4, "uint": 4, "int32": 4, "uint32": 4, "float": 4, "float32": 4,
    "double": 8, "float64": 8,
}  # fmt: skip


def _verify_ply(path: Path, size: int) -> str | None:
    """Check a binary PLY's length against its header (ASCII PLYs: header only)."""
    with open(path, "rb") as f:
        head = f.read(65536)
    end = head.find(b"end_header")
    if not head.startswith(b"ply") or end < 0:
        return "no PLY header"
    body_start = head.index(b"\n", end) + 1 if b"\n" in head[end:] else -1
    if body_start <= 0:
        return "PLY header is not terminated"
    fmt, expected = "", 0
    count, row = 0, 0
    for line in head[:end].decode("ascii", "replace").splitlines():
        words = line.split()
        if not words:
            continue
        if words[0] == "format":
            fmt = words[1]
        elif words[0] == "element":
            expected += count * row
            count, row = int(words[2]), 0
        elif words[0] == "property":
            if words[1] == "list":
                return None  # variable-length rows: the header check is all we can do
            row += _PLY_SIZES.get(words[1], 0)
    expected += count * row
    if fmt.startswith("binary") and size != body_start + expected:
        return f"{size} bytes where the PLY header promises {body_start + expected}"
    return None


def _verify_png(path: Path, size: int) -> str | None:
    with open(path, "rb") as f:
        head = f.read(8)
        f.seek(max(size - 12, 0))
        tail = f.read(12)
    if head != b"\x89PNG\r\n\x1a\n":
        return "no PNG signature"
    if tail[4:8] != b"IEND":
        return "the PNG does not end with its IEND chunk"
    return None


def _verify_jpeg(path: Path, size: int) -> str | None:
    with open(path, "rb") as f:
        head = f.read(2)
        f.seek(max(size - 2, 0))
        tail = f.read(2)
    if head != b"\xff\xd8" or tail != b"\xff\xd9":
        return "the JPEG does not start with SOI and end with EOI"
    return None


def _verify_npz(path: Path, size: int) -> str | None:
    # A zip ends with its end-of-central-directory record (22 bytes, no archive comment).
    with open(path, "rb") as f:
        f.seek(max(size - 22, 0))
        tail = f.read(22)
    if tail[:4] != b"PK\x05\x06":
        return "the npz (zip) has no end-of-central-directory record"
    return None


def _verify_mp4(path: Path, size: int) -> str | None:
    # Top-level boxes must tile the file exactly, and one of them must be the index (moov).
    pos, seen = 0, set()
    with open(path, "rb") as f:
        while pos < size:
            f.seek(pos)
            hdr = f.read(16)
            if len(hdr) < 8:
                return "the MP4 ends inside a box header"
            n, kind = struct.unpack(">I4s", hdr[:8])
            if n == 1 and len(hdr) == 16:
                n = struct.unpack(">Q", hdr[8:16])[0]
            elif n == 0:
                n = size - pos
            if n < 8:
                return "the MP4 has a malformed box"
            seen.add(kind)
            pos += n
    if pos != size:
        return "the MP4 ends inside a box"
    if b"moov" not in seen:
        return "the MP4 has no index (moov box)"
    return None


_VERIFIERS: dict[str, Callable[[Path, int], str | None]] = {
    ".ply": _verify_ply,
    ".png": _verify_png,
    ".jpg": _verify_jpeg,
    ".jpeg": _verify_jpeg,
    ".npz": _verify_npz,
    ".mp4": _verify_mp4,
}


def verify_file(path: str | os.PathLike, kind: str | None = None) -> str | None:
    """Check that a written file is complete, by its format's own framing.

    Parameters
    ----------
    path : path-like
    kind : str, optional
        The format as a suffix (``".ply"``, ``".png"``, ``".jpg"``, ``".npz"``, ``".mp4"``);
        default: the file's suffix. Other formats are only checked to exist.

    Returns
    -------
    str or None
        What is wrong, or None for a complete file.
    """
    path = Path(path)
    try:
        size = path.stat().st_size
    except OSError:
        return "the writer produced no file"
    check = _VERIFIERS.get((kind or path.suffix).lower())
    if check is None:
        return None
    if size == 0:
        return "the writer produced an empty file"
    try:
        return check(path, size)
    except (OSError, ValueError, struct.error) as exc:
        return f"unreadable after writing ({exc})"


def _fsync(path: Path, directory: bool = False) -> None:
    fd = os.open(path, os.O_RDONLY | (os.O_DIRECTORY if directory else 0))
    try:
        os.fsync(fd)
    except OSError as exc:
        if exc.errno not in (errno.EINVAL, errno.ENOTSUP, errno.EBADF):  # not supported there
            raise
    finally:
        os.close(fd)


def _describe(exc: OSError) -> str:
    if exc.errno == errno.ENOSPC:
        return "the disk is full"
    if exc.errno == errno.EDQUOT:
        return "the disk quota is exceeded"
    return exc.strerror or str(exc)


@contextlib.contextmanager
def atomic_path(
    path: str | os.PathLike, suffix: str | None = None, verify: bool = True
) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; check it and move it into place on success.

    Parameters
    ----------
    path : path-like
        The final destination. Its folder is created if needed.
    suffix : str, optional
        Suffix of the temporary file (default: that of ``path``), for writers that pick the
        format from the extension.
    verify : bool
        Check the written file by its format (:func:`verify_file`) before installing it.

    Yields
    ------
    pathlib.Path
        Where to write. On an exception, or if the file is incomplete, it is removed and
        ``path`` is left untouched.

    Raises
    ------
    WriteError
        If writing failed (a full disk, a read-only folder) or produced an incomplete file.
    """
    path = Path(path)
    suffix = path.suffix if suffix is None else suffix
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(
            prefix=f"{TEMP_PREFIX}{path.name}.", suffix=suffix, dir=path.parent
        )
        os.close(fd)
    except OSError as exc:
        raise WriteError(path, f"cannot write ({_describe(exc)})") from None
    tmp_path = Path(tmp)
    try:
        try:
            yield tmp_path
        except OSError as exc:
            raise _failed(path, f"cannot write ({_describe(exc)})") from None
        except WriteError as exc:  # a writer that reports its own failure
            raise _failed(path, exc.message) from None
        if verify:
            problem = verify_file(tmp_path, suffix)
            if problem is not None:
                raise _failed(path, f"incomplete output: {problem}")
        try:
            # mkstemp makes the file private (0600); give it the permissions of a plain new file.
            os.chmod(tmp_path, 0o666 & ~_UMASK)
            _fsync(tmp_path)
            os.replace(tmp_path, path)
            _fsync(path.parent, directory=True)
        except OSError as exc:
            raise _failed(path, f"cannot write ({_describe(exc)})") from None
    finally:
        if tmp_path.exists():
            with contextlib.suppress(OSError):
                tmp_path.unlink()
    _report_installed(path)


def _failed(path: Path, message: str) -> WriteError:
    """The error for a failed write of ``path``: why, whether the disk is (nearly) full, and
    whether an older file survives."""
    free = _free_bytes(path.parent)
    if free is not None and free < (16 << 20) and "disk is full" not in message:
        message += f" (the disk is nearly full: {free // 1024} KiB free)"
    kept = "; the previous file is kept" if path.exists() else ""
    return WriteError(path, message + kept)


def _free_bytes(folder: Path) -> int | None:
    try:
        st = os.statvfs(folder)
    except OSError:
        return None
    return st.f_bavail * st.f_frsize


def save_npz_atomic(
    path: str | os.PathLike, compress: bool | int = False, **arrays: np.ndarray
) -> None:
    """Write arrays to an ``.npz`` file atomically.

    Parameters
    ----------
    path : path-like
        Destination ``.npz`` file.
    compress : bool or int
        False: stored (``numpy.savez``); True: deflated at zlib's default level
        (``numpy.savez_compressed``); an int 1-9: deflated at that level (1 is about 3 times
        faster than the default and nearly as small on float data). Any form reads back with
        ``numpy.load``.
    **arrays : numpy.ndarray
        The arrays, by name.
    """
    if compress is not True and compress is not False and not 1 <= int(compress) <= 9:
        raise ValueError(f"compress: False, True or a zlib level 1-9, got {compress!r}")
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            if compress is True or compress is False:
                (np.savez_compressed if compress else np.savez)(f, **arrays)
                return
            with zipfile.ZipFile(
                f, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=int(compress)
            ) as zf:
                for name, array in arrays.items():
                    with zf.open(f"{name}.npy", "w", force_zip64=True) as member:
                        np.lib.format.write_array(member, np.asanyarray(array), allow_pickle=False)


def write_text_atomic(path: str | os.PathLike, text: str) -> None:
    """Write a text file atomically (UTF-8), checking that every byte arrived."""
    data = text.encode("utf-8")
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
        if tmp.stat().st_size != len(data):
            raise _failed(path, "incomplete output (is the disk full?)")


def remove_stale_temporaries(folder: str | os.PathLike) -> list[Path]:
    """Remove the temporary files that killed runs left below ``folder``.

    Only files named as :func:`atomic_path` names its temporaries are touched (and those of
    earlier versions, for pointtraj's own output names). Call it only while no other process
    writes there (under the work folder's lock).

    Returns
    -------
    list of pathlib.Path
        The files removed.
    """
    removed = []
    folder = Path(folder)
    if not folder.is_dir():
        return removed
    for dirpath, dirnames, filenames in os.walk(folder):
        dirnames[:] = [d for d in dirnames if not d.startswith(".") or d == ".pointtraj"]
        for name in filenames:
            if name.startswith(TEMP_PREFIX) or _LEGACY_TEMP.match(name):
                p = Path(dirpath) / name
                with contextlib.suppress(FileNotFoundError):
                    p.unlink()
                    removed.append(p)
    return removed
