"""A capture: a calibrated rig plus synchronised frames, from image folders or videos.

Layout (``data_specs/capture.md``)::

    <capture>/
      rig.toml                       calibration (pointtraj.rigio.toml)
      capture.toml                   optional: fps = 30.0, up = "+z"
      labels.toml                    optional: the label set
      frames/<camera>/<index>.jpg    one folder per camera, integer file names (any padding),
                                     frame t = the t-th file in numeric order
      videos/<camera>.mp4            or one video per camera (.mp4, .avi, .mov, .mkv)

Frames are read lazily, one image at a time; videos are seeked by frame index with OpenCV and
their ``VideoCapture`` is kept open per camera.
"""

from __future__ import annotations

import logging
import os
import re
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

from .atomic import atomic_path
from .camera import CameraRig
from .config import load_toml, save_toml
from .errors import FileFormatError, ValidationError

__all__ = [
    "Capture",
    "IMAGE_EXTENSIONS",
    "VIDEO_EXTENSIONS",
    "DEFAULT_FPS",
    "PLAUSIBLE_FPS",
    "check_video_fps",
    "save_capture_toml",
    "CameraMedia",
    "check_media",
    "list_images",
]

logger = logging.getLogger(__name__)

IMAGE_EXTENSIONS = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff")
VIDEO_EXTENSIONS = (".mp4", ".avi", ".mov", ".mkv")
#: Frame rate assumed when neither capture.toml nor a video gives one.
DEFAULT_FPS = 30.0
#: Frame rates a video header may report and be believed, ``[low, high]``: outside it (a 0.2 fps
#: header, or a container's time base such as 90000) the value is reported and not used.
PLAUSIBLE_FPS = (1.0, 1000.0)
#: JPEG quality of frames written by :meth:`Capture.write_frame`.
JPEG_QUALITY = 95
_CAPTURE_KEYS = ("fps", "image_format", "up", "description", "source")
_INT_NAME = re.compile(r"^-?\d+$")


def _read_image(path: Path, camera: str, frame: int) -> np.ndarray:
    """(H, W, 3) uint8 RGB image of a file, or a FileFormatError naming camera and frame
    (:func:`pointtraj.images.read_rgb`: truncated JPEGs and PNGs included)."""
    from .images import read_rgb

    return read_rgb(path, f"camera {camera!r} frame {frame}")


class _ImageFolder:
    """Frames of one camera stored as numbered image files."""

    def __init__(self, camera: str, folder: Path, files: list[Path] | None = None) -> None:
        self.camera = camera
        self.folder = folder
        if files is not None:  # chosen and ordered by the caller (check_media)
            self.files = list(files)
            return
        found: list[tuple[int, Path]] = []
        for f in folder.iterdir():
            if f.name.startswith(".") or not f.is_file():
                continue  # hidden files, including atomic-write temporaries
            if f.suffix.lower() not in IMAGE_EXTENSIONS:
                raise FileFormatError(
                    f, f"camera {camera!r}: not an image ({', '.join(IMAGE_EXTENSIONS)})"
                )
            if not _INT_NAME.match(f.stem):
                raise FileFormatError(f, f"camera {camera!r}: frame file name must be an integer")
            found.append((int(f.stem), f))
        found.sort()
        numbers = [n for n, _ in found]
        if len(set(numbers)) != len(numbers):
            dup = sorted({n for n in numbers if numbers.count(n) > 1})
            raise FileFormatError(folder, f"camera {camera!r}: frame number(s) {dup} repeat")
        if numbers and numbers[-1] - numbers[0] + 1 != len(numbers):
            logger.warning(
                "%s: frame numbers %d..%d have gaps; frames are taken in numeric order",
                folder,
                numbers[0],
                numbers[-1],
            )
        self.files = [f for _, f in found]

    @property
    def path(self) -> Path:
        """The folder, named in error messages."""
        return self.folder

    @property
    def num_frames(self) -> int:
        return len(self.files)

    def size(self) -> tuple[int, int] | None:
        return None if not self.files else self.read(0).shape[1::-1]

    def read(self, frame: int) -> np.ndarray:
        return _read_image(self.files[frame], self.camera, frame)

    def close(self) -> None:
        pass


