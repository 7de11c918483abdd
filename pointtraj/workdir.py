"""The work folder: where every stage after the capture writes its outputs.

A work folder (``data_specs/work_folder.md``) belongs to one capture, recorded in
``WORK/work.toml``. :class:`WorkFolder` names its files, so no stage spells a path twice, and
reads and writes ``work.toml``.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path
from typing import Any

from .errors import FileFormatError, ValidationError

__all__ = ["WorkFolder", "parse_frames", "WORK_TOML"]

logger = logging.getLogger(__name__)

#: Name of the file that records the capture and the reconstruction run.
WORK_TOML = "work.toml"


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
        import tomli_w

        from .atomic import write_text_atomic

        doc = self.run_document(capture, frames, reconstruct)
        header = "# pointtraj work folder (see data_specs/work_folder.md)\n"
        self.path.mkdir(parents=True, exist_ok=True)
        write_text_atomic(self.work_toml, header + tomli_w.dumps(doc))

    def run_identity(self) -> dict[str, Any]:
        """The parts of ``work.toml`` that identify a reconstruction run (capture, frames,
        parameters); a run can resume only where they equal :meth:`run_document`'s."""
        data = self.read_toml()
        return {k: data.get(k) for k in ("capture", "reconstruct_run", "reconstruct")}

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
