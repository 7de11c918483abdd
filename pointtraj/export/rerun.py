"""A work folder as a Rerun recording (``.rrd``), written frame by frame.

``rerun-sdk`` is an optional dependency (``pip install 'pointtraj[export]'``), imported inside
:func:`write_recording`. The entity layout is in ``data_specs/rerun.md``:

- ``world/points``: frame t's points, coloured by label (class ids with an annotation context
  give the class names), with per-point ``track_id``, ``label`` and, from the semantic map,
  one confidence component per class (``Confidence:<class>``);
- ``world/people``: the same points coloured by person, where ``labels.npz`` has ``instance``;
- ``world/tracks``: each live trajectory's last ``tail`` frames as a line strip;
- ``world/cameras/<name>``: each camera's pose, and under it ``image``: its pinhole and its
  (downscaled, JPEG) image of frame t.

Time is on two timelines: ``frame`` (sequence) and ``time`` (seconds, from the capture's
frame rate). Memory holds the inputs (the store, its frame-major index, the per-trajectory
tables) and one frame of output: the recording goes to its file as it is logged.
"""

from __future__ import annotations

import logging
import os
import time
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import FileFormatError, ValidationError

if TYPE_CHECKING:  # pragma: no cover
    from ..camera import Camera, CameraRig
    from ..session import Capture
    from ..stages import Progress
    from ..trajectories import Trajectories

__all__ = [
    "RerunConfig",
    "RerunExport",
    "export_rerun",
    "write_recording",
    "tail_rows",
    "cycle_colors",
    "NO_CLASS",
    "PERSON_COLORS",
]

logger = logging.getLogger(__name__)

#: Class id of an unlabelled point (label -1) and of a point of no person (instance -1).
NO_CLASS = 65535

#: How many distinct colours people (and trajectories, when a work folder has no labels) cycle
#: through.
PERSON_COLORS = 64

#: The pip extra that installs ``rerun-sdk``.
EXTRA = "export"


@dataclass(frozen=True)
class RerunConfig:
    """Options of the Rerun export (``pointtraj export rerun``).

    Attributes
    ----------
    tail : int
        Past frames in each trajectory's line strip: it joins the trajectory's positions from
        frame ``t - tail`` (or its first frame) to frame t, as ``pointtraj render``'s tails
        do. 0 logs no line strips.
    images : bool
        Log each camera's image of every frame (the cameras' poses are logged either way).
    image_scale : float
        Scale of the logged images, in (0, 1]; the pinholes are scaled with them.
    jpeg_quality : int
        JPEG quality of the logged images, 1 to 100.
    confidences : bool
        Log the semantic map's L3D confidences per point (one component per class).
    pooling : str
        The semantic map's pooling whose confidences are logged; "" means that of
        ``labels.npz``, else the map's default.
    """

    tail: int = 10
    images: bool = True
    image_scale: float = 0.5
    jpeg_quality: int = 85
    confidences: bool = True
    pooling: str = ""

    def __post_init__(self) -> None:
        if self.tail < 0:
            raise ValidationError(f"tail must be 0 or more, got {self.tail}")
        if not 0.0 < self.image_scale <= 1.0:
            raise ValidationError(f"image_scale must be in (0, 1], got {self.image_scale}")
        if not 1 <= self.jpeg_quality <= 100:
            raise ValidationError(f"jpeg_quality must be in [1, 100], got {self.jpeg_quality}")


@dataclass(frozen=True)
class RerunExport:
    """What :func:`write_recording` wrote.

    Attributes
    ----------
    path : pathlib.Path
        The ``.rrd`` file.
    frames : range
        The frames logged.
    points : int
        Point-frames logged (the sum over frames of the points on ``world/points``).
    strips : int
        Line strips logged, over all frames.
    images : int
        Camera images logged.
    cameras : int
        Cameras logged (poses and pinholes).
    color_source : str
        What colours ``world/points``: ``"labels.npz"``, ``"semantic_map.npz (argmax)"`` or
        ``"trajectory"`` (no labels: a colour per trajectory).
    people : int
        Distinct people of ``instance`` (0 without).
    seconds : float
        Wall time of the export.
    """

    path: Path
    frames: range
    points: int
    strips: int
    images: int
    cameras: int
    color_source: str
    people: int
    seconds: float