class _Video:
    """Frames of one camera in a video file, opened on first use and seeked by index."""

    def __init__(self, camera: str, path: Path) -> None:
        import cv2

        self.camera = camera
        self.path = path
        self._cap: Any = None
        self._next = 0  # index of the frame the decoder returns next
        cap = cv2.VideoCapture(str(path))
        try:
            if not cap.isOpened():
                raise FileFormatError(path, f"camera {camera!r}: OpenCV cannot open this video")
            self._count = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
            self._size = (
                int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)),
                int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)),
            )
            self._fps = float(cap.get(cv2.CAP_PROP_FPS))
        finally:
            cap.release()
        if self._count <= 0:
            raise FileFormatError(path, f"camera {camera!r}: video reports no frames")

    @property
    def num_frames(self) -> int:
        return self._count

    def size(self) -> tuple[int, int] | None:
        return self._size

    @property
    def header_fps(self) -> float:
        """The frame rate the video's header reports (may be 0, NaN or implausible)."""
        return self._fps

    def read(self, frame: int) -> np.ndarray:
        import cv2

        if self._cap is None:
            self._cap = cv2.VideoCapture(str(self.path))
            self._next = 0
        if frame != self._next:
            self._cap.set(cv2.CAP_PROP_POS_FRAMES, frame)
        ok, img = self._cap.read()
        if not ok or img is None:
            self._next = -1  # position unknown: seek next time
            raise FileFormatError(
                self.path, f"camera {self.camera!r} frame {frame}: cannot decode this frame"
            )
        self._next = frame + 1
        return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)

    def close(self) -> None:
        if self._cap is not None:
            self._cap.release()
            self._cap = None

    def __getstate__(self) -> dict[str, Any]:
        # An open cv2.VideoCapture cannot be pickled (process pools): reopen after unpickling.
        state = dict(self.__dict__)
        state["_cap"] = None
        state["_next"] = 0
        return state


