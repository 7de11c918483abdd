"""The work folder: where every stage after the capture writes its outputs.

A work folder (``data_specs/work_folder.md``) belongs to one capture, recorded in
``WORK/work.toml``. :class:`WorkFolder` names its files, so no stage spells a path twice, and
reads and writes ``work.toml``.
"""

from __future__ import annotations

import contextlib
import fcntl
import functools
import json
import logging
import os
import re
import socket
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any, TypeVar

from .errors import FileFormatError, ValidationError, WorkFolderError

__all__ = ["WorkFolder", "parse_frames", "locked", "WORK_TOML", "OWN_NAMES"]

F = TypeVar("F", bound=Callable[..., Any])

logger = logging.getLogger(__name__)

#: Name of the file that records the capture and the reconstruction run.
WORK_TOML = "work.toml"

#: pointtraj's own folder inside a work folder: the lock and the manifest.
_OWN_DIR = ".pointtraj"

#: Files that pointtraj writes in a work folder of an older version without a manifest, by
#: subfolder: only these may be removed there (``--force-folder`` too).
OWN_NAMES = {
    "state": re.compile(r"^(\d{6}|live)\.npz$"),
    "clouds": re.compile(r"^\d{6}\.ply$"),
}

# Work folders this process holds, with how many times (the lock is re-entrant per process).
_held: dict[Path, list] = {}
_held_lock = threading.Lock()


def parse_frames(text: str | None, num_frames: int, where: str = "frames") -> range:
    """Parse ``A:B`` (Python slice syntax, B exclusive, either side optional) into a range.

    Unlike a Python slice, a start or stop outside the capture is an error rather than clamped
    (``0:100`` of a 6-frame capture would silently be ``0:6``); negative indices count from the
    end as usual.

    Parameters
    ----------
    text : str or None
        ``"A:B"``, ``":B"``, ``"A:"``; None selects every frame.
    num_frames : int
        Frames in the capture.
    where : str
        Where the text came from, prefixing messages (``"--frames"``, ``"pipe.toml: frames"``).

    Returns
    -------
    range

    Raises
    ------
    ValidationError
        If the text is not ``A:B`` with integers, A or B lies outside the capture, or it selects
        no frame.

    Examples
    --------
    >>> parse_frames("2:5", 10)
    range(2, 5)
    >>> parse_frames(":-2", 10)
    range(0, 8)
    >>> parse_frames(None, 4)
    range(0, 4)
    >>> parse_frames("0:100", 6)
    Traceback (most recent call last):
    ...
    pointtraj.errors.ValidationError: frames: '0:100' ends at frame 100, but the capture has 6 frames (valid: -6 to 6)
    """
    if text is None:
        return range(num_frames)
    parts = str(text).split(":")
    if len(parts) != 2:
        raise ValidationError(f"{where}: expected A:B, got {text!r}")
    try:
        a = int(parts[0]) if parts[0].strip() else None
        b = int(parts[1]) if parts[1].strip() else None
    except ValueError:
        raise ValidationError(f"{where}: expected integers A:B, got {text!r}") from None
    n = int(num_frames)
    if a is not None and not -n <= a < n:
        raise ValidationError(
            f"{where}: {text!r} starts at frame {a}, but the capture has {n} frames "
            f"(valid: {-n} to {n - 1})"
        )
    if b is not None and not -n <= b <= n:
        raise ValidationError(
            f"{where}: {text!r} ends at frame {b}, but the capture has {n} frames "
            f"(valid: {-n} to {n})"
        )
    r = range(n)[slice(a, b)]
    if len(r) == 0:
        raise ValidationError(f"{where}: {text!r} selects no frame of the capture's {n}")
    return r


