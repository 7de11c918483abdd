"""The reconstruction stage driver and its work-folder files.

:func:`reconstruct_capture` streams a capture frame by frame through the :class:`~.track.Tracker`
into a work folder, writing each frame's point cloud and tracker state atomically so that an
interrupted run resumes from the last complete frame (the files: :mod:`.framestore`), and
assembles the ragged :class:`~pointtraj.trajectories.Trajectories` store from the per-frame
record files (:meth:`.framestore.FrameStore.assemble`; :func:`assemble_trajectories` does the
same from records in memory). A long
frame range is tracked in temporal chunks, one executor task each (:func:`reconstruct_chunk`),
joined across their boundaries (:mod:`~.chunks`).
"""

from __future__ import annotations

import dataclasses
import logging
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..atomic import TEMP_PREFIX, record_installed
from ..camera import CameraRig
from ..errors import FileFormatError, ValidationError
from ..executor import Executor, SerialExecutor
from ..trajectories import Trajectories, frame_pointcloud, write_cloud_ply
from .chunks import Bridge, Chunk, merge_chunks, plan_chunks
from .config import ReconstructConfig
from .framestore import FrameStore, assemble_records
from .stitch import stitch_trajectories
from .survive import trim_one_view_tails
from .texture import describe_texture_scale, texture_cameras, texture_patch_spacing
from .track import FrameRecord, Tracker, TrackState, config_edges

__all__ = [
    "ChunkResult",
    "ChunkTask",
    "assemble_trajectories",
    "reconstruct_capture",
    "reconstruct_chunk",
]

logger = logging.getLogger(__name__)

# -- assembling the store ---------------------------------------------------------------------


