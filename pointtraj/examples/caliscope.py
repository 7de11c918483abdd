"""The ``caliscope-board`` example: caliscope's post_optimization session from shared data."""

from __future__ import annotations

import csv
import logging
import os
import shutil
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..atomic import write_text_atomic
from ..camera import CameraRig
from ..errors import FileFormatError
from .common import (
    EXAMPLES,
    ExampleCapture,
    ExampleNotFoundError,
    _finish_output,
    _save_capture_toml,
    _start_output,
    _video_info,
)

logger = logging.getLogger(__name__)


#: Environment variable naming the shared data root (holding ``data/caliscope_board_4cam``).
SHARED_ENV = "POINTTRAJ_SHARED"

CALISCOPE_FOLDER = "caliscope_board_4cam"


@dataclass(frozen=True)
class SyncReport:
    """Frame timing of a software-synchronised capture.

    Attributes
    ----------
    frame_counts : dict of str to int
        Frames per camera (from the videos).
    timestamp_counts : dict of str to int
        Timestamps per camera.
    spread : (S,) float ndarray
        Per sync index seen by every camera: latest minus earliest frame time, seconds.
    fps : float
        1 / median frame interval.
    """

    frame_counts: dict[str, int]
    timestamp_counts: dict[str, int]
    spread: np.ndarray
    fps: float

    def describe(self) -> str:
        """A short text summary."""
        s = self.spread * 1000
        return (
            "frames per camera: "
            + ", ".join(f"{k}={v}" for k, v in self.frame_counts.items())
            + "; timestamps per camera: "
            + ", ".join(f"{k}={v}" for k, v in self.timestamp_counts.items())
            + f"; fps {self.fps:.3f}; spread of frame times per sync index over {len(s)} "
            f"indices: median {np.median(s):.1f} ms, 90th percentile "
            f"{np.percentile(s, 90):.1f} ms, max {s.max():.1f} ms"
        )


# -- locations ------------------------------------------------------------------------------


def find_shared_data(name: str = CALISCOPE_FOLDER) -> Path | None:
    """``<shared>/data/<name>`` from ``$POINTTRAJ_SHARED``, ``<repo>/../shared`` or
    ``/work/shared``; None if none exists."""
    roots = []
    if os.environ.get(SHARED_ENV):
        roots.append(Path(os.environ[SHARED_ENV]).expanduser())
    roots += [Path(__file__).resolve().parents[2].parent / "shared", Path("/work/shared")]
    for root in roots:
        if (root / "data" / name).is_dir():
            return root / "data" / name
    return None


# -- caliscope ------------------------------------------------------------------------------


def _read_csv(path: Path, required: tuple[str, ...]) -> list[dict[str, str]]:
    if not path.is_file():
        raise FileFormatError(path, "no such file")
    with open(path, newline="") as f:
        reader = csv.DictReader(f)
        missing = [c for c in required if c not in (reader.fieldnames or [])]
        if missing:
            raise FileFormatError(path, f"missing column(s) {', '.join(missing)}")
        return list(reader)


def caliscope_sync_report(
    timestamps: str | os.PathLike, frame_counts: Mapping[str, int] | None = None
) -> SyncReport:
    """Frame-time spread per sync index of a caliscope ``timestamps.csv``.

    Parameters
    ----------
    timestamps : path-like
        CSV with columns ``sync_index, cam_id, frame_time`` (seconds).
    frame_counts : mapping of str to int, optional
        Frames per camera found in the videos (reported as is).

    Returns
    -------
    SyncReport

    Raises
    ------
    FileFormatError
        On missing columns or non-numeric values.
    """
    path = Path(timestamps)
    rows = _read_csv(path, ("sync_index", "cam_id", "frame_time"))
    try:
        data = np.array(
            [[float(r["sync_index"]), float(r["cam_id"]), float(r["frame_time"])] for r in rows]
        )  # (R, 3)
    except ValueError as exc:
        raise FileFormatError(path, f"non-numeric value ({exc})") from None
    if len(data) == 0:
        raise FileFormatError(path, "no rows")
    cams = np.unique(data[:, 1]).astype(int)
    sync = np.unique(data[:, 0]).astype(int)
    times = np.full((len(sync), len(cams)), np.nan)  # (S, C)
    times[np.searchsorted(sync, data[:, 0]), np.searchsorted(cams, data[:, 1])] = data[:, 2]
    full = np.all(np.isfinite(times), axis=1)
    spread = times[full].max(axis=1) - times[full].min(axis=1)
    order = np.argsort(times, axis=0)
    dt = np.diff(np.take_along_axis(times, order, axis=0), axis=0)
    fps = float(1.0 / np.nanmedian(dt))
    ts_counts = {f"cam_{c}": int(np.isfinite(times[:, i]).sum()) for i, c in enumerate(cams)}
    return SyncReport(dict(frame_counts or {}), ts_counts, spread, fps)