def _import_rerun() -> Any:
    """The ``rerun`` module, or a one-line error naming the pip extra."""
    try:
        import rerun
    except ImportError:
        raise ValidationError(
            f"exporting a Rerun recording needs rerun-sdk: pip install 'pointtraj[{EXTRA}]' "
            "(or pip install rerun-sdk)"
        ) from None
    return rerun


def cycle_colors(n: int) -> np.ndarray:
    """``n`` distinct, deterministic display colours (golden-ratio hues).

    Parameters
    ----------
    n : int

    Returns
    -------
    (n, 3) uint8 ndarray

    Examples
    --------
    >>> cycle_colors(2).shape
    (2, 3)
    """
    from matplotlib.colors import hsv_to_rgb

    hue = (0.13 + 0.618034 * np.arange(n)) % 1.0  # (n,)
    hsv = np.stack([hue, np.full(n, 0.75), np.full(n, 0.9)], axis=1)  # (n, 3)
    return np.rint(hsv_to_rgb(hsv) * 255).astype(np.uint8)


def _class_ids(values: np.ndarray) -> np.ndarray:
    """(M,) uint16 class ids: ``values`` where non-negative, :data:`NO_CLASS` where -1."""
    values = np.asarray(values, np.int64)
    return np.where(values >= 0, values, NO_CLASS).astype(np.uint16)