class Capture:
    """A calibrated, synchronised multi-camera capture (see the module docstring for the layout).

    Use :meth:`open` to read an existing capture and :meth:`create` to write a new one.

    Attributes
    ----------
    path : pathlib.Path
        The capture folder.
    rig : CameraRig
        The calibration, restricted to the cameras that have frames.
    num_frames : int
        T, the number of synchronised frames.
    fps : float
        Frame rate: ``capture.toml`` ``fps``, else the first plausible video header's (in
        :data:`PLAUSIBLE_FPS`; others are reported with a warning), else 30.
    up : (3,) float ndarray or None
        The world's up direction from ``capture.toml`` ``up`` (unit vector), or None when it is
        not set (``"auto"``): :func:`pointtraj.geometry.resolve_up` then detects it.
    strict : bool
        Whether inconsistencies are errors (True) or warnings (False).
    """

    def __init__(
        self,
        path: Path,
        rig: CameraRig,
        sources: dict[str, _ImageFolder | _Video] | None,
        num_frames: int,
        fps: float,
        strict: bool = True,
        image_format: str | None = None,
        up: np.ndarray | None = None,
    ) -> None:
        self.path = path
        self.up = up
        self.rig = rig
        self._sources = sources or {}
        self.num_frames = int(num_frames)
        self.fps = float(fps)
        self.strict = strict
        self._image_format = image_format
        self._sizes: dict[str, tuple[int, int]] = {}
        self._size_warned: set[str] = set()

    # -- opening -----------------------------------------------------------------------------
    @classmethod
    def open(
        cls,
        path: str | os.PathLike,
        rig: CameraRig | str | os.PathLike | None = None,
        *,
        strict: bool = True,
    ) -> Capture:
        """Open a capture folder.

        Parameters
        ----------
        path : path-like
            The capture folder.
        rig : CameraRig or path-like, optional
            The calibration, or a rig file in any format of :func:`pointtraj.rigio.load_rig`
            (default ``<path>/rig.toml``).
        strict : bool
            If False, tolerate and log: cameras with different frame counts (truncated to the
            shortest), image sizes that disagree with the calibration, frame folders or videos
            of cameras not in the rig (ignored), and rig cameras without frames (dropped).

        Returns
        -------
        Capture

        Raises
        ------
        FileFormatError
            Naming the camera (and file) for: no frames, a camera folder or video not in the rig,
            a rig camera without frames, mismatched frame counts, a corrupt first image, or an
            image size that disagrees with the calibration (when ``strict``).
        """
        from .rigio import load_rig

        path = Path(path)
        if not path.is_dir():
            raise FileFormatError(path, "capture folder does not exist")
        if rig is None:
            rig_file = path / "rig.toml"
            if not rig_file.is_file():
                raise FileFormatError(
                    rig_file,
                    "no rig.toml in the capture: make the capture with `pointtraj capture`, or "
                    "write the calibration there with `pointtraj rig convert`",
                )
            rig = load_rig(rig_file, fmt="toml")
        elif not isinstance(rig, CameraRig):
            rig = load_rig(rig)
        settings = _read_capture_toml(path)
        checked = _check_sources(path, rig, _find_sources(path), strict)
        rig, sources, num_frames = checked.rig, checked.sources, checked.num_frames
        fps = settings.get("fps")
        if fps is None:
            fps = _fps_from_videos([sources[n] for n in rig.names], path)
        cap = cls(
            path,
            rig,
            {n: sources[n] for n in rig.names},
            num_frames,
            fps,
            strict,
            settings.get("image_format"),
            up=settings.get("up"),
        )
        cap._sizes.update(checked.sizes)
        cap._size_warned.update(n for n in rig.names if checked.sizes[n] != rig[n].size)
        logger.info(
            "opened capture %s: %d cameras, %d frames at %.3g fps",
            path,
            len(rig),
            num_frames,
            cap.fps,
        )
        return cap

    # -- creating ----------------------------------------------------------------------------
    @classmethod
    def create(
        cls,
        path: str | os.PathLike,
        rig: CameraRig,
        fps: float = DEFAULT_FPS,
        *,
        image_format: str = "jpg",
    ) -> Capture:
        """Start a new capture folder: write ``rig.toml`` and ``capture.toml``.

        Frames are then added with :meth:`write_frame`; :meth:`open` the folder to read it
        back with all consistency checks.

        Parameters
        ----------
        path : path-like
            The capture folder (created; existing frames are kept and may be overwritten).
        rig : CameraRig
        fps : float
            Frame rate, positive.
        image_format : {"jpg", "png"}
            How :meth:`write_frame` stores frames (JPEG quality 95, or lossless PNG).

        Returns
        -------
        Capture
            A writable capture; ``num_frames`` counts the frames written through it.
        """
        from .rigio.toml import save_rig_toml

        if image_format not in ("jpg", "png"):
            raise ValidationError(f"image_format must be 'jpg' or 'png', got {image_format!r}")
        if not np.isfinite(fps) or fps <= 0:
            raise ValidationError(f"fps must be positive, got {fps}")
        if not isinstance(rig, CameraRig):
            raise ValidationError(f"rig must be a CameraRig, got {type(rig).__name__}")
        path = Path(path)
        path.mkdir(parents=True, exist_ok=True)
        save_rig_toml(rig, path / "rig.toml")
        save_capture_toml(path, fps=fps, image_format=image_format)
        cap = cls(path, rig, None, 0, fps, True, image_format)
        for name in rig.names:
            cap._sizes[name] = rig[name].size
        return cap

    def write_frame(self, camera: str | int, frame: int, image: np.ndarray) -> Path:
        """Write one frame of one camera to ``frames/<camera>/<frame:06d>.<ext>``, atomically.

        Parameters
        ----------
        camera : str or int
            Camera name or index in the rig.
        frame : int
            Frame index, non-negative.
        image : (H, W, 3) uint8 ndarray
            RGB image of the camera's calibrated size.

        Returns
        -------
        pathlib.Path
            The file written.
        """
        import cv2

        if self._sources:
            raise ValidationError(
                f"{self.path}: write_frame works on a capture made by Capture.create, not on one "
                "opened for reading"
            )
        name = self._camera_name(camera)
        if int(frame) != frame or frame < 0:
            raise ValidationError(f"frame must be a non-negative integer, got {frame!r}")
        w, h = self.rig[name].size
        img = np.asarray(image)
        if img.shape != (h, w, 3) or img.dtype != np.uint8:
            raise ValidationError(
                f"image for camera {name!r} frame {frame}: expected ({h}, {w}, 3) uint8 RGB, "
                f"got {img.shape} {img.dtype}"
            )
        ext = self._image_format or "jpg"
        params = [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY] if ext == "jpg" else []
        ok, buf = cv2.imencode(f".{ext}", np.ascontiguousarray(img[..., ::-1]), params)
        if not ok:
            raise FileFormatError(self.path, f"camera {name!r} frame {frame}: encoding failed")
        out = self.path / "frames" / name / f"{int(frame):06d}.{ext}"
        with atomic_path(out) as tmp:
            tmp.write_bytes(buf.tobytes())
        self.num_frames = max(self.num_frames, int(frame) + 1)
        return out

    # -- reading -----------------------------------------------------------------------------
    @property
    def camera_names(self) -> list[str]:
        """Names of the C cameras, in rig order."""
        return self.rig.names

    @property
    def labels_path(self) -> Path | None:
        """``<capture>/labels.toml`` if it exists."""
        p = self.path / "labels.toml"
        return p if p.is_file() else None

    def image_size(self, camera: str | int) -> tuple[int, int]:
        """``(width, height)`` of a camera's frames (its calibrated size unless strict=False let
        a different size through)."""
        name = self._camera_name(camera)
        return self._sizes.get(name, self.rig[name].size)

    def read(self, camera: str | int, frame: int) -> np.ndarray:
        """One frame of one camera.

        Parameters
        ----------
        camera : str or int
            Camera name or index in the rig.
        frame : int
            Frame index in ``[0, num_frames)``.

        Returns
        -------
        (H, W, 3) uint8 ndarray
            RGB.

        Raises
        ------
        ValidationError
            For an unknown camera or a frame out of range.
        FileFormatError
            If the image cannot be read or decoded, or its size disagrees with the calibration
            (when ``strict``).
        """
        name = self._camera_name(camera)
        if isinstance(frame, bool) or int(frame) != frame or not 0 <= frame < self.num_frames:
            raise ValidationError(
                f"camera {name!r}: frame {frame!r} out of range [0, {self.num_frames})"
            )
        frame = int(frame)
        source = self._sources.get(name)
        if source is None:  # a capture being written: read the file back
            files = [
                p
                for ext in IMAGE_EXTENSIONS
                if (p := self.path / "frames" / name / f"{frame:06d}{ext}").is_file()
            ]
            if not files:
                raise FileFormatError(
                    self.path / "frames" / name, f"camera {name!r} frame {frame}: no image file"
                )
            img = _read_image(files[0], name, frame)
        else:
            img = source.read(frame)
        self._check_size(name, img.shape[1::-1], frame)
        return img

    def iter_frame(self, frame: int) -> dict[str, np.ndarray]:
        """All cameras' images of one frame, ``{camera name: (H, W, 3) uint8 RGB}``."""
        return {name: self.read(name, frame) for name in self.camera_names}

    def __iter__(self) -> Iterator[dict[str, np.ndarray]]:
        for t in range(self.num_frames):
            yield self.iter_frame(t)

    def __len__(self) -> int:
        return self.num_frames

    def close(self) -> None:
        """Release open videos (they reopen on the next read)."""
        for s in self._sources.values():
            s.close()

    def __enter__(self) -> Capture:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return (
            f"Capture({str(self.path)!r}, {len(self.rig)} cameras, {self.num_frames} frames, "
            f"{self.fps:g} fps)"
        )

    # -- helpers -----------------------------------------------------------------------------
    def _camera_name(self, camera: str | int) -> str:
        if isinstance(camera, str):
            self.rig.index(camera)  # raises ValidationError naming the cameras
            return camera
        if isinstance(camera, int | np.integer) and 0 <= camera < len(self.rig):
            return self.rig.names[int(camera)]
        raise ValidationError(
            f"camera must be a name or an index in [0, {len(self.rig)}), got {camera!r}"
        )

    def _check_size(self, name: str, size: tuple[int, int] | None, frame: int = 0) -> None:
        if size is None:
            return
        size = (int(size[0]), int(size[1]))
        expected = self.rig[name].size
        if size != expected:
            msg = _size_message(name, frame, size, expected)
            if self.strict:
                source = self._sources.get(name)
                raise FileFormatError(self.path if source is None else source.path, msg)
            if name not in self._size_warned:
                logger.warning("%s: %s", self.path, msg)
                self._size_warned.add(name)
        self._sizes[name] = size


