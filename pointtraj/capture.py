"""Make a capture folder (``data_specs/capture.md``) from videos or image folders and a rig file.

:func:`make_capture` is what ``pointtraj capture`` runs: it reads the rig in any format of
:func:`pointtraj.rigio.load_rig`, checks the media against it with
:func:`pointtraj.session.check_media` (the checks of :meth:`Capture.open`: cameras, frame
counts, image sizes), then writes ``rig.toml``, ``capture.toml``, an optional ``labels.toml``
and the media (copied or linked) into a new folder, and opens the result with
:meth:`Capture.open` before moving it into place. Nothing is left behind on an error.
"""

from __future__ import annotations

import logging
import os
import shutil
import tempfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from .camera import CameraRig
from .errors import FileFormatError, ValidationError
from .session import (
    VIDEO_EXTENSIONS,
    CameraMedia,
    Capture,
    check_media,
    check_video_fps,
    save_capture_toml,
)

__all__ = ["CaptureMade", "make_capture", "media_by_camera"]

logger = logging.getLogger(__name__)

#: How media get into the capture: copies, or symbolic links to the originals.
MediaMode = Literal["copy", "link"]


@dataclass
class CaptureMade:
    """What :func:`make_capture` wrote.

    Attributes
    ----------
    path : pathlib.Path
        The capture folder.
    rig_source : str
        The rig file read and its format (``"camera_array.toml (caliscope)"``).
    media : list of CameraMedia
        Per camera, the media it was made from (rig order).
    num_frames : int
    fps : float
        The capture's frame rate, as :meth:`Capture.open` reads it back.
    fps_source : str
        Where it comes from: ``"--fps"`` / ``"fps="``, ``"video header"`` or ``"assumed"``.
    up : (3,) float ndarray
        The up direction (set, or detected from the cameras).
    up_source : str
        How it was found.
    files : list of pathlib.Path
        The files written (``rig.toml``, ``capture.toml``, ``labels.toml`` if any), in the
        capture.
    mode : {"copy", "link"}
    dropped : list of str
        Rig cameras left out (no media, ``strict=False``).
    """

    path: Path
    rig_source: str
    media: list[CameraMedia]
    num_frames: int
    fps: float
    fps_source: str
    up: np.ndarray
    up_source: str
    files: list[Path] = field(default_factory=list)
    mode: MediaMode = "copy"
    dropped: list[str] = field(default_factory=list)


def media_by_camera(items: Sequence[str | os.PathLike], rig: CameraRig) -> dict[str, Path]:
    """Camera name -> media path, from command-line style items.

    Parameters
    ----------
    items : sequence of str or path-like
        Each is ``NAME=PATH`` (PATH is camera NAME's video or image folder), a video (its
        camera is its file name without the extension), an image folder (its camera is the
        folder's name), or a folder holding such videos and folders, named after the cameras.
    rig : CameraRig
        For the error messages (the camera names) and to tell a folder of camera folders from
        one camera's image folder.

    Returns
    -------
    dict of str to pathlib.Path

    Raises
    ------
    ValidationError
        Naming the item: a camera given twice, or a folder with nothing usable in it.
    FileFormatError
        A path that does not exist.
    """
    from .session import IMAGE_EXTENSIONS

    out: dict[str, Path] = {}

    def add(name: str, path: Path, item: object) -> None:
        if name in out:
            raise ValidationError(
                f"camera {name!r} is given twice: {out[name]} and {path} (from {item!s})"
            )
        out[name] = path

    for item in items:
        text = str(item)
        name, sep, rest = text.partition("=")
        if sep and name and not Path(text).exists():
            path = Path(rest)
            if not path.exists():
                raise FileFormatError(path, f"camera {name!r}: no such file or folder")
            add(name, path, item)
            continue
        path = Path(text)
        if not path.exists():
            raise FileFormatError(path, "no such file or folder")
        if path.is_file():
            add(path.stem, path, item)
            continue
        has_images = any(
            f.suffix.lower() in IMAGE_EXTENSIONS for f in path.iterdir() if f.is_file()
        )
        if has_images or path.name in rig.names:
            add(path.name, path, item)
            continue
        # A folder of per-camera videos and image folders.
        found = 0
        for f in sorted(path.iterdir()):
            if f.name.startswith("."):
                continue
            if f.is_file() and f.suffix.lower() in VIDEO_EXTENSIONS:
                add(f.stem, f, item)
                found += 1
            elif f.is_dir():
                add(f.name, f, item)
                found += 1
        if not found:
            raise ValidationError(
                f"{path}: no images, videos ({', '.join(VIDEO_EXTENSIONS)}) or camera folders"
            )
    return out


def _place(src: Path, dst: Path, mode: MediaMode) -> None:
    """Copy or symlink one file (the folder exists)."""
    if mode == "link":
        os.symlink(src.resolve(), dst)
    else:
        shutil.copyfile(src, dst)


