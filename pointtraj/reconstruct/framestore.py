"""The reconstruction's per-frame files in a work folder (``state/``), and the store built from them.

Two kinds of file, so that the disk a frame costs is only its share of the store:

- ``state/<t:06d>.npz``, one per frame (format 2): frame t's *record*, the point-frames that go
  into the trajectory store (:class:`~.track.FrameRecord`), deflated. Kept: the final
  :class:`~pointtraj.trajectories.Trajectories` is assembled from them.
- ``state/live.npz``: the tracker's *live state* after the last complete frame
  (:class:`~.track.TrackState`), what resuming needs. Only one is kept: each frame replaces it
  atomically, so the previous one stays until the new one is whole. Pixels and visibility are
  kept sparse (their observed entries, bit-exact), so a resumed run gives byte-identical
  results.

A frame is complete once ``live.npz`` says so; the record is written first. Work folders of
older versions hold format 1 files, ``state/<t:06d>.npz`` with the record *and* the live state
of every frame: they are read as records, and the last of them resumes the run.

:meth:`FrameStore.assemble` builds the store from the record files in two streamed passes (the
trajectory ids first, then the rows), so that no list of every frame's record is held: its
memory is the store's own arrays plus one frame.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from ..atomic import save_npz_atomic
from ..errors import FileFormatError, ValidationError
from ..npzfile import load_npz
from ..trajectories import Trajectories
from .reacquire import LOST_FIELDS, PATCH_SIDE, LostViews
from .track import FrameRecord, TrackState

__all__ = ["FrameStore", "RECORD_FORMAT_VERSION", "LIVE_FORMAT_VERSION", "DEFLATE_LEVEL"]

logger = logging.getLogger(__name__)

#: ``state/<t>.npz``: 1 = record and live state (older versions), 2 = the record alone.
RECORD_FORMAT_VERSION = 2
#: ``state/live.npz``.
LIVE_FORMAT_VERSION = 2
#: zlib level of both files: level 1 is 2-3 times faster than the default and within 10 % of
#: its size on these arrays (paper69 frame 2: a record of 108k points 4.1 MB in 0.12 s).
DEFLATE_LEVEL = 1

# array names of a record in each format (format 1 prefixes them with "rec_")
_RECORD_FIELDS = ("ids", "xyz", "visibility", "error", "color", "num_new")
_V1_LIVE = ("live_ids", "live_xyz", "live_visibility", "live_pixels", "next_id")
_LIVE_FIELDS = (
    "frame",
    "num_cameras",
    "ids",
    "xyz",
    "visibility_mask",
    "visibility_values",
    "pixels_mask",
    "pixels_values",
    "lone",
    "next_id",
)


class FrameStore:
    """The per-frame record files and the live tracker state of a work folder.

    Parameters
    ----------
    work : path-like
        The work folder; the files live in its ``state/``.
    num_cameras : int
        C, checked against every file read.
    """

    def __init__(self, work: str | os.PathLike, num_cameras: int) -> None:
        self.folder = Path(work) / "state"
        self.num_cameras = int(num_cameras)

    # -- paths -----------------------------------------------------------------------------------
    def record_path(self, t: int) -> Path:
        """``state/<t:06d>.npz``."""
        return self.folder / f"{t:06d}.npz"

    @property
    def live_path(self) -> Path:
        """``state/live.npz``."""
        return self.folder / "live.npz"

    # -- writing ---------------------------------------------------------------------------------
    def save_frame(self, record: FrameRecord, state: TrackState) -> None:
        """Write frame ``record.frame``'s record, then the live state that marks it complete."""
        self.write_record(record)
        self.write_live(state)

    def write_record(self, record: FrameRecord) -> None:
        """Write ``state/<t>.npz`` (format 2), deflated."""
        save_npz_atomic(
            self.record_path(record.frame),
            compress=DEFLATE_LEVEL,
            format_version=np.int64(RECORD_FORMAT_VERSION),
            frame=np.int64(record.frame),
            ids=record.ids,
            xyz=record.xyz,
            visibility=record.visibility,
            error=record.error,
            color=record.color,
            num_new=np.int64(record.num_new),
        )

    def write_live(self, state: TrackState) -> None:
        """Replace ``state/live.npz`` with ``state`` (visibility and pixels sparse), deflated.

        Visibility keeps its non-zero entries and pixels the cameras where a point's pixel is
        not NaN, each as a bit mask and the values, bit for bit.
        """
        vis = np.asarray(state.visibility)  # (N, C)
        pix = np.asarray(state.pixels)  # (C, N, 2)
        vmask = vis != 0  # (N, C)
        pmask = ~np.isnan(pix).all(axis=2)  # (C, N)
        save_npz_atomic(
            self.live_path,
            compress=DEFLATE_LEVEL,
            format_version=np.int64(LIVE_FORMAT_VERSION),
            frame=np.int64(state.frame),
            num_cameras=np.int64(vis.shape[1]),
            ids=state.ids,
            xyz=state.xyz,
            visibility_dtype=np.array(vis.dtype.str),
            visibility_mask=np.packbits(vmask, axis=None),
            visibility_values=vis[vmask],
            pixels_dtype=np.array(pix.dtype.str),
            pixels_mask=np.packbits(pmask, axis=None),
            pixels_values=pix[pmask],  # (K, 2)
            lone=state.lone,
            # view discovery's back-off counters, mostly 0: the flat (N * C) indices of the rest
            misses_index=np.flatnonzero(state.misses),
            misses_values=state.misses.ravel()[np.flatnonzero(state.misses)],
            next_id=np.int64(state.next_id),
            densify_backlog=np.bool_(state.densify_backlog),
            # the lost views that carried points may get back (reacquire.LostViews)
            **{f"lost_{f}": getattr(state.lost, f) for f in LOST_FIELDS},
        )

    # -- reading ---------------------------------------------------------------------------------
    def read_record(self, t: int, fields: tuple[str, ...] = _RECORD_FIELDS) -> FrameRecord:
        """Frame ``t``'s record, from a file of either format.

        Parameters
        ----------
        t : int
        fields : tuple of str
            The record's arrays to read (others are left empty), e.g. ``("ids",)``.

        Returns
        -------
        FrameRecord

        Raises
        ------
        FileFormatError
            Naming the file: missing, unreadable, of another frame or camera count, or
            inconsistent.
        """
        path = self.record_path(t)
        names = [*fields] + [f"rec_{k}" for k in fields]
        d = load_npz(path, (), "a frame record", keys=["format_version", "frame", *names])
        version = int(d.get("format_version", 1))
        if version > RECORD_FORMAT_VERSION:
            raise FileFormatError(
                path,
                f"format_version {version} is newer than this pointtraj reads "
                f"({RECORD_FORMAT_VERSION})",
            )
        prefix = "rec_" if version == 1 else ""
        missing = [prefix + k for k in fields if prefix + k not in d]
        if "frame" not in d or missing:
            raise FileFormatError(
                path,
                f"missing array {', '.join(repr(k) for k in missing or ['frame'])}: not a "
                "frame record, or damaged",
            )
        try:
            frame = int(d["frame"])
            got = {k: np.asarray(d[prefix + k]) for k in fields}
        except (TypeError, ValueError) as exc:
            raise FileFormatError(path, f"unreadable frame record ({exc})") from None
        if frame != t:
            raise FileFormatError(path, f"holds frame {frame}, expected {t}")
        n = got["ids"].shape[0] if "ids" in got else None
        shapes = {
            "ids": (n,),
            "xyz": (n, 3),
            "visibility": (n, self.num_cameras),
            "error": (n,),
            "color": (n, 3),
            "num_new": (),
        }
        for k, a in got.items():
            want = shapes[k]
            if a.ndim != len(want) or any(w is not None and w != s for w, s in zip(want, a.shape)):
                raise FileFormatError(
                    path,
                    f"{prefix + k} has shape {a.shape}, expected "
                    f"({', '.join('N' if w is None else str(w) for w in want)})"
                    + (f" for {self.num_cameras} cameras" if k == "visibility" else ""),
                )
        empty = np.zeros(0)
        return FrameRecord(
            frame,
            got.get("ids", empty),
            got.get("xyz", empty),
            got.get("visibility", empty),
            got.get("error", empty),
            got.get("color", empty),
            int(got["num_new"]) if "num_new" in got else 0,
        )

    def record_version(self, t: int) -> int:
        """The format of ``state/<t>.npz`` (1: with the live state, 2: the record alone)."""
        d = load_npz(self.record_path(t), (), "a frame record", keys=["format_version"])
        return int(d.get("format_version", 1))

    def read_live(self) -> TrackState | None:
        """The live state of ``state/live.npz``, or None without one.

        Raises
        ------
        FileFormatError
            Naming the file if it is unreadable, for another camera count or inconsistent.
        """
        path = self.live_path
        if not path.is_file():
            return None
        d = load_npz(path, _LIVE_FIELDS, "a tracker state")
        version = int(d.get("format_version", LIVE_FORMAT_VERSION))
        if version > LIVE_FORMAT_VERSION:
            raise FileFormatError(
                path,
                f"format_version {version} is newer than this pointtraj reads "
                f"({LIVE_FORMAT_VERSION})",
            )
        C = self.num_cameras
        if int(d["num_cameras"]) != C:
            raise FileFormatError(
                path, f"tracker state is for {int(d['num_cameras'])} cameras, not {C}"
            )
        ids = d["ids"]
        N = ids.shape[0]
        try:
            vmask = np.unpackbits(d["visibility_mask"], count=N * C).astype(bool).reshape(N, C)
            vis = np.zeros((N, C), np.dtype(str(d["visibility_dtype"])))
            vis[vmask] = d["visibility_values"]
            pmask = np.unpackbits(d["pixels_mask"], count=C * N).astype(bool).reshape(C, N)
            pix = np.full((C, N, 2), np.nan, np.dtype(str(d["pixels_dtype"])))
            pix[pmask] = d["pixels_values"]
            misses = np.zeros(N * C, np.uint8)  # absent before the back-off: all 0
            if "misses_index" in d:
                misses[d["misses_index"]] = d["misses_values"]
            state = TrackState(
                int(d["frame"]),
                ids,
                d["xyz"],
                vis,
                pix,
                int(d["next_id"]),
                d["lone"],
                misses.reshape(N, C),
                # absent before densification's backlog: none
                densify_backlog=bool(d["densify_backlog"]) if "densify_backlog" in d else False,
                # absent before lost views were re-acquired: none
                lost=LostViews(*(d[f"lost_{f}"] for f in LOST_FIELDS)) if "lost_ids" in d else None,
            )
        except (KeyError, TypeError, ValueError, IndexError) as exc:
            raise FileFormatError(path, f"unreadable tracker state ({exc})") from None
        _check_live(path, state)
        return state

    def read_v1_live(self, t: int) -> TrackState:
        """The live state in a format 1 ``state/<t>.npz`` (older versions).

        Raises
        ------
        FileFormatError
            Naming the file if it is unreadable or inconsistent.
        """
        path = self.record_path(t)
        d = load_npz(path, _V1_LIVE, "a tracker state", keys=[*_V1_LIVE, "live_lone"])
        try:
            state = TrackState(
                t,
                d["live_ids"],
                d["live_xyz"],
                d["live_visibility"],
                d["live_pixels"],
                int(d["next_id"]),
                d.get("live_lone"),  # absent in the states of older versions: all 0
            )
        except (TypeError, ValueError) as exc:
            raise FileFormatError(path, f"unreadable tracker state ({exc})") from None
        if state.visibility.shape[1:] != (self.num_cameras,):
            raise FileFormatError(path, f"tracker state is not for {self.num_cameras} cameras")
        _check_live(path, state)
        return state

    def read_state_at(self, t: int) -> TrackState:
        """The tracker's state after frame ``t``: ``live.npz``'s if of frame t, else that of a
        format 1 ``state/<t>.npz``.

        Raises
        ------
        FileFormatError
            If neither holds frame t's state.
        """
        live = self.read_live()
        if live is not None and live.frame == t:
            return live
        if self.record_path(t).is_file() and self.record_version(t) == 1:
            return self.read_v1_live(t)
        raise FileFormatError(
            self.live_path,
            f"no tracker state of frame {t} (it holds "
            + (f"frame {live.frame}" if live is not None else "none: the file is missing")
            + ")",
        )

    # -- resuming --------------------------------------------------------------------------------
    def resume(self, frames: range) -> tuple[int, TrackState | None]:
        """Where a run of ``frames`` resumes: the frames done, and the live state after them.

        The resume point is the latest frame, among those whose records exist contiguously
        from ``frames.start``, that has a live state: ``live.npz``'s frame, or a format 1
        record file's. Records after it are recomputed.

        Parameters
        ----------
        frames : range

        Returns
        -------
        done : int
            Frames complete from ``frames.start`` (0: start afresh).
        state : TrackState or None
            The live state after frame ``frames.start + done - 1``.
        """
        n = 0
        while n < len(frames) and self.record_path(frames[n]).is_file():
            n += 1
        if n == 0:
            return 0, None
        live = self.read_live()
        for i in range(n - 1, -1, -1):
            t = frames[i]
            if live is not None and live.frame == t:
                return i + 1, live
            if self.record_version(t) == 1:
                return i + 1, self.read_v1_live(t)
        logger.warning(
            "%s: %d frame records but no tracker state among them (%s); reconstructing afresh",
            self.folder,
            n,
            f"live.npz is of frame {live.frame}" if live is not None else "no live.npz",
        )
        return 0, None

    # -- the store -------------------------------------------------------------------------------
    def assemble(
        self, frames: range, camera_names: list[str], fps: float, num_frames: int
    ) -> Trajectories:
        """Build the ragged store from the record files of ``frames``, streamed.

        A first pass reads the trajectory ids of each frame (counts, first frames: the
        offsets), a second fills the store's rows frame by frame. Memory: the store's arrays,
        one frame's record and a few (M,) integer arrays. The result equals
        :func:`~.stage.assemble_trajectories` of the same records.

        Parameters
        ----------
        frames : range
        camera_names : list of str
        fps : float
        num_frames : int

        Returns
        -------
        Trajectories

        Raises
        ------
        ValidationError
            If the ids are not ``0 .. M-1`` or a trajectory skips a frame.
        FileFormatError
            If a record file is missing or damaged (naming it).
        """
        return assemble_records(
            ((t, self.read_record(t, ("ids",)).ids, self.record_path(t)) for t in frames),
            (self.read_record(t) for t in frames),
            self.num_cameras,
            camera_names,
            fps,
            num_frames,
        )