def save_capture_toml(
    capture: str | os.PathLike,
    *,
    fps: float | None = None,
    image_format: str | None = None,
    up: str | list[float] | None = None,
    source: str | None = None,
    description: str | None = None,
    comment: str = "",
) -> Path:
    """Write ``<capture>/capture.toml`` (atomically) with the settings given; None is left out.

    Parameters
    ----------
    capture : path-like
        The capture folder.
    fps : float, optional
        Frame rate, positive.
    image_format : {"jpg", "png"}, optional
    up : str or 3 floats, optional
        As :func:`pointtraj.geometry.parse_up` reads it (``"auto"`` is left out).
    source, description : str, optional
    comment : str
        A comment at the top of the file.

    Returns
    -------
    pathlib.Path
        The file written.

    Raises
    ------
    ValidationError
        For a bad value (the file is not written).
    """
    from .geometry import parse_up

    doc: dict[str, Any] = {}
    if fps is not None:
        if isinstance(fps, bool) or not np.isfinite(fps) or not fps > 0:
            raise ValidationError(f"fps must be positive, got {fps!r}")
        doc["fps"] = float(fps)
    if image_format is not None:
        if image_format not in ("jpg", "png"):
            raise ValidationError(f"image_format must be 'jpg' or 'png', got {image_format!r}")
        doc["image_format"] = image_format
    if up is not None and parse_up(up, "up") is not None:
        doc["up"] = up if isinstance(up, str) else [float(v) for v in up]
    for key, value in (("source", source), ("description", description)):
        if value:
            doc[key] = str(value)
    file = Path(capture) / "capture.toml"
    save_toml(file, doc, comment=comment)
    return file