def assemble_trajectories(
    records: Sequence[FrameRecord], camera_names: list[str], fps: float, num_frames: int
) -> Trajectories:
    """Build the ragged store from per-frame records in memory
    (:func:`~.framestore.assemble_records`, as for records on disk).

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
    C = records[0].visibility.shape[1] if records else len(camera_names)
    return assemble_records(
        ((r.frame, r.ids, f"frame {r.frame}") for r in records),
        records,
        C,
        camera_names,
        fps,
        num_frames,
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


@dataclass(frozen=True)
class ChunkTask:
    """One temporal chunk to track: an executor task for :func:`reconstruct_chunk`.

    Attributes
    ----------
    capture : str or Capture
        The capture folder, which the worker opens with ``rig`` (workers share the filesystem),
        or, where there is no folder, the capture itself (serial runs).
    rig : CameraRig
        The calibration the capture was opened with.
    folder : str
        The chunk's sub-folder of the work folder (``state/``, ``trajectories.npz``,
        ``tail.npz``).
    start, stop : int
        The frames tracked, warm-up included.
    tail_stop : int
        The trajectories alive at ``stop - 1`` are carried on, without new points, up to this
        frame (the next chunk's end; ``stop``: no tail, the last chunk).
    config : ReconstructConfig
    edges : (E, 2) int64 ndarray, optional
        The camera pairs to match (default: from the config, :func:`~.track.config_edges`);
        :func:`reconstruct_capture` chooses them once, where their warnings are seen.
    """

    capture: Any
    rig: CameraRig
    folder: str
    start: int
    stop: int
    tail_stop: int
    config: ReconstructConfig
    edges: np.ndarray | None = None


@dataclass(frozen=True)
class ChunkResult:
    """What :func:`reconstruct_chunk` gives back (small: the store stays in its file).

    Attributes
    ----------
    store : str
        The chunk's ``trajectories.npz``.
    tail : str or None
        Its ``tail.npz`` (None for the last chunk).
    tracked : int
        Frames tracked by this call (0 when the chunk was already complete).
    stops : dict of str to int
        Trajectories ended, by reason, in the frames tracked by this call.
    cpu_s : float
        CPU seconds of this call in its process.
    wall_s : float
        Wall seconds of this call.
    """

    store: str
    tail: str | None
    tracked: int
    stops: dict[str, int]
    cpu_s: float
    wall_s: float = 0.0


def one_blas_thread():
    """A context in which BLAS (numpy's matrix products) runs on one thread.

    A multi-threaded BLAS splits a large product into blocks by its thread count, and the
    blocks' edges can round the last bit differently: on paper69, 2 of the 51,041 reprojection
    errors of frame 0 differed between 2 threads (serial, in the calling process) and 1 (a
    Dask worker, whose environment limits it), and the tracker's later decisions went apart.
    Tracking runs on one BLAS thread everywhere, so that no executor changes an output. Its
    products are (N, 3) by (3, 3): one thread costs little.
    """
    from threadpoolctl import threadpool_limits

    return threadpool_limits(limits=1, user_api="blas")


def reconstruct_chunk(task: ChunkTask) -> ChunkResult:
    """Track one temporal chunk into its folder, resuming it; then its tail.

    Writes ``state/`` per frame and ``trajectories.npz`` (the chunk's store) once its frames
    are done, then ``tail.npz``: the trajectories alive at its last frame carried on over the
    next chunk's frames by the same tracker, without new points, until they end
    (:class:`~.chunks.Bridge`, joined to the next chunk by :func:`~.chunks.join_tail`). A
    chunk whose files exist is not recomputed; an interrupted one resumes after its last
    complete frame (its ``state/`` files).

    Parameters
    ----------
    task : ChunkTask

    Returns
    -------
    ChunkResult
    """
    cpu0, wall0 = time.process_time(), time.perf_counter()
    folder = Path(task.folder)
    out = folder / "trajectories.npz"
    tail = folder / "tail.npz" if task.tail_stop > task.stop else None
    if out.is_file() and (tail is None or tail.is_file()):
        return ChunkResult(str(out), tail and str(tail), 0, {}, 0.0)
    capture = task.capture
    if isinstance(capture, (str, os.PathLike)):
        from ..session import Capture

        capture = Capture.open(capture, rig=task.rig, strict=False)
    frames = range(task.start, task.stop)
    tracked, stops = 0, {}
    with one_blas_thread():
        if not out.is_file():
            traj, tracker, resumed = _track_frames(
                capture, folder, frames, task.config, edges=task.edges
            )
            traj.save(out)
            tracked, stops = len(frames) - resumed, dict(tracker.stops)
        if tail is not None:
            state = FrameStore(folder, len(capture.rig)).read_state_at(task.stop - 1)
            _carry_on(capture, state, task.tail_stop, task.config, task.edges).save(tail)
    return ChunkResult(
        str(out),
        tail and str(tail),
        tracked,
        stops,
        time.process_time() - cpu0,
        time.perf_counter() - wall0,
    )


def _carry_on(
    capture, state: TrackState, stop: int, cfg: ReconstructConfig, edges: np.ndarray | None = None
) -> Bridge:
    """Track the live trajectories of a state on to ``stop``, without new points (no matching,
    no densification), until they end: a chunk's tail (:class:`~.chunks.Bridge`, no joins).
    """
    rig = capture.rig
    names = list(rig.names)
    carry_cfg = dataclasses.replace(
        cfg,
        match_every=2**62,  # never at the frames stepped here: no new points
        match_moving=False,
        densify=dataclasses.replace(cfg.densify, enabled=False),
        views=dataclasses.replace(
            cfg.views, enabled=cfg.views.enabled and cfg.chunk_tail_discovery
        ),
    )
    tracker = Tracker(rig, carry_cfg, edges, state=state, first_frame=state.frame)
    rows: list[FrameRecord] = []
    if len(state):
        tracker.set_previous_images([capture.read(n, state.frame) for n in names])
    for t in range(state.frame + 1, stop):
        if len(tracker.state) == 0:
            break
        rec = tracker.step(t, [capture.read(n, t) for n in names])
        old = rec.ids < state.next_id  # (no new points: every one)
        rows.append(
            FrameRecord(
                t, rec.ids[old], rec.xyz[old], rec.visibility[old], rec.error[old], rec.color[old]
            )
        )
    C = len(rig)
    return Bridge(
        ids=np.concatenate([r.ids for r in rows] or [np.zeros(0)]).astype(np.int64),
        frame=np.concatenate([np.full(len(r), r.frame) for r in rows] or [np.zeros(0)]).astype(
            np.int64
        ),
        xyz=np.concatenate([r.xyz for r in rows] or [np.zeros((0, 3))]).astype(np.float32),
        visibility=np.concatenate([r.visibility for r in rows] or [np.zeros((0, C))]).astype(
            np.uint8
        ),
        error=np.concatenate([r.error for r in rows] or [np.zeros(0)]).astype(np.float32),
        color=np.concatenate([r.color for r in rows] or [np.zeros((0, 3))]).astype(np.uint8),
        joins=np.zeros((0, 3), np.int64),
    )


def _track_frames(
    capture,
    folder: Path,
    frames: range,
    cfg: ReconstructConfig,
    *,
    write_clouds: bool = False,
    on_frame: Callable[[FrameRecord | None], None] | None = None,
    edges: np.ndarray | None = None,
) -> tuple[Trajectories, Tracker, int]:
    """Track frames with one tracker into ``folder/state/`` (and ``folder/clouds/``), resuming.

    Each frame's record goes to ``state/<t>.npz`` and the tracker's state replaces
    ``state/live.npz`` (:class:`~.framestore.FrameStore`); no record stays in memory, and the
    store is assembled from the record files at the end.

    Returns
    -------
    store : Trajectories
        The frames' store (before stitching), resumed frames included.
    tracker : Tracker
        Its ``stops`` count the trajectories ended in the frames tracked now.
    resumed : int
        Frames complete before this call.
    """
    rig = capture.rig
    names = list(rig.names)
    store = FrameStore(folder, len(rig))
    resumed, state = store.resume(frames)
    if on_frame is not None:
        for t in frames[:resumed]:
            on_frame(store.read_record(t))
    if resumed:
        logger.info(
            "%s: resuming after frame %d (%d frames done)", folder, frames[resumed - 1], resumed
        )
    tracker = Tracker(rig, cfg, edges, state=state, first_frame=frames.start)
    if state is not None and resumed < len(frames):
        tracker.set_previous_images([capture.read(n, state.frame) for n in names])
    for t in frames[resumed:]:
        images = [capture.read(n, t) for n in names]
        rec = tracker.step(t, images)
        if len(rec.ids) == 0:
            logger.warning(
                "frame %d: no point reconstructed (black or featureless images?); "
                "writing an empty cloud and going on",
                t,
            )
        if write_clouds:
            write_frame_cloud(folder / "clouds" / f"{t:06d}.ply", rec, cfg.cloud_visibility)
        store.save_frame(rec, tracker.state)
        if on_frame is not None:
            on_frame(rec)
    traj = store.assemble(frames, names, float(capture.fps), int(capture.num_frames))
    return traj, tracker, resumed


def _log_stops(stops: dict[str, int]) -> None:
    ended = sum(stops.values())
    if ended:
        logger.info(
            "%d trajectories ended in the frames reconstructed now: %s",
            ended,
            ", ".join(f"{k} {100 * v / ended:.1f} %" for k, v in stops.items()),
        )


def reconstruct_capture(
    capture,
    work: str | os.PathLike,
    frames: range | None = None,
    config: ReconstructConfig | None = None,
    *,
    on_frame: Callable[[FrameRecord | None], None] | None = None,
    executor: Executor | None = None,
) -> Trajectories:
    """Reconstruct trajectories of a capture into a work folder, resuming where it stopped.

    A frame range of at most ``config.chunk_frames`` frames is one chunk: it writes
    ``clouds/<t:06d>.ply`` and the frame's record ``state/<t:06d>.npz`` per frame, then replaces
    ``state/live.npz`` (the tracker's state, which marks the frame complete;
    :class:`~.framestore.FrameStore`), and at the end ``trajectories.npz``, assembled from the
    record files; frames up to the live state's (with records contiguously from
    ``frames.start``) are not recomputed. No record stays in memory between frames.

    A longer range is tracked in temporal chunks (:func:`~.chunks.plan_chunks`), one executor
    task each (:func:`reconstruct_chunk`), into ``chunks/<start>-<stop>/`` (``state/`` per
    frame, ``trajectories.npz`` when complete, then ``tail.npz``: its trajectories carried on
    over the next chunk's frames); the stores are joined across the boundaries
    (:func:`~.chunks.merge_chunks`), and ``clouds/`` and ``trajectories.npz`` are written from
    the result. Complete chunks are not recomputed; an interrupted one resumes
    from its last complete frame. The output does not depend on the executor.

    In both cases the store is then stitched (:mod:`~.stitch`) and its one-view tails trimmed
    (:func:`~.survive.trim_one_view_tails`).

    Parameters
    ----------
    capture : pointtraj.session.Capture
        With ``rig``, ``camera_names``, ``num_frames``, ``fps`` and ``read(camera, frame)``;
        chunks on other processes open it again from its ``path`` (a folder every worker
        reads).
    work : path-like
        The work folder.
    frames : range, optional
        Frames to process (step 1), default all.
    config : ReconstructConfig, optional
    on_frame : callable, optional
        Called once per frame, e.g. to advance a progress bar: with the frame's record in a
        one-chunk run (also for resumed frames), with None for each frame of a finished chunk.
    executor : Executor, optional
        Runs the chunks (default: serially, in this process).

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
    # the rig-derived settings and camera pairs, chosen once here, where their log is seen
    cfg = with_texture_choices(cfg, capture, frames.start).for_rig(rig)
    edges = config_edges(rig, cfg)
    chunks = plan_chunks(frames, cfg.chunk_frames, cfg.chunk_overlap)
    if len(chunks) == 1:
        with one_blas_thread():
            traj, tracker, _ = _track_frames(
                capture, work, frames, cfg, write_clouds=True, on_frame=on_frame, edges=edges
            )
        _log_stops(tracker.stops)
    else:
        traj = _reconstruct_chunks(capture, work, chunks, cfg, executor, on_frame, edges)
    stitched, new_id = stitch_trajectories(traj, cfg.stitch)
    final, dropped = trim_one_view_tails(stitched, cfg.visibility_threshold, cfg.min_views)
    if dropped:
        logger.info(
            "%d one-view point-frames at trajectories' ends dropped (no second view returned)",
            dropped,
        )
    form = cfg.cloud_visibility
    if len(chunks) > 1:  # no frame has a cloud yet
        for t in frames:
            final.write_frame_ply(t, work / "clouds" / f"{t:06d}.ply", visibility_form=form)
    elif final is not traj:  # the clouds carry the stitched trajectories' ids and rows
        for t in frames:
            if _frame_changed(traj, final, t):
                final.write_frame_ply(t, work / "clouds" / f"{t:06d}.ply", visibility_form=form)
    final.save(work / "trajectories.npz")
    return final


def with_texture_choices(cfg: ReconstructConfig, capture, frame: int) -> ReconstructConfig:
    """``cfg`` with the patch spacings of densification and view discovery chosen from a
    frame's texture where they are left out (:func:`~.texture.texture_patch_spacing`: one
    spacing for both), and the choice logged.

    Parameters
    ----------
    cfg : ReconstructConfig
    capture : pointtraj.session.Capture
        With ``camera_names`` and ``read(camera, frame)``.
    frame : int
        The frame whose images are measured (the first one reconstructed).

    Returns
    -------
    ReconstructConfig
        Unchanged where both spacings are set, or the mechanisms whose are left out are off
        (densification set off, view discovery off).
    """
    d, v = cfg.densify, cfg.views
    left = [
        name
        for name, on, sub in (("densify", d.enabled is not False, d), ("views", v.enabled, v))
        if on and sub.patch_spacing_px is None
    ]
    if not left:
        return cfg
    names = list(capture.camera_names)
    images = [capture.read(names[c], frame) for c in texture_cameras(len(names))]
    spacing, scale = texture_patch_spacing(images, d.patch_size)
    what = {"densify": "densification", "views": "view discovery"}
    logger.info(
        "patch spacing of %s (%s patch_spacing_px): samples %s",
        " and ".join(what[n] for n in left),
        " and ".join(f"[reconstruct.{n}]" for n in left),
        describe_texture_scale(scale, spacing),
    )
    return dataclasses.replace(
        cfg, **{n: dataclasses.replace(getattr(cfg, n), patch_spacing_px=spacing) for n in left}
    )


def _reconstruct_chunks(
    capture,
    work: Path,
    chunks: list[Chunk],
    cfg: ReconstructConfig,
    executor: Executor | None,
    on_frame: Callable[[FrameRecord | None], None] | None,
    edges: np.ndarray | None = None,
) -> Trajectories:
    """Track every chunk through the executor and merge their stores (see
    :func:`reconstruct_capture`)."""
    path = getattr(capture, "path", None)
    source = str(path) if path is not None and Path(path).is_dir() else capture
    tasks = [
        ChunkTask(
            source,
            capture.rig,
            str(work / "chunks" / c.name),
            c.start,
            c.stop,
            chunks[k + 1].stop if k + 1 < len(chunks) else c.stop,
            cfg,
            edges,
        )
        for k, c in enumerate(chunks)
    ]
    executor = executor or SerialExecutor()
    logger.info(
        "tracking %d frames in %d chunks of %d frames (%d warm-up frames each) on %r",
        chunks[-1].stop - chunks[0].start,
        len(chunks),
        cfg.chunk_frames,
        cfg.chunk_overlap,
        executor,
    )
    stops: dict[str, int] = {}
    stores: list[Trajectories] = []
    tails: list[Bridge | None] = []
    for chunk, result in zip(chunks, executor.map(reconstruct_chunk, tasks, label="reconstruct")):
        for f in sorted(Path(work / "chunks" / chunk.name).rglob("*")):
            if f.is_file() and not f.name.startswith(TEMP_PREFIX):
                record_installed(f)  # a worker wrote them: the work folder's manifest lists them
        for k, v in result.stops.items():
            stops[k] = stops.get(k, 0) + v
        if result.tracked:
            logger.info(
                "chunk %s: %d frames tracked%s in %.1f s (%.1f CPU-s in its process)",
                chunk.name,
                result.tracked,
                " and its tail carried on" if result.tail else "",
                result.wall_s,
                result.cpu_s,
            )
        stores.append(Trajectories.load(result.store))
        tails.append(Bridge.load(result.tail) if result.tail else None)
        if on_frame is not None:
            for _ in range(chunk.stop - chunk.boundary):
                on_frame(None)
    _log_stops(stops)
    merged, _ = merge_chunks(
        stores,
        chunks,
        capture.rig,
        cfg.chunk_join_m,
        2 * cfg.ransac_threshold_px,
        cfg.visibility_threshold,
        tails=tails[:-1],
    )
    return merged


def _frame_changed(before: Trajectories, after: Trajectories, t: int) -> bool:
    """Whether frame t's point-frames differ between two stores (ids, rows or positions)."""
    a, b = before.frame_rows(t), after.frame_rows(t)
    if len(a) != len(b):
        return True
    return not (
        np.array_equal(before.row_track[a], after.row_track[b])
        and np.array_equal(before.xyz[a], after.xyz[b], equal_nan=True)
    )