def tail_rows(
    trajectories: Trajectories, rows: np.ndarray, track: np.ndarray, t: int, tail: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The rows of each live trajectory from frame ``t - tail`` to frame ``t``, as strips.

    A trajectory's rows are consecutive in the store, so its strip ends at its row at ``t``.
    (:func:`pointtraj.render.scene.tail_segments` gives the same tails as separate segments
    with their age, for fading.)

    Parameters
    ----------
    trajectories : Trajectories
    rows : (N,) int64 ndarray
        The rows alive at frame ``t`` (:meth:`Trajectories.frame_rows`).
    track : (N,) int64 ndarray
        Their trajectories.
    t : int
    tail : int
        Past frames, at least 1.

    Returns
    -------
    idx : (Q,) int64 ndarray
        The tails' rows, strip after strip, oldest first.
    offsets : (S + 1,) int64 ndarray
        Strip s is ``idx[offsets[s]:offsets[s + 1]]``.
    strip_track : (S,) int64 ndarray
        The trajectory of each strip: those of ``track`` alive before frame ``t`` too.
    """
    start = np.maximum(trajectories.first_frame[track], t - tail)  # (N,)
    n = t - start + 1  # (N,) frames in each strip
    keep = n >= 2
    rows_k, n_k = rows[keep], n[keep]
    offsets = np.concatenate([[0], np.cumsum(n_k)]).astype(np.int64)  # (S + 1,)
    begin = rows_k - (n_k - 1)  # (S,) each tail's first row
    idx = np.repeat(begin - offsets[:-1], n_k) + np.arange(offsets[-1], dtype=np.int64)
    return idx, offsets, track[keep]


def _strips_array(rr: Any, xyz: np.ndarray, offsets: np.ndarray) -> Any:
    """Line strips as the exact Arrow type of Rerun's ``LineStrip3D`` (no per-strip Python)."""
    import pyarrow as pa

    if offsets[-1] >= 2**31:
        raise ValidationError(
            f"{int(offsets[-1])} line-strip points in one frame exceed Arrow's 32-bit offsets; "
            "use a shorter tail"
        )
    kind = rr.components.LineStrip3DBatch._ARROW_DATATYPE
    inner = pa.FixedSizeListArray.from_arrays(
        pa.array(np.ascontiguousarray(xyz, np.float32).reshape(-1)), type=kind.value_type
    )
    return pa.ListArray.from_arrays(pa.array(offsets.astype(np.int32)), inner, type=kind)


def write_recording(
    path: str | os.PathLike,
    trajectories: Trajectories,
    *,
    labels: np.ndarray | None = None,
    class_names: tuple[str, ...] = (),
    palette: np.ndarray | None = None,
    instance: np.ndarray | None = None,
    confidences: np.ndarray | None = None,
    rig: CameraRig | None = None,
    capture: Capture | None = None,
    config: RerunConfig | None = None,
    frames: range | None = None,
    color_source: str = "",
    name: str = "pointtraj",
    progress: Progress | None = None,
) -> RerunExport:
    """Write a Rerun recording of a trajectory store, one frame at a time, atomically.

    Parameters
    ----------
    path : path-like
        The ``.rrd`` file.
    trajectories : Trajectories
        M trajectories over T frames.
    labels : (M,) int ndarray, optional
        Class per trajectory, -1 unlabelled. Without it the points take a colour per trajectory.
    class_names : tuple of K str
        The classes of ``labels`` and ``confidences``.
    palette : (K, 3) uint8 ndarray, optional
        Display colour per class (default :func:`pointtraj.render.palette.class_palette`).
    instance : (M,) int ndarray, optional
        Person per trajectory, -1 none; adds ``world/people``.
    confidences : (M, K) float ndarray, optional
        The semantic map's L3D, logged per point when ``config.confidences``.
    rig : CameraRig, optional
        The cameras' poses and pinholes.
    capture : Capture, optional
        The images (``config.images``), by camera name.
    config : RerunConfig, optional
    frames : range, optional
        The frames to log (default: from the first to the last frame with a trajectory).
    color_source : str
        For the result (default: ``"labels"`` with labels, ``"trajectory"`` without).
    name : str
        The recording's name in the viewer.
    progress : callable, optional
        ``progress(label, done, total)`` after each frame.

    Returns
    -------
    RerunExport

    Raises
    ------
    ValidationError
        If rerun-sdk is not installed, or an array has the wrong shape.
    WriteError
        If the file cannot be written whole.
    """
    from ..atomic import atomic_path
    from ..errors import check_array
    from ..render.palette import UNLABELLED_COLOR, class_palette, label_colors

    rr = _import_rerun()
    cfg = config or RerunConfig()
    start_time = time.perf_counter()
    traj = trajectories
    M, K = traj.num_trajectories, len(class_names)
    frames = traj.occupied_frames if frames is None else frames
    if len(frames) and (frames[0] < 0 or frames[-1] >= traj.num_frames):
        raise ValidationError(f"frames {frames} outside the store's [0, {traj.num_frames})")

    # Per-trajectory tables, O(M): the colour, class id and person of each trajectory.
    if labels is not None:
        labels = check_array("labels", labels, (M,), dtype=np.int64)
        if M and (labels.min() < -1 or labels.max() >= K):
            raise ValidationError(f"labels must lie in [-1, {K}), the {K} classes")

        palette = (
            class_palette(class_names)
            if palette is None
            else check_array("palette", palette, (K, 3), dtype=np.uint8)
        )
        colors = label_colors(labels, palette)  # (M, 3)
        class_ids = _class_ids(labels)
        color_source = color_source or "labels"
    else:
        colors = cycle_colors(PERSON_COLORS)[np.arange(M) % PERSON_COLORS]  # (M, 3)
        class_ids = None
        color_source = color_source or "trajectory"
    people = 0
    if instance is not None:
        instance = check_array("instance", instance, (M,), dtype=np.int64)
        if M and instance.min() < -1:
            raise ValidationError("instance must be -1 (no person) or a person index >= 0")
        people = int(instance.max()) + 1 if M else 0
        if people >= NO_CLASS:
            raise ValidationError(f"instance: {people} people exceed {NO_CLASS - 1}")

        person_colors = np.empty((M, 3), np.uint8)
        person_colors[:] = UNLABELLED_COLOR
        has = instance >= 0
        person_colors[has] = cycle_colors(PERSON_COLORS)[instance[has] % PERSON_COLORS]
        person_ids = _class_ids(instance)
    if confidences is not None and cfg.confidences:
        confidences = check_array("confidences", confidences, (M, K), dtype=np.float32)
    else:
        confidences = None
    cameras = list(rig) if rig is not None else []
    image_cameras = cameras if (capture is not None and cfg.images) else []

    counts = {"points": 0, "strips": 0, "images": 0}
    path = Path(path)
    with atomic_path(path) as tmp:
        rec = rr.RecordingStream("pointtraj", recording_id=str(uuid.uuid4()))
        rec.set_log_time_enabled(False)
        rec.save(tmp)
        try:
            rec.send_recording_name(name)
            _log_static(rr, rec, cameras, cfg, class_names, palette, labels, people)
            for i, t in enumerate(frames):
                rec.set_time("frame", sequence=int(t))
                rec.set_time("time", duration=float(t) / traj.fps)
                rows = traj.frame_rows(int(t))  # (N,) frame-major index
                track = traj.row_track[rows]  # (N,)
                xyz = traj.xyz[rows]  # (N, 3)
                values: dict[str, np.ndarray] = {"track_id": track}
                extra: list[Any] = []
                if labels is not None:
                    values["label"] = labels[track]
                if confidences is not None:
                    conf = confidences[track]  # (N, K)
                    extra.append(
                        rr.DynamicArchetype(
                            "Confidence",
                            components={n: conf[:, k] for k, n in enumerate(class_names)},
                        )
                    )
                rec.log(
                    "world/points",
                    rr.Points3D(
                        xyz,
                        colors=colors[track],
                        class_ids=None if class_ids is None else class_ids[track],
                    ),
                    rr.AnyValues(**values),
                    *extra,
                )
                counts["points"] += len(rows)
                if instance is not None:
                    rec.log(
                        "world/people",
                        rr.Points3D(xyz, colors=person_colors[track], class_ids=person_ids[track]),
                        rr.AnyValues(instance=instance[track]),
                    )
                if cfg.tail > 0:
                    idx, offsets, strip_track = tail_rows(traj, rows, track, int(t), cfg.tail)
                    rec.log(
                        "world/tracks",
                        rr.LineStrips3D(
                            _strips_array(rr, traj.xyz[idx], offsets),
                            colors=colors[strip_track],
                        ),
                    )
                    counts["strips"] += len(strip_track)
                for cam in image_cameras:
                    if t < capture.num_frames:
                        _log_image(rr, rec, capture, cam, int(t), cfg)
                        counts["images"] += 1
                rec.flush()  # the frame reaches the file: memory holds one frame
                if progress is not None:
                    progress("export rerun", i + 1, len(frames))
        finally:
            rec.flush()
            rec.disconnect()
    seconds = time.perf_counter() - start_time
    logger.info("wrote %s: %d frames in %.1f s", path, len(frames), seconds)
    return RerunExport(
        path=path,
        frames=frames,
        points=counts["points"],
        strips=counts["strips"],
        images=counts["images"],
        cameras=len(cameras),
        color_source=color_source,
        people=people,
        seconds=seconds,
    )


def _entity(camera: str) -> str:
    """The entity path of a camera."""
    from rerun import escape_entity_path_part

    return f"world/cameras/{escape_entity_path_part(camera)}"


def _log_static(
    rr: Any,
    rec: Any,
    cameras: list[Camera],
    cfg: RerunConfig,
    class_names: tuple[str, ...],
    palette: np.ndarray | None,
    labels: np.ndarray | None,
    people: int,
) -> None:
    """What does not change over time: class and person names, the cameras."""
    from ..render.palette import UNLABELLED_COLOR

    grey = tuple(int(c) for c in UNLABELLED_COLOR)
    if labels is not None and palette is not None:
        infos = [(k, n, tuple(int(c) for c in palette[k])) for k, n in enumerate(class_names)]
        rec.log(
            "world/points",
            rr.AnnotationContext([*infos, (NO_CLASS, "unlabelled", grey)]),
            static=True,
        )
    if people:
        person = cycle_colors(PERSON_COLORS)
        infos = [
            (p, f"person {p}", tuple(int(c) for c in person[p % PERSON_COLORS]))
            for p in range(people)
        ]
        rec.log(
            "world/people",
            rr.AnnotationContext([*infos, (NO_CLASS, "no person", grey)]),
            static=True,
        )
    for cam in cameras:
        pinhole = cam.resized(cfg.image_scale)
        K, (w, h) = pinhole.K, pinhole.size
        entity = _entity(cam.name)
        # Camera to world: X_w = R^T X_c + C (Camera.R is world to camera).
        rec.log(
            entity,
            rr.Transform3D(translation=np.asarray(cam.C, np.float64), mat3x3=cam.R.T),
            static=True,
        )
        rec.log(
            f"{entity}/image",
            rr.Pinhole(image_from_camera=K, resolution=[w, h], camera_xyz=rr.ViewCoordinates.RDF),
            static=True,
        )


def _log_image(
    rr: Any, rec: Any, capture: Capture, camera: Camera, t: int, cfg: RerunConfig
) -> None:
    """Camera ``camera``'s image of frame ``t``, resized to its pinhole, as a JPEG."""
    import cv2

    img = capture.read(camera.name, t)  # (H, W, 3) uint8 RGB
    w, h = camera.resized(cfg.image_scale).size
    if (img.shape[1], img.shape[0]) != (w, h):
        img = cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)
    rec.log(
        f"{_entity(camera.name)}/image",
        rr.Image(img, color_model="RGB").compress(jpeg_quality=cfg.jpeg_quality),
    )