def _read_capture_toml(path: Path) -> dict[str, Any]:
    """Validated settings of ``capture.toml`` (empty if absent)."""
    file = path / "capture.toml"
    if not file.is_file():
        return {}
    data = load_toml(file)
    unknown = sorted(set(data) - set(_CAPTURE_KEYS))
    if unknown:
        logger.warning("%s: ignoring unknown key(s) %s", file, ", ".join(unknown))
    out: dict[str, Any] = {}
    if "fps" in data:
        fps = data["fps"]
        if isinstance(fps, bool) or not isinstance(fps, int | float) or not fps > 0:
            raise FileFormatError(file, f"fps: expected a positive number, got {fps!r}")
        out["fps"] = float(fps)
    if "image_format" in data:
        if data["image_format"] not in ("jpg", "png"):
            raise FileFormatError(
                file, f"image_format: expected 'jpg' or 'png', got {data['image_format']!r}"
            )
        out["image_format"] = data["image_format"]
    if "up" in data:
        from .geometry import parse_up

        try:
            out["up"] = parse_up(data["up"], "up")
        except ValidationError as exc:
            raise FileFormatError(file, str(exc)) from None
    return out


def check_video_fps(fps: float | None, path: str | os.PathLike) -> float | None:
    """A video header's frame rate if it is plausible (in :data:`PLAUSIBLE_FPS`), else None.

    An implausible one (below 1 fps, above 1000, zero, NaN) is logged as a warning naming the
    file and how to set the right one.

    Parameters
    ----------
    fps : float or None
        What the header reports (``cv2.CAP_PROP_FPS``).
    path : path-like
        The video, named in the warning.

    Returns
    -------
    float or None
    """
    if fps is None or not np.isfinite(fps) or fps <= 0:
        logger.warning(
            "%s: the video header gives no frame rate; set fps in capture.toml "
            "(pointtraj capture --fps)",
            path,
        )
        return None
    low, high = PLAUSIBLE_FPS
    if not low <= fps <= high:
        logger.warning(
            "%s: the video header says %.4g fps, which is implausible (outside %g-%g); not "
            "using it: set the right rate with fps = ... in capture.toml "
            "(pointtraj capture --fps)",
            path,
            fps,
            low,
            high,
        )
        return None
    return float(fps)