def _sync_to_frame(outer: Path, inner: Path) -> dict[int, int]:
    """caliscope's outer sync_index -> video frame index, matched through the frame times."""
    o = _read_csv(outer, ("sync_index", "cam_id", "frame_time"))
    i = _read_csv(inner, ("sync_index", "cam_id", "frame_index", "frame_time"))
    frame_of = {(r["cam_id"], r["frame_time"]): int(r["frame_index"]) for r in i}
    out: dict[int, set[int]] = {}
    for r in o:
        f = frame_of.get((r["cam_id"], r["frame_time"]))
        if f is not None:
            out.setdefault(int(r["sync_index"]), set()).add(f)
    bad = {s: f for s, f in out.items() if len(f) != 1}
    if bad:
        raise FileFormatError(outer, f"sync indices map to several frames: {bad}")
    frame_of = {s: next(iter(f)) for s, f in out.items()}
    offsets = {s - f for s, f in frame_of.items()}
    if len(offsets) == 1:  # a constant offset also holds for sync indices without a time match
        off = offsets.pop()
        frame_of.update({int(r["sync_index"]): int(r["sync_index"]) - off for r in o})
    return frame_of


def _write_corners(src: Path, dst: Path, frame_of: Mapping[int, int]) -> tuple[int, int]:
    """Corner files with a video ``frame`` column; returns (2D rows, 3D rows) written."""
    xy = _read_csv(
        src / "xy_CHARUCO.csv",
        ("sync_index", "cam_id", "keypoint_id", "img_loc_x", "img_loc_y"),
    )
    xyz = _read_csv(
        src / "xyz_CHARUCO.csv", ("sync_index", "keypoint_id", "x_coord", "y_coord", "z_coord")
    )
    lines2 = ["frame,camera,keypoint_id,x,y,board_x,board_y,board_z"]
    for r in xy:
        f = frame_of.get(int(r["sync_index"]))
        if f is None:
            continue
        lines2.append(
            f"{f},cam_{r['cam_id']},{r['keypoint_id']},{r['img_loc_x']},{r['img_loc_y']},"
            f"{r.get('obj_loc_x', '')},{r.get('obj_loc_y', '')},{r.get('obj_loc_z', '')}"
        )
    lines3 = ["frame,keypoint_id,x,y,z"]
    for r in xyz:
        f = frame_of.get(int(r["sync_index"]))
        if f is None:
            continue
        lines3.append(f"{f},{r['keypoint_id']},{r['x_coord']},{r['y_coord']},{r['z_coord']}")
    write_text_atomic(dst / "corners_2d.csv", "\n".join(lines2) + "\n")
    write_text_atomic(dst / "corners_3d.csv", "\n".join(lines3) + "\n")
    return len(lines2) - 1, len(lines3) - 1


