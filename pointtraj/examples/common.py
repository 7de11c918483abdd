"""The example registry and what every fetcher shares: error, result, output-folder helpers."""

from __future__ import annotations

import os
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import FileFormatError, PointtrajError, ValidationError
from .mapping import ImageMapping

POSE2SIM_REQUIREMENT = "pose2sim==0.10.49"
POSE2SIM_DEMO = "Pose2Sim/Demo_SinglePerson/"
#: The folder inside the wheel of each Pose2Sim example (the same four cameras and calibration).
POSE2SIM_DEMOS = {"pose2sim": POSE2SIM_DEMO, "pose2sim-multi": "Pose2Sim/Demo_MultiPerson/"}

_MARK = "pointtraj examples"


class ExampleNotFoundError(PointtrajError):
    """The source files of an example cannot be found or downloaded."""


@dataclass(frozen=True)
class ExampleSpec:
    """One example capture pointtraj knows how to lay out.

    Attributes
    ----------
    name : str
    description : str
    source : str
        Where the files come from.
    licence : str
        SPDX identifier of the source's licence.
    """

    name: str
    description: str
    source: str
    licence: str


#: Every example capture, by name.
EXAMPLES: dict[str, ExampleSpec] = {
    "pose2sim": ExampleSpec(
        "pose2sim",
        "Pose2Sim Demo_SinglePerson: 4 cameras, 100 frames at 60 fps, 1088x1920 portrait, a man "
        "balancing on a treadmill (Qualisys calibration)",
        f"PyPI wheel {POSE2SIM_REQUIREMENT}, folder {POSE2SIM_DEMO}",
        "BSD-3-Clause",
    ),
    "pose2sim-multi": ExampleSpec(
        "pose2sim-multi",
        "Pose2Sim Demo_MultiPerson: the same 4 cameras and calibration, 100 frames at 60 fps, "
        "1088x1920 portrait, a man balancing on a treadmill and a woman beside it",
        f"PyPI wheel {POSE2SIM_REQUIREMENT}, folder {POSE2SIM_DEMOS['pose2sim-multi']}",
        "BSD-3-Clause",
    ),
    "caliscope-board": ExampleSpec(
        "caliscope-board",
        "caliscope post_optimization session: 4 webcams, 57 frames at ~6 fps, 1280x720, a "
        "person moving a ChArUco board (caliscope calibration, 2D/3D corners)",
        "shared/data/caliscope_board_4cam (github.com/mprib/caliscope @ ddda95b, "
        "tests/sessions/post_optimization)",
        "BSD-2-Clause",
    ),
}


@dataclass(frozen=True)
class ExampleCapture:
    """What a ``fetch_*`` call wrote.

    Attributes
    ----------
    name : str
        Example name.
    path : pathlib.Path
        The capture folder.
    camera_names : list of str
    num_frames : dict of str to int
        Frames per camera.
    fps : float
    corrections : dict of str to ImageMapping
        Cameras whose calibration was adapted to the stored frames.
    notes : list of str
        Findings worth reporting (also in the capture's README.md).
    """

    name: str
    path: Path
    camera_names: list[str]
    num_frames: dict[str, int]
    fps: float
    corrections: dict[str, ImageMapping] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)


# -- output folder --------------------------------------------------------------------------


def _start_output(out: Path, overwrite: bool) -> Path:
    """A temporary folder beside ``out`` to build the capture in (checked before any work)."""
    if out.exists():
        if not out.is_dir():
            raise ValidationError(f"out: {out} exists and is not a folder")
        if any(out.iterdir()):
            if not overwrite:
                raise ValidationError(
                    f"out: {out} exists and is not empty; choose a new folder or overwrite it "
                    "(overwrite=True, --force)"
                )
            mark = out / "capture.toml"
            if not (mark.is_file() and _MARK in mark.read_text(errors="replace")):
                raise ValidationError(
                    f"out: {out} is not a capture written by {_MARK}; refusing to overwrite it"
                )
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    umask = os.umask(0)
    os.umask(umask)
    tmp.chmod(0o777 & ~umask)  # mkdtemp makes it private; the capture is an ordinary folder
    return tmp


def _finish_output(tmp: Path, out: Path) -> None:
    """Move the finished capture into place, replacing an old one."""
    old = None
    if out.exists():
        old = Path(tempfile.mkdtemp(prefix=f".{out.name}.old.", dir=out.parent))
        os.replace(out, old / "capture")
    os.replace(tmp, out)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


def _save_capture_toml(path: Path, fps: float, source: str, description: str) -> None:
    """Write an example's ``capture.toml``, marked as written by :data:`_MARK`."""
    from ..config import save_toml

    doc = {"fps": float(fps), "source": source, "description": description}
    save_toml(path, doc, comment=f"written by {_MARK}")


def _video_info(path: Path) -> tuple[int, tuple[int, int], float]:
    """Frame count, (width, height) and fps of a video, or a FileFormatError."""
    import cv2

    cap = cv2.VideoCapture(str(path))
    try:
        if not cap.isOpened():
            raise FileFormatError(path, "OpenCV cannot open this video")
        count = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
        size = (int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)))
        fps = float(cap.get(cv2.CAP_PROP_FPS))
    finally:
        cap.release()
    return count, size, fps


def _first_frame(path: Path) -> np.ndarray:
    """(H, W, 3) uint8 RGB first frame of a video."""
    import cv2

    cap = cv2.VideoCapture(str(path))
    try:
        ok, img = cap.read()
    finally:
        cap.release()
    if not ok or img is None:
        raise FileFormatError(path, "cannot decode the first frame")
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