def _fps_from_videos(sources: list[_ImageFolder | _Video], path: Path) -> float:
    """The frame rate of a capture without ``capture.toml`` ``fps``: the first plausible video
    header's (:func:`check_video_fps` warns about the others), else :data:`DEFAULT_FPS`.
    Headers that disagree are logged."""
    videos = [s for s in sources if isinstance(s, _Video)]
    rates = {v.path: check_video_fps(v.header_fps, v.path) for v in videos}
    good = {p: f for p, f in rates.items() if f is not None}
    if len(set(good.values())) > 1:
        logger.warning(
            "%s: the videos' headers disagree on the frame rate (%s); using the first; set fps "
            "in capture.toml to choose",
            path,
            ", ".join(f"{p.name} {f:.4g}" for p, f in good.items()),
        )
    if good:
        return next(iter(good.values()))
    if videos:
        logger.warning(
            "%s: no video gives a plausible frame rate; assuming %g fps (set fps in capture.toml)",
            path,
            DEFAULT_FPS,
        )
    return DEFAULT_FPS


def _shown(file: Path, root: Path) -> str:
    """``file`` relative to ``root`` if it is inside, else as given."""
    try:
        return file.relative_to(root).as_posix()
    except ValueError:
        return str(file)


def _size_message(name: str, frame: int, size: tuple[int, int], expected: tuple[int, int]) -> str:
    return (
        f"camera {name!r} frame {frame}: image is {size[0]}x{size[1]} but the calibration says "
        f"{expected[0]}x{expected[1]}"
    )


@dataclass
class _Checked:
    """What :func:`_check_sources` found: the rig kept, its sources, T and first-frame sizes."""

    rig: CameraRig
    sources: dict[str, _ImageFolder | _Video]
    num_frames: int
    sizes: dict[str, tuple[int, int]]


