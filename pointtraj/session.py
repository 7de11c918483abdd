"""A capture: a calibrated rig plus synchronised frames, from image folders or videos.

Layout (``data_specs/capture.md``)::

    <capture>/
      rig.toml                       calibration (pointtraj.rigio.toml)
      capture.toml                   optional: fps = 30.0
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
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from .atomic import atomic_path
from .camera import CameraRig
from .config import load_toml, save_toml
from .errors import FileFormatError, ValidationError

__all__ = ["Capture", "IMAGE_EXTENSIONS", "VIDEO_EXTENSIONS", "DEFAULT_FPS"]

logger = logging.getLogger(__name__)

IMAGE_EXTENSIONS = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff")
VIDEO_EXTENSIONS = (".mp4", ".avi", ".mov", ".mkv")
#: Frame rate assumed when neither capture.toml nor a video gives one.
DEFAULT_FPS = 30.0
#: JPEG quality of frames written by :meth:`Capture.write_frame`.
JPEG_QUALITY = 95
_CAPTURE_KEYS = ("fps", "image_format", "description", "source")
_INT_NAME = re.compile(r"^-?\d+$")


def _read_image(path: Path, camera: str, frame: int) -> np.ndarray:
    """(H, W, 3) uint8 RGB image of a file, or a FileFormatError naming camera and frame
    (:func:`pointtraj.images.read_rgb`: truncated JPEGs and PNGs included)."""
    from .images import read_rgb

    return read_rgb(path, f"camera {camera!r} frame {frame}")


class _ImageFolder:
    """Frames of one camera stored as numbered image files."""

    def __init__(self, camera: str, folder: Path) -> None:
        self.camera = camera
        self.folder = folder
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
    def num_frames(self) -> int:
        return len(self.files)

    def size(self) -> tuple[int, int] | None:
        return None if not self.files else self.read(0).shape[1::-1]

    def fps(self) -> float | None:
        return None

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

    def fps(self) -> float | None:
        return self._fps if np.isfinite(self._fps) and self._fps > 0 else None

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
        Frame rate: ``capture.toml`` ``fps``, else the first video's, else 30.
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
    ) -> None:
        self.path = path
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
                raise FileFormatError(rig_file, "no rig.toml in the capture (or pass rig=)")
            rig = load_rig(rig_file, fmt="toml")
        elif not isinstance(rig, CameraRig):
            rig = load_rig(rig)
        settings = _read_capture_toml(path)
        sources = _find_sources(path)
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
        _check_distinct_sources({n: sources[n] for n in rig.names}, path)
        counts = {n: sources[n].num_frames for n in rig.names}
        empty = [n for n, c in counts.items() if c == 0]
        if empty:
            raise FileFormatError(path, f"camera(s) {', '.join(empty)} have no frames")
        num_frames = min(counts.values())
        if len(set(counts.values())) > 1:
            msg = "cameras have different frame counts: " + ", ".join(
                f"{n}={c}" for n, c in counts.items()
            )
            if strict:
                raise FileFormatError(path, msg)
            logger.warning("%s: %s; using the first %d frames", path, msg, num_frames)
        fps = settings.get("fps")
        if fps is None:
            fps = next((f for s in sources.values() if (f := s.fps()) is not None), DEFAULT_FPS)
        cap = cls(
            path,
            rig,
            {n: sources[n] for n in rig.names},
            num_frames,
            fps,
            strict,
            settings.get("image_format"),
        )
        for name in rig.names:
            cap._check_size(name, sources[name].size())
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
        save_toml(path / "capture.toml", {"fps": float(fps), "image_format": image_format})
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
            msg = (
                f"camera {name!r} frame {frame}: image is {size[0]}x{size[1]} but the "
                f"calibration says {expected[0]}x{expected[1]}"
            )
            if self.strict:
                raise FileFormatError(self.path, msg)
            if name not in self._size_warned:
                logger.warning("%s: %s", self.path, msg)
                self._size_warned.add(name)
        self._sizes[name] = size


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
    return out


def _source_identity(source: _ImageFolder | _Video) -> list[tuple[Path, tuple[int, int]]]:
    """(resolved path, (device, inode)) of the files a source reads: its video, or the folder
    and its first image (a symlinked folder, or linked image files, give the same)."""
    files = [source.path] if isinstance(source, _Video) else [source.folder, *source.files[:1]]
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