class WorkFolder:
    """Paths of a work folder's files.

    Parameters
    ----------
    path : path-like
        The folder (need not exist yet).

    Attributes
    ----------
    path : pathlib.Path
    """

    def __init__(self, path: str | os.PathLike) -> None:
        self.path = Path(path)

    def __repr__(self) -> str:
        return f"WorkFolder({str(self.path)!r})"

    @property
    def work_toml(self) -> Path:
        """``work.toml``: the capture and the reconstruction run."""
        return self.path / WORK_TOML

    @property
    def trajectories(self) -> Path:
        """``trajectories.npz``: the trajectory store."""
        return self.path / "trajectories.npz"

    @property
    def clouds(self) -> Path:
        """``clouds/``: one PLY per frame."""
        return self.path / "clouds"

    @property
    def state(self) -> Path:
        """``state/``: the reconstruction's resume points."""
        return self.path / "state"

    @property
    def semantic_map(self) -> Path:
        """``semantic_map.npz``: L3D per trajectory."""
        return self.path / "semantic_map.npz"

    @property
    def affinity(self) -> Path:
        """``affinity.npz``: the sparse affinity graph."""
        return self.path / "affinity.npz"

    @property
    def labels(self) -> Path:
        """``labels.npz``: a label per trajectory (``labels.csv`` beside it)."""
        return self.path / "labels.npz"

    @property
    def labels_csv(self) -> Path:
        """``labels.csv``."""
        return self.path / "labels.csv"

    @property
    def segments(self) -> Path:
        """``segments.npz``: per-part 6-DoF poses and joint centres."""
        return self.path / "segments.npz"

    @property
    def report(self) -> Path:
        """``report/``: the evaluation report."""
        return self.path / "report"

    @property
    def renders(self) -> Path:
        """``renders/``: PNG frames and videos."""
        return self.path / "renders"

    @property
    def pipeline_state(self) -> Path:
        """``pipeline.json``: what ``pointtraj run`` has done, per stage."""
        return self.path / "pipeline.json"

    @property
    def timings(self) -> Path:
        """``timings.json``: seconds per stage of the latest runs."""
        return self.path / "timings.json"

    def cloud(self, frame: int) -> Path:
        """``clouds/<frame:06d>.ply``."""
        return self.clouds / f"{int(frame):06d}.ply"

    def read_toml(self) -> dict[str, Any]:
        """The parsed ``work.toml`` ({} when there is none).

        Raises
        ------
        FileFormatError
            If it is not valid TOML.
        """
        from .config import load_toml

        return load_toml(self.work_toml) if self.work_toml.is_file() else {}

    def capture_path(self) -> Path | None:
        """The capture folder recorded in ``work.toml`` (None when there is none).

        Raises
        ------
        FileFormatError
            If ``capture`` is missing or not a string.
        """
        data = self.read_toml()
        if not data:
            return None
        capture = data.get("capture")
        if not isinstance(capture, str) or not capture:
            raise FileFormatError(
                self.work_toml, "capture: expected the capture folder as a string"
            )
        return Path(capture)

    def require_capture(self, capture: str | os.PathLike | None = None) -> Path:
        """The capture folder: ``capture`` if given, else the one ``work.toml`` records.

        Raises
        ------
        FileFormatError
            If neither is available, or the recorded folder no longer exists.
        """
        if capture is not None:
            return Path(capture)
        recorded = self.capture_path()
        if recorded is None:
            raise FileFormatError(
                self.work_toml, "no such file: the work folder does not record its capture"
            )
        if not recorded.is_dir():
            raise FileFormatError(self.work_toml, f"capture folder {recorded} does not exist")
        return recorded

    @staticmethod
    def run_document(
        capture: str | os.PathLike, frames: range | None = None, reconstruct: Any = None
    ) -> dict[str, Any]:
        """The ``work.toml`` document for a capture, frame range and reconstruction parameters.

        Parameters
        ----------
        capture : path-like
            The capture folder (stored absolute).
        frames : range, optional
            The reconstructed frames (``[reconstruct_run] frames = [A, B]``).
        reconstruct : dataclass, optional
            The reconstruction parameters (table ``[reconstruct]``).
        """
        from .config import to_mapping

        doc: dict[str, Any] = {"capture": str(Path(capture).resolve())}
        if frames is not None:
            doc["reconstruct_run"] = {"frames": [frames.start, frames.stop]}
        if reconstruct is not None:
            doc["reconstruct"] = to_mapping(reconstruct)
        return doc

    def write_toml(
        self,
        capture: str | os.PathLike,
        frames: range | None = None,
        reconstruct: Any = None,
    ) -> None:
        """Write ``work.toml`` (:meth:`run_document`) atomically, creating the folder."""
        from .config import save_toml

        doc = self.run_document(capture, frames, reconstruct)
        self.path.mkdir(parents=True, exist_ok=True)
        save_toml(
            self.work_toml, doc, comment="pointtraj work folder (see data_specs/work_folder.md)"
        )

    def run_identity(self) -> dict[str, Any]:
        """The parts of ``work.toml`` that identify a reconstruction run (capture, frames,
        parameters); a run can resume only where they equal :meth:`run_document`'s."""
        data = self.read_toml()
        return {k: data.get(k) for k in ("capture", "reconstruct_run", "reconstruct")}

    # -- ownership ---------------------------------------------------------------------------
    @property
    def manifest(self) -> Path:
        """``.pointtraj/manifest``: every file pointtraj installed here, one relative path a
        line (appended while the folder is locked)."""
        return self.path / _OWN_DIR / "manifest"

    @property
    def lock_file(self) -> Path:
        """``.pointtraj/lock``: who holds the folder (pid, host, command, since)."""
        return self.path / _OWN_DIR / "lock"

    @property
    def labels_pending(self) -> Path:
        """``.pointtraj/labels-pending``: present while ``label`` rewrites the clouds, so that
        an interrupted rewrite is known (the clouds then mix two labellings)."""
        return self.path / _OWN_DIR / "labels-pending"

    def is_pointtraj(self) -> bool:
        """Whether the folder holds pointtraj's marks (a manifest that records something,
        ``work.toml``, a pipeline record or a trajectory store)."""
        return self.has_manifest() or any(
            p.exists() for p in (self.work_toml, self.pipeline_state, self.trajectories)
        )

    def has_manifest(self) -> bool:
        """Whether the manifest records anything (a lock alone leaves an empty one)."""
        try:
            return self.manifest.stat().st_size > 0
        except OSError:
            return False

    def owned(self) -> set[Path]:
        """The files the manifest lists that still exist (absolute paths)."""
        if not self.manifest.is_file():
            return set()
        try:
            lines = self.manifest.read_text(encoding="utf-8").splitlines()
        except OSError as exc:
            raise FileFormatError(self.manifest, f"unreadable ({exc.strerror or exc})") from None
        root = self.path.resolve()
        return {root / line for line in lines if line and (root / line).is_file()}

    def claim(self, force: bool = False) -> None:
        """Refuse to write into an existing, non-empty folder that is not a work folder.

        Parameters
        ----------
        force : bool
            Take the folder over anyway (it is logged).

        Raises
        ------
        WorkFolderError
            If the folder holds files but no pointtraj mark, and ``force`` is False.
        """
        if not self.path.is_dir() or self.is_pointtraj():
            return
        entries = sorted(p.name for p in self.path.iterdir())
        if not entries:
            return
        if not force:
            shown = ", ".join(entries[:5]) + (", ..." if len(entries) > 5 else "")
            raise WorkFolderError(
                f"{self.path}: not a pointtraj work folder (it holds {shown} but no work.toml); "
                "choose a new or empty folder, or pass --force-folder to use it anyway"
            )
        logger.warning("%s: using a folder that is not a pointtraj work folder", self.path)

    def remove_outputs(self, subfolders: Sequence[str], force: bool = False) -> list[Path]:
        """Remove the files pointtraj wrote in ``subfolders`` (e.g. ``["state", "clouds"]``).

        A file is pointtraj's when the manifest lists it. In a work folder of an older version
        (``work.toml`` but no manifest), when its name is one pointtraj gives there
        (:data:`OWN_NAMES`). Other files are kept and named in a warning; a subfolder is removed
        only when it ends up empty.

        Parameters
        ----------
        subfolders : sequence of str
        force : bool
            In a folder with no pointtraj mark, remove the files named as pointtraj names them
            (each folder and count is logged); without it such a folder is refused.

        Returns
        -------
        list of pathlib.Path
            The files removed.

        Raises
        ------
        WorkFolderError
            If the subfolders hold files and the folder has no pointtraj mark, and not ``force``.
        """
        present = [self.path / s for s in subfolders if (self.path / s).is_dir()]
        files = [p for d in present for p in sorted(d.rglob("*")) if p.is_file()]
        if not files:
            return []
        if self.has_manifest():
            owned = self.owned()
            mine = [p for p in files if p.resolve() in owned]
        elif self.work_toml.is_file() or force:
            mine = [
                p
                for p in files
                if p.parent.name in OWN_NAMES and OWN_NAMES[p.parent.name].match(p.name)
            ]
            if not self.work_toml.is_file():
                logger.warning(
                    "--force-folder: removing %d files named as pointtraj's in %s",
                    len(mine),
                    ", ".join(str(d) for d in present),
                )
        else:
            raise WorkFolderError(
                f"{self.path}: {', '.join(p.name + '/' for p in present)} hold files that "
                "pointtraj did not record writing (no work.toml, no manifest); refusing to "
                "remove them. Use another work folder, or pass --force-folder to remove the "
                "files named as pointtraj names them"
            )
        for p in mine:
            p.unlink(missing_ok=True)
        kept = sorted(set(files) - set(mine))
        if kept:
            logger.warning(
                "%s: kept %d files that pointtraj did not write: %s",
                self.path,
                len(kept),
                ", ".join(str(p.relative_to(self.path)) for p in kept[:5])
                + (", ..." if len(kept) > 5 else ""),
            )
        for d in present:
            for sub in sorted((q for q in d.rglob("*") if q.is_dir()), reverse=True) + [d]:
                with contextlib.suppress(OSError):
                    sub.rmdir()  # only when empty
        logger.info("%s: removed %d files of the previous run", self.path, len(mine))
        return mine

    @contextlib.contextmanager
    def lock(self, command: str = "pointtraj") -> Iterator[WorkFolder]:
        """Hold the folder for this process: one pointtraj run at a time writes into it.

        On entry (outermost only; the lock is re-entrant within a process) the folder is
        created, stale temporary files of killed runs are removed, and every file written
        below it is recorded in the manifest until exit. The lock is an ``flock`` on
        ``.pointtraj/lock``, so the OS releases it when a process dies.

        Parameters
        ----------
        command : str
            Named to a second run that finds the folder held.

        Raises
        ------
        WorkFolderError
            If another process holds the folder (naming its pid, host and command).
        """
        from .atomic import remove_stale_temporaries

        key = self.path.resolve()
        with _held_lock:
            if key in _held:
                _held[key][1] += 1
                reentered = True
            else:
                reentered = False
        if reentered:
            try:
                yield self
            finally:
                with _held_lock:
                    _held[key][1] -= 1
            return
        try:
            self.lock_file.parent.mkdir(parents=True, exist_ok=True)
            fd = os.open(self.lock_file, os.O_RDWR | os.O_CREAT, 0o666)
        except OSError as exc:
            raise WorkFolderError(
                f"{self.path}: cannot write into the work folder ({(exc.strerror or str(exc)).lower()})"
            ) from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _describe_holder(fd)
            os.close(fd)
            raise WorkFolderError(
                f"{self.path}: in use by {holder}; wait for it to finish or stop it"
            ) from None
        try:
            info = {
                "pid": os.getpid(),
                "host": socket.gethostname(),
                "command": command,
                "since": time.strftime("%Y-%m-%dT%H:%M:%S"),
            }
            with contextlib.suppress(OSError):  # on a full disk the lock holds without its note
                os.ftruncate(fd, 0)
                os.pwrite(fd, (json.dumps(info) + "\n").encode(), 0)
            with _held_lock:
                _held[key] = [fd, 1]
            stale = remove_stale_temporaries(self.path)
            if stale:
                logger.info(
                    "%s: removed %d temporary files of an interrupted run", self.path, len(stale)
                )
            if self.labels_pending.exists():
                logger.warning(
                    "%s: an interrupted `label` run left clouds/ partly relabelled; run "
                    "`pointtraj label` again",
                    self.path,
                )
            with self._recording():
                yield self
        finally:
            with _held_lock:
                _held.pop(key, None)
            with contextlib.suppress(OSError):
                os.ftruncate(fd, 0)
            os.close(fd)

    @contextlib.contextmanager
    def _recording(self) -> Iterator[None]:
        """Append every file installed below the folder to the manifest."""
        from .atomic import owner

        root = self.path.resolve()
        known = {str(p.relative_to(root)) for p in self.owned()}
        handle = open(self.manifest, "a", encoding="utf-8")
        guard = threading.Lock()

        def record(path: Path) -> None:
            rel = str(path.relative_to(root))
            with guard:
                if rel in known or rel.startswith(_OWN_DIR):
                    return
                known.add(rel)
                try:
                    handle.write(rel + "\n")
                    handle.flush()
                except OSError as exc:
                    # The file is installed; unrecorded, a restart keeps it (the safe side).
                    logger.warning("%s: cannot record %s (%s)", self.manifest, rel, exc.strerror)

        try:
            with owner(root, record):
                yield
        finally:
            with contextlib.suppress(OSError):
                handle.close()

    def check_capture(self, capture: str | os.PathLike) -> None:
        """Raise if ``work.toml`` records a capture other than ``capture``.

        Raises
        ------
        ValidationError
            Naming both folders.
        """
        recorded = self.capture_path()
        if recorded is not None and recorded.resolve() != Path(capture).resolve():
            raise ValidationError(
                f"{self.work_toml}: records capture {recorded}, not {Path(capture).resolve()}; "
                "use another work folder"
            )


def locked(command: str) -> Callable[[F], F]:
    """Decorate a stage function whose first argument is the work folder: run it under the
    folder's lock (:meth:`WorkFolder.lock`)."""

    def decorate(fn: F) -> F:
        @functools.wraps(fn)
        def wrapper(work: str | os.PathLike, *args: Any, **kwargs: Any) -> Any:
            with WorkFolder(work).lock(command):
                return fn(work, *args, **kwargs)

        return wrapper  # type: ignore[return-value]

    return decorate


def _describe_holder(fd: int) -> str:
    """Who holds a lock file, from what it wrote there."""
    try:
        info = json.loads(os.pread(fd, 4096, 0).decode() or "{}")
    except (OSError, ValueError):
        info = {}
    if not info:
        return "another pointtraj run"
    return (
        f"`{info.get('command', 'pointtraj')}` (pid {info.get('pid', '?')} on "
        f"{info.get('host', '?')}, since {info.get('since', '?')})"
    )
