"""The reconstruction stage driver and its work-folder files.

:func:`reconstruct_capture` streams a capture frame by frame through the :class:`~.track.Tracker`
into a work folder, writing each frame's point cloud and tracker state atomically so that an
interrupted run resumes from the last complete frame (the files: :mod:`.framestore`), and
assembles the ragged :class:`~pointtraj.trajectories.Trajectories` store from the per-frame
record files (:meth:`.framestore.FrameStore.assemble`; :func:`assemble_trajectories` does the
same from records in memory).
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from ..errors import FileFormatError, ValidationError
from ..trajectories import Trajectories, frame_pointcloud, write_cloud_ply
from .config import ReconstructConfig
from .framestore import FrameStore
from .stitch import stitch_trajectories
from .survive import trim_one_view_tails
from .track import FrameRecord, Tracker

__all__ = [
    "assemble_trajectories",
    "reconstruct_capture",
]

logger = logging.getLogger(__name__)

# -- assembling the store ---------------------------------------------------------------------


def assemble_trajectories(
    records: Sequence[FrameRecord], camera_names: list[str], fps: float, num_frames: int
) -> Trajectories:
    """Build the ragged store from per-frame records (one stable sort by trajectory id).

    Parameters
    ----------
    records : list of FrameRecord
        In frame order; a trajectory's frames must be consecutive.
    camera_names : list of str
    fps : float
    num_frames : int

    Returns
    -------
    Trajectories
        Trajectory m is the one with id m; ids must be ``0 .. M-1``.
    """
    if not records:
        return Trajectories.empty(camera_names, fps, num_frames)
    ids = np.concatenate([r.ids for r in records])  # (P,)
    frames = np.concatenate([np.full(len(r), r.frame, np.int64) for r in records])
    order = np.lexsort((frames, ids))  # by id, then frame
    ids_s = ids[order]
    M = int(ids_s[-1]) + 1 if ids_s.size else 0
    counts = np.bincount(ids_s, minlength=M)
    if np.any(counts == 0):
        raise ValidationError("assemble_trajectories: trajectory ids are not 0 .. M-1")
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    first = frames[order][offsets[:-1]]
    span = frames[order][offsets[1:] - 1] - first + 1
    if np.any(span != counts):
        raise ValidationError("assemble_trajectories: a trajectory skips a frame")
    return Trajectories(
        first_frame=first,
        offsets=offsets,
        xyz=np.concatenate([r.xyz for r in records])[order],
        visibility=np.concatenate([r.visibility for r in records])[order],
        reprojection_error=np.concatenate([r.error for r in records])[order],
        color=np.concatenate([r.color for r in records])[order],
        camera_names=list(camera_names),
        fps=fps,
        num_frames=num_frames,
    )


# -- work folder streaming --------------------------------------------------------------------


def write_frame_cloud(
    path: str | os.PathLike, record: FrameRecord, visibility_form: str = "full"
) -> None:
    """Write one frame's points as a PLY (:func:`~pointtraj.trajectories.frame_pointcloud`'s
    attributes, ``track_id`` as int32).

    Parameters
    ----------
    path : path-like
    record : FrameRecord
    visibility_form : {"full", "uint8", "sparse"}
        :data:`~pointtraj.trajectories.CLOUD_VISIBILITY`.
    """
    pcd = frame_pointcloud(
        record.xyz, record.color, record.visibility, record.ids, None, visibility_form
    )
    write_cloud_ply(path, pcd, record.visibility if visibility_form == "sparse" else None)


def reconstruct_capture(
    capture,
    work: str | os.PathLike,
    frames: range | None = None,
    config: ReconstructConfig | None = None,
    *,
    on_frame: Callable[[FrameRecord], None] | None = None,
) -> Trajectories:
    """Reconstruct trajectories of a capture into a work folder, resuming where it stopped.

    Writes ``clouds/<t:06d>.ply`` and the frame's record ``state/<t:06d>.npz`` per frame, then
    replaces ``state/live.npz`` (the tracker's state, which marks the frame complete;
    :class:`~.framestore.FrameStore`), and at the end ``trajectories.npz``, assembled from the
    record files. Frames up to the live state's (with records contiguously from
    ``frames.start``) are not recomputed. No record stays in memory between frames.

    Parameters
    ----------
    capture : pointtraj.session.Capture
        With ``rig``, ``camera_names``, ``num_frames``, ``fps`` and ``read(camera, frame)``.
    work : path-like
        The work folder.
    frames : range, optional
        Frames to process (step 1), default all.
    config : ReconstructConfig, optional
    on_frame : callable, optional
        Called with each frame's record (also for resumed frames), e.g. to advance a progress
        bar.

    Returns
    -------
    Trajectories
    """
    cfg = config or ReconstructConfig()
    work = Path(work)
    rig = capture.rig
    names = list(rig.names)
    if len(names) < 2:
        raise FileFormatError(
            getattr(capture, "path", work),
            f"reconstruction needs at least 2 cameras; the capture has {len(names)} "
            f"({', '.join(names)})",
        )
    T = int(capture.num_frames)
    frames = range(T) if frames is None else frames
    if frames.step != 1 or len(frames) == 0 or frames.start < 0 or frames.stop > T:
        raise ValidationError(
            f"frames {frames.start}:{frames.stop} must be a non-empty range within [0, {T})"
        )
    store = FrameStore(work, len(rig))
    done, state = store.resume(frames)
    for t in frames[:done]:
        if on_frame is not None:
            on_frame(store.read_record(t))
    if done:
        logger.info("resuming after frame %d (%d frames done)", frames[done - 1], done)
    tracker = Tracker(rig, cfg, state=state, first_frame=frames.start)
    if state is not None and done < len(frames):
        tracker.set_previous_images([capture.read(n, state.frame) for n in names])
    for t in frames[done:]:
        images = [capture.read(n, t) for n in names]
        rec = tracker.step(t, images)
        if len(rec.ids) == 0:
            logger.warning(
                "frame %d: no point reconstructed (black or featureless images?); "
                "writing an empty cloud and going on",
                t,
            )
        write_frame_cloud(work / "clouds" / f"{t:06d}.ply", rec, cfg.cloud_visibility)
        store.save_frame(rec, tracker.state)
        if on_frame is not None:
            on_frame(rec)
    ended = sum(tracker.stops.values())
    if ended:
        logger.info(
            "%d trajectories ended in the frames reconstructed now: %s",
            ended,
            ", ".join(f"{k} {100 * v / ended:.1f} %" for k, v in tracker.stops.items()),
        )
    traj = store.assemble(frames, names, float(capture.fps), T)
    stitched, new_id = stitch_trajectories(traj, cfg.stitch)
    final, dropped = trim_one_view_tails(stitched, cfg.visibility_threshold, cfg.min_views)
    if dropped:
        logger.info(
            "%d one-view point-frames at trajectories' ends dropped (no second view returned)",
            dropped,
        )
    if final is not traj:  # the clouds carry the stitched trajectories' ids and rows
        for t in frames:
            if _frame_changed(traj, final, t):
                final.write_frame_ply(
                    t, work / "clouds" / f"{t:06d}.ply", visibility_form=cfg.cloud_visibility
                )
    final.save(work / "trajectories.npz")
    return final


def _frame_changed(before: Trajectories, after: Trajectories, t: int) -> bool:
    """Whether frame t's point-frames differ between two stores (ids, rows or positions)."""
    a, b = before.frame_rows(t), after.frame_rows(t)
    if len(a) != len(b):
        return True
    return not (
        np.array_equal(before.row_track[a], after.row_track[b])
        and np.array_equal(before.xyz[a], after.xyz[b], equal_nan=True)
    )