def fetch_caliscope_board(
    out: str | os.PathLike,
    *,
    source: str | os.PathLike | None = None,
    link: bool = True,
    overwrite: bool = False,
) -> ExampleCapture:
    """Lay out caliscope's 4-camera ChArUco session as a pointtraj capture.

    Writes ``rig.toml`` (from ``camera_array.toml``), ``videos/cam_N.mp4`` (symlinks to, or
    copies of, ``calibration/extrinsic/cam_N.mp4``), ``capture.toml`` (fps from
    ``CHARUCO/timestamps.csv``), ``labels.toml`` (14 body parts and a ``board`` object),
    ``charuco.toml``, ``charuco/`` (caliscope's corner and timestamp files unchanged, plus
    ``corners_2d.csv`` / ``corners_3d.csv`` indexed by video frame), ``LICENSE``,
    ``SOURCE.md`` and ``README.md`` (with the synchronisation report).

    Parameters
    ----------
    out : path-like
        The capture folder to write (new or empty).
    source : path-like, optional
        The ``caliscope_board_4cam`` folder; default :func:`find_shared_data`.
    link : bool
        Symlink the videos (absolute paths) instead of copying them.
    overwrite : bool
        Replace ``out`` if it holds a capture written by this module.

    Returns
    -------
    ExampleCapture
        ``notes`` holds the :class:`SyncReport` summary.

    Raises
    ------
    ExampleNotFoundError
        If the source folder is missing (saying where to get it).
    FileFormatError
        For a missing or malformed source file.
    """
    from ..labelset import BODY_PARTS, LabelSet
    from ..rigio.caliscope import load_caliscope
    from ..rigio.toml import save_rig_toml

    src = Path(source) if source is not None else find_shared_data(CALISCOPE_FOLDER)
    if src is None or not src.is_dir():
        raise ExampleNotFoundError(
            f"caliscope-board: source folder {src or CALISCOPE_FOLDER!s} not found (looked in "
            f"${SHARED_ENV}/data, <repo>/../shared/data and /work/shared/data); get it from "
            "https://github.com/mprib/caliscope at commit ddda95b44ba2, folder "
            "tests/sessions/post_optimization, and pass --source DIR"
        )
    src = src.resolve()
    ext = src / "calibration" / "extrinsic"
    for need in (src / "camera_array.toml", ext / "CHARUCO" / "timestamps.csv"):
        if not need.is_file():
            raise ExampleNotFoundError(
                f"caliscope-board: {need} is missing; --source must be the caliscope_board_4cam "
                "folder (camera_array.toml, calibration/extrinsic/cam_N.mp4, CHARUCO/*.csv)"
            )
    rig = load_caliscope(src / "camera_array.toml")
    out = Path(out)
    tmp = _start_output(out, overwrite)
    try:
        counts = {}
        for cam in rig:
            video = ext / f"{cam.name}.mp4"
            if not video.is_file():
                raise FileFormatError(video, f"no video for calibrated camera {cam.name}")
            count, size, _ = _video_info(video)
            if tuple(size) != tuple(cam.size):
                raise FileFormatError(
                    video,
                    f"video is {size[0]}x{size[1]} but the calibration says "
                    f"{cam.size[0]}x{cam.size[1]}",
                )
            counts[cam.name] = count
            dst = tmp / "videos" / video.name
            dst.parent.mkdir(parents=True, exist_ok=True)
            if link:
                dst.symlink_to(video)
            else:
                shutil.copyfile(video, dst)
        save_rig_toml(rig, tmp / "rig.toml")
        charuco = ext / "CHARUCO"
        sync = caliscope_sync_report(charuco / "timestamps.csv", counts)
        outer = ext / "timestamps.csv"
        full_sync = caliscope_sync_report(outer, counts) if outer.is_file() else sync
        spec = EXAMPLES["caliscope-board"]
        _save_capture_toml(
            tmp / "capture.toml",
            sync.fps,
            f"{spec.source}, read from {src}",
            f"{spec.description}. Licence: {spec.licence} (LICENSE, Copyright (c) 2024, "
            'Donald "Mac" Prible).',
        )
        base = LabelSet.default()
        LabelSet(
            (*BODY_PARTS, "board"),
            np.vstack([base.colors[: len(BODY_PARTS)], [[255, 225, 25]]]),
            ("body",) * len(BODY_PARTS) + ("object",),
        ).save(tmp / "labels.toml")
        for name in ("charuco.toml", "LICENSE", "SOURCE.md"):
            if (src / name).is_file():
                shutil.copyfile(src / name, tmp / name)
        (tmp / "charuco").mkdir()
        for f in sorted(charuco.glob("*.csv")):
            shutil.copyfile(f, tmp / "charuco" / f.name)
        if outer.is_file():
            shutil.copyfile(outer, tmp / "charuco" / "timestamps_sync.csv")
            frame_of = _sync_to_frame(outer, charuco / "timestamps.csv")
        else:
            frame_of = {s: s for s in range(max(counts.values()))}
        n2, n3 = _write_corners(charuco, tmp / "charuco", frame_of)
        offsets = sorted({s - f for s, f in frame_of.items()})
        notes = [
            "sync (CHARUCO/timestamps.csv): " + sync.describe(),
            "sync (extrinsic/timestamps.csv): " + full_sync.describe(),
            f"caliscope's corner files use sync_index = video frame + {offsets[0]}"
            if len(offsets) == 1
            else f"sync_index - frame offsets vary: {offsets}",
            f"charuco/corners_2d.csv: {n2} detections, charuco/corners_3d.csv: {n3} corners, "
            "indexed by video frame",
        ]
        _write_caliscope_readme(tmp, rig, counts, sync.fps, notes)
        _finish_output(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    logger.info("wrote %s: %s", out, sync.describe())
    return ExampleCapture("caliscope-board", out, rig.names, counts, sync.fps, {}, notes)


def _write_caliscope_readme(
    folder: Path, rig: CameraRig, counts: Mapping[str, int], fps: float, notes: list[str]
) -> None:
    rows = "\n".join(f"| {c.name} | {c.size[0]}x{c.size[1]} | {counts[c.name]} |" for c in rig)
    text = (
        f"""# caliscope ChArUco board session, as a pointtraj capture

Written by `pointtraj examples fetch caliscope-board`.

- **Origin**: caliscope (<https://github.com/mprib/caliscope>), commit ddda95b44ba2, folder
  `tests/sessions/post_optimization` (see `SOURCE.md`).
- **Licence**: BSD-2-Clause, Copyright (c) 2024, Donald "Mac" Prible (`LICENSE`).
- **Content**: 4 webcams, software-synchronised, ~{fps:.2f} fps; a person moves a ChArUco board
  (`charuco.toml`: 4x5 squares of 5.4 cm, DICT_4X4_1000, printed inverted).
- `rig.toml` is caliscope's `camera_array.toml` converted by `pointtraj.rigio.load_caliscope`.
- `videos/` link to (or copy) caliscope's `calibration/extrinsic/cam_N.mp4`.
- `labels.toml`: the 14 body parts and `board` (object).
- `charuco/`: caliscope's `xy_CHARUCO.csv` (2D corners), `xyz_CHARUCO.csv` (their
  triangulation), `timestamps.csv` (CHARUCO) and `timestamps_sync.csv` (extrinsic) unchanged,
  plus `corners_2d.csv` and `corners_3d.csv` with a `frame` column (video frame index) for the
  rigidity evaluation.

| camera | size | frames |
|---|---|---|
{rows}

Notes:

"""
        + "\n".join(f"- {n}" for n in notes)
        + "\n"
    )
    write_text_atomic(folder / "README.md", text)