def assemble_records(
    frame_ids: Iterable[tuple[int, np.ndarray, object]],
    records: Iterable[FrameRecord],
    num_cameras: int,
    camera_names: list[str],
    fps: float,
    num_frames: int,
) -> Trajectories:
    """Build the ragged store in two passes over the frames, in frame order (the one
    implementation, for records on disk, :meth:`FrameStore.assemble`, and in memory,
    :func:`~.stage.assemble_trajectories`).

    A first pass reads each frame's trajectory ids (counts, first frames: the offsets), a second
    fills the store's rows frame by frame. Memory: the store's arrays, one frame's record and a
    few (M,) integer arrays.

    Parameters
    ----------
    frame_ids : iterable of (int, (N_t,) int ndarray, object)
        Each frame's index, its records' trajectory ids, and where they come from (named in
        errors).
    records : iterable of FrameRecord
        The same frames' records, in the same order.
    num_cameras : int
    camera_names : list of str
    fps : float
    num_frames : int

    Returns
    -------
    Trajectories
        Trajectory m is the one with id m.

    Raises
    ------
    ValidationError
        If an id is negative, the ids are not ``0 .. M-1`` or a trajectory skips a frame.
    """
    counts = np.zeros(0, np.int64)
    first = np.zeros(0, np.int64)
    last = np.zeros(0, np.int64)
    for t, ids, where in frame_ids:
        ids = ids.astype(np.int64, copy=False)
        if ids.size == 0:
            continue
        if ids.min() < 0:
            raise ValidationError(f"{where}: negative trajectory id")
        top = int(ids.max()) + 1
        if top > counts.size:
            grow = max(top, 2 * counts.size) - counts.size
            counts = np.concatenate([counts, np.zeros(grow, np.int64)])
            first = np.concatenate([first, np.full(grow, -1, np.int64)])
            last = np.concatenate([last, np.full(grow, -1, np.int64)])
        seen = counts[ids] > 0
        if np.any(last[ids[seen]] != t - 1):
            raise ValidationError("assemble_trajectories: a trajectory skips a frame")
        first[ids[~seen]] = t
        last[ids] = t
        counts[ids] += 1
    nonzero = np.flatnonzero(counts)
    M = int(nonzero[-1]) + 1 if nonzero.size else 0
    if M == 0:
        return Trajectories.empty(camera_names, fps, num_frames)
    counts, first = counts[:M], first[:M]
    if np.any(counts == 0):
        raise ValidationError("assemble_trajectories: trajectory ids are not 0 .. M-1")
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    P, C = int(offsets[-1]), num_cameras
    xyz = np.empty((P, 3), np.float32)
    vis = np.empty((P, C), np.uint8)
    err = np.empty(P, np.float32)
    color = np.empty((P, 3), np.uint8)
    for rec in records:
        t = rec.frame
        if len(rec) == 0:
            continue
        rows = offsets[rec.ids] + (t - first[rec.ids])  # (N_t,)
        xyz[rows] = rec.xyz
        vis[rows] = rec.visibility
        err[rows] = rec.error
        color[rows] = rec.color
    return Trajectories(
        first_frame=first,
        offsets=offsets,
        xyz=xyz,
        visibility=vis,
        reprojection_error=err,
        color=color,
        camera_names=list(camera_names),
        fps=fps,
        num_frames=num_frames,
    )