def make_capture(
    out: str | os.PathLike,
    rig: str | os.PathLike | CameraRig,
    media: Mapping[str, str | os.PathLike],
    *,
    rig_format: str | None = None,
    fps: float | None = None,
    up: str | Sequence[float] | None = None,
    labels: str | os.PathLike | None = None,
    mode: MediaMode = "copy",
    strict: bool = True,
    description: str = "",
) -> CaptureMade:
    """Make a capture folder from a rig file and each camera's video or image folder.

    Writes ``out/rig.toml`` (the rig in pointtraj's format, only the cameras with media),
    ``out/capture.toml`` (``fps``, ``up``, ``source``, ``description`` as given),
    ``out/labels.toml`` if ``labels`` is given, and per camera ``videos/<camera><ext>`` or
    ``frames/<camera>/<t:06d><ext>`` (images renamed in frame order), copied or linked. The
    folder is built beside ``out`` and moved into place once :meth:`Capture.open` reads it.

    Parameters
    ----------
    out : path-like
        The new capture folder; it must not exist or be empty.
    rig : path-like or CameraRig
        A rig file in any format of :func:`pointtraj.rigio.load_rig`, or a rig.
    media : mapping of str to path-like
        Camera name -> video file or image folder (:func:`media_by_camera` builds it from
        command-line items).
    rig_format : str, optional
        The rig file's format (default: detected).
    fps : float, optional
        The frame rate written to ``capture.toml``; default none is written, and the videos'
        headers give it (an implausible one is reported, :func:`check_video_fps`) or 30 fps.
    up : str or (3,) float, optional
        The world's up direction written to ``capture.toml`` (``"+z"``, ``"-y"``, 3 numbers,
        or ``"auto"``: detected by :func:`pointtraj.geometry.detect_up`, nothing written).
    labels : path-like or "default", optional
        A ``labels.toml`` to copy (checked by :meth:`LabelSet.load`), or ``"default"`` for the
        default body-part set.
    mode : {"copy", "link"}
        Copy the media, or make symbolic links to them (absolute paths).
    strict : bool
        If False, rig cameras without media are dropped from ``rig.toml`` (with a warning)
        instead of an error.
    description : str
        Written to ``capture.toml``.

    Returns
    -------
    CaptureMade

    Raises
    ------
    FileFormatError
        A bad rig, media or labels file, named (``check_media`` lists the checks).
    ValidationError
        ``out`` not empty, a bad ``fps``, ``up`` or ``mode``.
    """
    from .geometry import parse_up, resolve_up
    from .labelset import LabelSet
    from .rigio import detect_format, load_rig
    from .rigio.toml import save_rig_toml

    if mode not in ("copy", "link"):
        raise ValidationError(f"mode: expected 'copy' or 'link', got {mode!r}")
    if fps is not None and (isinstance(fps, bool) or not np.isfinite(fps) or not fps > 0):
        raise ValidationError(f"fps: must be a positive number, got {fps!r}")
    up_value = None if up is None else parse_up(up, "up")
    if not media:
        raise ValidationError("no media: give each camera's video or image folder")
    out = Path(out)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise ValidationError(f"out: {out} exists and is not an empty folder; choose a new one")
    if isinstance(rig, CameraRig):
        cams, rig_source = rig, "a CameraRig"
    else:
        fmt = rig_format or detect_format(rig)
        cams = load_rig(rig, fmt=fmt)
        rig_source = f"{rig} ({fmt})"
    label_set = None
    if labels is not None:
        label_set = LabelSet.default() if str(labels) == "default" else LabelSet.load(labels)

    unknown = [n for n in media if n not in cams.names]
    if unknown and strict:
        raise ValidationError(
            f"media of camera(s) {', '.join(unknown)} ({', '.join(str(media[n]) for n in unknown)})"
            f" but the rig {rig_source} has {', '.join(cams.names)}: name each NAME=PATH"
        )
    missing = [n for n in cams.names if n not in media]
    if missing and strict:
        raise ValidationError(
            f"rig camera(s) {', '.join(missing)} of {rig_source} have no media: give them, or "
            "leave them out of the capture with strict=False (--drop-missing)"
        )
    all_names = cams.names
    cams, found, num_frames = check_media(cams, media, strict=strict)
    dropped = [n for n in all_names if n not in cams.names]
    header_fps = None
    if fps is None:
        rates = [check_video_fps(m.header_fps, m.path) for m in found if m.kind == "video"]
        header_fps = next((f for f in rates if f is not None), None)

    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    umask = os.umask(0)
    os.umask(umask)
    tmp.chmod(0o777 & ~umask)  # mkdtemp makes it private; a capture is an ordinary folder
    try:
        save_rig_toml(cams, tmp / "rig.toml")
        save_capture_toml(
            tmp,
            fps=fps,
            up=up,
            source=rig_source if isinstance(rig, CameraRig) else str(rig),
            description=description,
            comment="written by pointtraj capture",
        )
        written = [out / "rig.toml", out / "capture.toml"]
        if label_set is not None:
            label_set.save(tmp / "labels.toml")
            written.append(out / "labels.toml")
        for m in found:
            if m.kind == "video":
                (tmp / "videos").mkdir(exist_ok=True)
                _place(m.path, tmp / "videos" / f"{m.camera}{m.path.suffix.lower()}", mode)
            else:
                folder = tmp / "frames" / m.camera
                folder.mkdir(parents=True)
                for t, f in enumerate(m.files[:num_frames]):
                    _place(f, folder / f"{t:06d}{f.suffix.lower()}", mode)
        # Read it back as every stage will; check_media has reported what it would warn about.
        session_log = logging.getLogger("pointtraj.session")
        level = session_log.level
        session_log.setLevel(logging.ERROR)
        try:
            with Capture.open(tmp, strict=strict) as cap:
                capture_fps = cap.fps
                up_vec, up_source = resolve_up(
                    "auto" if cap.up is None else cap.up, cap.rig, "capture.toml up"
                )
        finally:
            session_log.setLevel(level)
        if up_value is not None:
            up_source = f"set (up = {up!r} in capture.toml)"
        if out.exists():
            out.rmdir()
        os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    if fps is not None:
        fps_source = "given"
    elif header_fps is not None:
        fps_source = "video header"
    else:
        fps_source = "assumed (no plausible video header): set it with --fps"
    return CaptureMade(
        path=out,
        rig_source=rig_source,
        media=found,
        num_frames=num_frames,
        fps=capture_fps,
        fps_source=fps_source,
        up=up_vec,
        up_source=up_source,
        files=written,
        mode=mode,
        dropped=dropped,
    )