def _check_sources(
    path: Path, rig: CameraRig, sources: dict[str, _ImageFolder | _Video], strict: bool
) -> _Checked:
    """Match frame sources to the rig's cameras and check them, as :meth:`Capture.open` does.

    Checks: sources of cameras not in the rig, rig cameras without a source, two cameras
    reading the same files, cameras without frames, frame counts that differ (the message
    lists every camera's count and file), and first-frame sizes that disagree with the
    calibration (the error names the camera's file). With ``strict=False`` the recoverable
    ones are logged: extra sources ignored, cameras without frames dropped, frame counts
    truncated to the shortest, sizes let through.

    Raises
    ------
    FileFormatError
        Naming ``path`` (or the camera's file, for a size) and what is wrong.
    """
    sources = dict(sources)
    extra = sorted(set(sources) - set(rig.names))
    if extra:
        msg = f"frames of camera(s) {', '.join(extra)} but the rig has {', '.join(rig.names)}"
        if strict:
            raise FileFormatError(path, msg)
        logger.warning("%s: %s; ignoring them", path, msg)
        for name in extra:
            sources.pop(name)
    missing = [n for n in rig.names if n not in sources]
    if missing:
        msg = f"rig camera(s) {', '.join(missing)} have no frames or video"
        if strict or len(missing) == len(rig):
            raise FileFormatError(path, msg)
        logger.warning("%s: %s; dropping them from the rig", path, msg)
        rig = rig.subset([n for n in rig.names if n in sources])
    sources = {n: sources[n] for n in rig.names}
    _check_distinct_sources(sources, path)
    counts = {n: sources[n].num_frames for n in rig.names}
    empty = [n for n, c in counts.items() if c == 0]
    if empty:
        raise FileFormatError(path, f"camera(s) {', '.join(empty)} have no frames")
    num_frames = min(counts.values())
    if len(set(counts.values())) > 1:
        msg = "cameras have different frame counts: " + ", ".join(
            f"{n}={c} ({_shown(sources[n].path, path)})" for n, c in counts.items()
        )
        if strict:
            raise FileFormatError(path, msg)
        logger.warning("%s: %s; using the first %d frames", path, msg, num_frames)
    sizes = {}
    for name, source in sources.items():
        size = source.size()
        size = rig[name].size if size is None else (int(size[0]), int(size[1]))
        if size != rig[name].size:
            msg = _size_message(name, 0, size, rig[name].size)
            if strict:
                raise FileFormatError(source.path, msg)
            logger.warning("%s: %s", source.path, msg)
        sizes[name] = size
    return _Checked(rig, sources, num_frames, sizes)


_DIGITS = re.compile(r"\d+")