def export_rerun(
    work: str | os.PathLike,
    out: str | os.PathLike | None = None,
    config: RerunConfig | None = None,
    *,
    frames: slice | None = None,
    progress: Progress | None = None,
) -> RerunExport:
    """Write a work folder's trajectories, labels, semantic map and cameras as a ``.rrd``.

    Parameters
    ----------
    work : path-like
        A work folder with ``trajectories.npz``; ``labels.npz`` (with its optional
        ``instance``), ``semantic_map.npz`` and the capture of ``work.toml`` are used where
        present.
    out : path-like, optional
        The recording (default ``WORK/export/recording.rrd``).
    config : RerunConfig, optional
    frames : slice, optional
        Frames to log, a slice of ``range(T)`` (negative ends count from the end; default:
        the frames with trajectories).
    progress : callable, optional
        ``progress(label, done, total)``.

    Returns
    -------
    RerunExport

    Raises
    ------
    FileFormatError
        If the work folder or ``trajectories.npz`` is missing, or a present file is unreadable
        or disagrees with the store.
    ValidationError
        If rerun-sdk is not installed or an option is out of range.
    """
    from ..labelset import LabelSet
    from ..render.palette import class_palette
    from ..results import load
    from ..session import Capture
    from ..workdir import WorkFolder

    cfg = config or RerunConfig()
    _import_rerun()  # fail before reading anything
    wf = WorkFolder(work)
    if not wf.path.is_dir():
        raise FileFormatError(wf.path, "work folder does not exist")
    res = load(wf.path)
    traj = res.trajectories

    capture = None
    try:
        cap_path = wf.capture_path()
    except FileFormatError as exc:
        logger.warning("no cameras: %s", exc)
        cap_path = None
    if cap_path is None:
        logger.warning("no cameras: %s names no capture", wf.work_toml)
    else:
        try:
            capture = Capture.open(cap_path, strict=False)
        except FileFormatError as exc:
            logger.warning("no cameras: cannot open the capture: %s", exc)
    if capture is not None:
        traj.check_cameras(capture, wf.trajectories)

    labels, source = None, "trajectory"
    if res.labels is not None:
        labels, source = res.labels.labels, "labels.npz"
    elif res.semantic_map is not None:
        labels, source = res.semantic_map.argmax_labels(), "semantic_map.npz (argmax)"
    else:
        logger.warning(
            "%s and %s missing: points coloured by trajectory", wf.labels, wf.semantic_map
        )
    palette = None
    if labels is not None:
        label_set = None
        if capture is not None and capture.labels_path is not None:
            label_set = LabelSet.load(capture.labels_path)
        palette = class_palette(res.class_names, label_set)
    instance = res.labels.instance if res.labels is not None else None

    confidences = None
    smap = res.semantic_map
    if smap is not None and cfg.confidences:
        pooling = cfg.pooling or (
            res.labels.pooling
            if res.labels is not None and res.labels.pooling in smap.poolings
            else smap.poolings[0]
        )
        if pooling not in smap.poolings:
            raise ValidationError(
                f"pooling: {pooling!r} not in {wf.semantic_map} (has: {', '.join(smap.poolings)})"
            )
        if tuple(smap.class_names) != tuple(res.class_names):
            raise FileFormatError(
                wf.semantic_map,
                f"its classes ({', '.join(smap.class_names)}) are not those of {wf.labels} "
                f"({', '.join(res.class_names)})",
            )
        confidences = smap.L3D[pooling]

    out = wf.path / "export" / "recording.rrd" if out is None else Path(out)
    try:
        return write_recording(
            out,
            traj,
            labels=labels,
            class_names=tuple(res.class_names),
            palette=palette,
            instance=instance,
            confidences=confidences,
            rig=capture.rig if capture is not None else None,
            capture=capture,
            config=cfg,
            frames=None if frames is None else range(traj.num_frames)[frames],
            color_source=source,
            name=wf.path.name,
            progress=progress,
        )
    finally:
        if capture is not None:
            capture.close()