def _check_live(path: Path, state: TrackState) -> None:
    """Refuse a live state whose arrays disagree in length, or whose lost views name a
    camera the rig lacks (naming the file)."""
    N = len(state.ids)
    C = state.visibility.shape[1] if state.visibility.ndim == 2 else -1
    problems = {
        "xyz": (state.xyz.shape, (N, 3)),
        "visibility": (state.visibility.shape, (N, C)),
        "pixels": (state.pixels.shape, (C, N, 2)),
        "lone": (state.lone.shape, (N,)),
        "misses": (state.misses.shape, (N, C)),
    }
    lost = state.lost
    L = lost.ids.shape[0] if lost.ids.ndim else -1
    problems |= {
        "lost_ids": (lost.ids.shape, (L,)),
        "lost_camera": (lost.camera.shape, (L,)),
        "lost_offset": (lost.offset.shape, (L, 2)),
        "lost_frac": (lost.frac.shape, (L, 2)),
        "lost_patch": (lost.patch.shape, (L, PATCH_SIDE * PATCH_SIDE)),
    }
    for name, (got, want) in problems.items():
        if got != want:
            raise FileFormatError(path, f"tracker state: live_{name} has {got}, expected {want}")
    if L > 0 and not np.all((lost.camera >= 0) & (lost.camera < C)):
        raise FileFormatError(
            path, f"tracker state: live_lost_camera has cameras outside 0-{C - 1}"
        )