def list_images(folder: str | os.PathLike) -> list[Path]:
    """The image files of a folder in frame order, whatever their names.

    Files whose names all hold a number (``frame_0012.png``, ``12.jpg``) are ordered by the
    last number in the name, then by name; otherwise by name. Hidden files and files that are
    not images (:data:`IMAGE_EXTENSIONS`) are left out.

    Parameters
    ----------
    folder : path-like

    Returns
    -------
    list of pathlib.Path

    Raises
    ------
    FileFormatError
        If ``folder`` is not a folder.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise FileFormatError(folder, "not a folder")
    files = [
        f
        for f in folder.iterdir()
        if f.is_file() and not f.name.startswith(".") and f.suffix.lower() in IMAGE_EXTENSIONS
    ]
    numbers = [_DIGITS.findall(f.stem) for f in files]
    if files and all(numbers):
        return [f for _, f in sorted(zip((int(n[-1]) for n in numbers), files))]
    return sorted(files)


@dataclass(frozen=True)
class CameraMedia:
    """One camera's frames outside a capture folder, as :func:`check_media` found them.

    Attributes
    ----------
    camera : str
        The rig camera.
    kind : {"video", "images"}
    path : pathlib.Path
        The video file or the image folder.
    files : tuple of pathlib.Path
        The images in frame order (empty for a video).
    num_frames : int
    size : (int, int)
        ``(width, height)`` of the first frame.
    header_fps : float or None
        The frame rate the video's header reports, as it is (None for images): pass it to
        :func:`check_video_fps` before use.
    """

    camera: str
    kind: Literal["video", "images"]
    path: Path
    files: tuple[Path, ...]
    num_frames: int
    size: tuple[int, int]
    header_fps: float | None


def check_media(
    rig: CameraRig, media: Mapping[str, str | os.PathLike], *, strict: bool = True
) -> tuple[CameraRig, list[CameraMedia], int]:
    """Check videos or image folders against a rig before they become a capture.

    The same checks as :meth:`Capture.open` (one implementation): every rig camera has media
    and no media names an unknown camera, no two cameras read the same file, frame counts
    agree, and first-frame sizes equal the calibration. Image folders may name their files
    anyhow (:func:`list_images` orders them).

    Parameters
    ----------
    rig : CameraRig
    media : mapping of str to path-like
        Camera name -> its video file (:data:`VIDEO_EXTENSIONS`) or image folder.
    strict : bool
        As for :meth:`Capture.open`: if False, rig cameras without media are dropped, frame
        counts truncated to the shortest and size mismatches let through, with warnings.

    Returns
    -------
    rig : CameraRig
        The rig, less the cameras dropped (``strict=False``).
    media : list of CameraMedia
        In rig order.
    num_frames : int
        T, the synchronised frame count.

    Raises
    ------
    FileFormatError
        Naming the file: a missing path, a file that is not a video, a folder without images,
        a video OpenCV cannot open, frame counts that differ (each camera's count and file
        listed), a size that disagrees with the calibration.
    """
    sources: dict[str, _ImageFolder | _Video] = {}
    for camera, where in media.items():
        p = Path(where)
        if p.is_dir():
            files = list_images(p)
            if not files:
                raise FileFormatError(
                    p, f"camera {camera!r}: no images ({', '.join(IMAGE_EXTENSIONS)})"
                )
            sources[camera] = _ImageFolder(camera, p, files)
        elif p.is_file():
            if p.suffix.lower() not in VIDEO_EXTENSIONS:
                raise FileFormatError(
                    p,
                    f"camera {camera!r}: not a video ({', '.join(VIDEO_EXTENSIONS)}) nor an "
                    "image folder",
                )
            sources[camera] = _Video(camera, p)
        else:
            raise FileFormatError(p, f"camera {camera!r}: no such file or folder")
    where = Path(os.path.commonpath([str(Path(m).resolve()) for m in media.values()]))
    checked = _check_sources(where, rig, sources, strict)
    out = []
    for name, src in checked.sources.items():
        video = isinstance(src, _Video)
        out.append(
            CameraMedia(
                name,
                "video" if video else "images",
                src.path,
                () if video else tuple(src.files),
                src.num_frames,
                checked.sizes[name],
                src.header_fps if video else None,
            )
        )
    return checked.rig, out, checked.num_frames


def _source_identity(source: _ImageFolder | _Video) -> list[tuple[Path, tuple[int, int]]]:
    """(resolved path, (device, inode)) of the files a source reads: its video, or the folder
    and its first image (a symlinked folder, or linked image files, give the same)."""
    files = [source.path] if isinstance(source, _Video) else [source.folder, *source.files[:1]]
    files = list(dict.fromkeys(files))
    out = []
    for f in files:
        st = f.stat()
        out.append((f.resolve(), (st.st_dev, st.st_ino)))
    return out


def _check_distinct_sources(sources: dict[str, _ImageFolder | _Video], path: Path) -> None:
    """Refuse two cameras that read the same frames (a symlinked or linked folder or video).

    Raises
    ------
    FileFormatError
        Naming the capture, both cameras and the shared path.
    """
    seen: dict[tuple[int, int], str] = {}
    for name, source in sources.items():
        for resolved, key in _source_identity(source):
            other = seen.setdefault(key, name)
            if other != name:
                raise FileFormatError(
                    path,
                    f"cameras {other!r} and {name!r} read the same frames ({resolved}): "
                    "a duplicated or symlinked camera folder or video",
                )


def _find_sources(path: Path) -> dict[str, _ImageFolder | _Video]:
    """Per camera, its frame folder (``frames/<camera>/``) or else its video (``videos/``)."""
    sources: dict[str, _ImageFolder | _Video] = {}
    frames = path / "frames"
    videos = path / "videos"
    if frames.is_dir():
        for d in sorted(frames.iterdir()):
            if d.is_dir() and not d.name.startswith("."):
                sources[d.name] = _ImageFolder(d.name, d)
    if videos.is_dir():
        for f in sorted(videos.iterdir()):
            if f.name.startswith(".") or not f.is_file():
                continue
            if f.suffix.lower() not in VIDEO_EXTENSIONS:
                logger.debug("ignoring %s (not a video)", f)
                continue
            if f.stem in sources:
                if isinstance(sources[f.stem], _Video):
                    raise FileFormatError(f, f"camera {f.stem!r} has two videos")
                logger.info("camera %s: using frames/ rather than %s", f.stem, f)
                continue
            sources[f.stem] = _Video(f.stem, f)
    if not sources:
        raise FileFormatError(path, "no frames/<camera>/ folders or videos/<camera>.mp4 files")
    return sources
