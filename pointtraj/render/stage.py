"""The render stage: :func:`render_work` renders a labelled work folder into ``WORK/renders/``.

PNG frames and an MP4 per view (the orbiting virtual camera, rig cameras), overlays on the
camera images, and a legend, resuming where a previous run stopped; see
``data_specs/work_folder.md``.
"""

from __future__ import annotations

import contextlib
import dataclasses
import itertools
import json
import logging
import math
import os
import re
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Literal

import numpy as np

from ..atomic import write_text_atomic
from ..camera import Camera, CameraRig
from ..errors import FileFormatError, ValidationError
from ..geometry import resolve_up
from ..trajectories import Trajectories
from ..workdir import WorkFolder, locked
from .config import ORBIT, RenderConfig
from .offscreen import TrajectoryRenderer
from .overlay import (
    draw_caption,
    draw_legend,
    draw_overlay,
    draw_scene,
    legend_image,
    legend_origin,
)
from .palette import UNLABELLED_COLOR, blend_colors, class_palette, label_colors
from .scene import floor_grid, frame_geometry, orbit_cameras, plane_basis
from .video import read_png, write_png, write_video

if TYPE_CHECKING:
    from ..executor import Executor
    from ..session import Capture

__all__ = ["RenderOutput", "RenderResult", "render_work"]

logger = logging.getLogger(__name__)

#: Version of the ``render.json`` written beside each folder of frames; a change of what the
#: same settings draw raises it, so that frames drawn before are re-rendered (2: legend and
#: caption text sized from the image's shorter side).
_PARAMS_VERSION = 2

_FRAME_PNG = re.compile(r"^\d{6}\.png$")


@dataclass
class RenderOutput:
    """One folder of frames written by :func:`render_work`.

    Attributes
    ----------
    kind : {"view", "overlay"}
    name : str
        View name (``"orbit"`` or a camera) or the overlay's camera.
    folder : pathlib.Path
        Holds ``<t:06d>.png`` per frame and ``render.json`` (the settings they were made with).
    video : pathlib.Path or None
        The MP4, if one was written.
    size : (int, int)
        Image (width, height).
    rendered, skipped : int
        Frames drawn now, and frames found up to date and kept.
    render_seconds : float
        Wall time spent drawing and writing the rendered frames.
    """

    kind: Literal["view", "overlay"]
    name: str
    folder: Path
    video: Path | None
    size: tuple[int, int]
    rendered: int = 0
    skipped: int = 0
    render_seconds: float = 0.0


@dataclass
class RenderResult:
    """What :func:`render_work` made.

    Attributes
    ----------
    folder : pathlib.Path
        ``WORK/renders``.
    outputs : list of RenderOutput
        Views first, then overlays.
    legend : pathlib.Path
        ``renders/legend.png``.
    frames : range
        The frames rendered.
    color_source : str
        ``"labels.npz"``, ``"semantic_map.npz (argmax)"`` or ``"grey"``.
    num_trajectories : int
        Trajectories drawn (after ``min_length``).
    classes : list of str
        The classes in the legend.
    seconds : float
        Wall time of the call.
    """

    folder: Path
    outputs: list[RenderOutput]
    legend: Path
    frames: range
    color_source: str
    num_trajectories: int
    classes: list[str] = field(default_factory=list)
    seconds: float = 0.0

    @property
    def rendered(self) -> int:
        """Images drawn now."""
        return sum(o.rendered for o in self.outputs)

    @property
    def skipped(self) -> int:
        """Images found up to date and kept."""
        return sum(o.skipped for o in self.outputs)


@dataclass
class _Scene:
    """Everything :func:`render_work` loads from the work folder."""

    trajectories: Trajectories
    labels: np.ndarray  # (M,) int64, -1 unlabelled
    class_names: list[str]
    palette: np.ndarray  # (K, 3) uint8
    source: str
    inputs: list[Path]
    capture: Capture | None
    capture_problem: str


def _load_scene(work: Path, cfg: RenderConfig) -> _Scene:
    from ..config import load_toml
    from ..labelset import LabelSet, check_class_names
    from ..session import Capture

    if not work.is_dir():
        raise FileFormatError(work, "work folder does not exist")
    traj_path = work / "trajectories.npz"
    if not traj_path.is_file():
        raise FileFormatError(traj_path, "no such file (run `pointtraj reconstruct` first)")
    traj = Trajectories.load(traj_path)
    M = traj.num_trajectories
    inputs = [traj_path]

    capture, problem = None, f"{work / 'work.toml'} names no capture"
    if (work / "work.toml").is_file():
        cap_path = load_toml(work / "work.toml").get("capture")
        if isinstance(cap_path, str) and cap_path:
            try:
                capture = Capture.open(cap_path, strict=False)
            except FileFormatError as exc:
                problem = f"cannot open the capture: {exc}"
                logger.warning("%s", problem)
    if capture is not None:
        traj.check_cameras(capture, traj_path)
    else:
        problem = f"{work / 'work.toml'} does not exist"

    labels, names, source = None, [], ""
    labels_path, smap_path = work / "labels.npz", work / "semantic_map.npz"
    if cfg.colors in ("auto", "labels") and labels_path.is_file():
        from ..npzfile import load_npz

        z = load_npz(labels_path, ("labels", "class_names"), "a labels file")
        labels = np.asarray(z["labels"], np.int64)
        names = [str(s) for s in z["class_names"]]
        source = "labels.npz"
        inputs.append(labels_path)
    elif cfg.colors == "labels":
        raise FileFormatError(labels_path, "no such file (run `pointtraj label` first)")
    if labels is None and cfg.colors in ("auto", "semantic_map"):
        if smap_path.is_file():
            from ..semantics.semantic_map import SemanticMap

            smap = SemanticMap.load(smap_path)
            labels, names = smap.argmax_labels(), list(smap.class_names)
            source = "semantic_map.npz (argmax)"
            inputs.append(smap_path)
        elif cfg.colors == "semantic_map":
            raise FileFormatError(smap_path, "no such file (run `pointtraj semantics` first)")
    if labels is None and cfg.colors == "grey":
        labels, source = np.full(M, -1, np.int64), "grey"
    if labels is None:
        raise FileFormatError(
            work,
            "not labelled: no labels.npz or semantic_map.npz (run `pointtraj semantics` and "
            "`pointtraj label`, or render with --colors grey)",
        )
    if labels.shape != (M,):
        raise FileFormatError(
            inputs[-1], f"has {labels.shape[0]} labels, trajectories.npz has {M} trajectories"
        )
    if capture is not None:
        # rig.toml places the cameras; capture.toml's fps and up change captions and views.
        inputs += [p for n in ("rig.toml", "capture.toml") if (p := capture.path / n).is_file()]
    label_set = None
    if capture is not None and capture.labels_path is not None:
        label_set = LabelSet.load(capture.labels_path)
        if source != "grey":
            made = labels_path if source == "labels.npz" else smap_path
            check_class_names(capture.labels_path, label_set.names, made, names)
        inputs.append(capture.labels_path)
    palette = class_palette(names, label_set)
    if cfg.color_by == "instance":  # the person ids take the place of the classes
        labels, names, palette = _person_colors(labels_path, source, M)
    drawn = traj.lengths >= cfg.min_length  # (M,)
    if not cfg.unlabelled:
        drawn &= (labels >= 0) & (labels < len(names))
    if not drawn.all():
        if not drawn.any():
            raise ValidationError("nothing to render: no trajectory is labelled and long enough")
        keep = np.flatnonzero(drawn)
        traj, labels = traj.subset(keep), labels[keep]
    return _Scene(traj, labels, names, palette, source, inputs, capture, problem)


def _resolve_frames(
    spec: tuple[int | None, int | None] | None, traj: Trajectories, stride: int
) -> range:
    T = traj.num_frames
    if traj.num_trajectories == 0:
        raise ValidationError("the trajectory store is empty: nothing to render")
    if spec is None:
        return range(int(traj.first_frame.min()), int(traj.last_frame.max()) + 1, stride)
    a, b = (d if v is None else int(v) + T if int(v) < 0 else int(v) for v, d in zip(spec, (0, T)))
    if not 0 <= a < b <= T:
        text = ":".join("" if v is None else str(v) for v in spec)
        raise ValidationError(
            f"frames {text} is not a non-empty range within the store's frames 0:{T}"
        )
    return range(a, b, stride)


def _nice_step(x: float) -> float:
    """The largest of 1, 2, 2.5, 5 times a power of ten not above ``x``."""
    p = 10.0 ** math.floor(math.log10(x))
    return max(m * p for m in (1, 2, 2.5, 5) if m * p <= x * (1 + 1e-9))


@dataclass
class _Stage:
    """Where the orbit camera goes and where the floor is."""

    center: np.ndarray  # (3,)
    up: np.ndarray  # (3,)
    distance: float
    azimuth0_deg: float
    grid: np.ndarray  # (S, 2, 3)


def _stage(
    traj: Trajectories,
    rig: CameraRig | None,
    cfg: RenderConfig,
    capture_up: np.ndarray | None = None,
) -> _Stage:
    """The orbit's centre, axis and distance and the floor grid, all from the scene's own
    scale (a room or a 1 cm subject), about the up direction of ``cfg.up``, else
    ``capture_up`` (capture.toml), else detected from ``rig`` (:func:`resolve_up`)."""
    if cfg.up == "auto" and capture_up is not None:
        up, how = np.asarray(capture_up, float), "capture.toml up"
    else:
        up, how = resolve_up(cfg.up, rig, "[render] up")
    # A guess that failed (no direction, or no sign) is a warning: the grid may be wrong.
    log = logger.warning if "set up to choose" in how else logger.info
    log("render: up = (%.3f, %.3f, %.3f), from %s", *up, how)
    xyz = traj.xyz
    xyz = xyz[:: max(1, len(xyz) // 400_000)]
    xyz = xyz[np.isfinite(xyz).all(axis=1)].astype(np.float64)
    if len(xyz) == 0:
        raise ValidationError("the trajectory store has no finite positions")
    # Robust framing: the median point, and the radius holding 95% of the points (x 1.1).
    center = np.median(xyz, axis=0)
    extent = 1.1 * float(np.percentile(np.linalg.norm(xyz - center, axis=1), 95))
    if not extent > 1e-9:  # one point, or all at one place: a tenth of the rig's distance
        far = np.linalg.norm(rig.C - center, axis=1) if rig is not None else np.zeros(0)
        extent = 0.1 * float(np.median(far)) if len(far) and np.median(far) > 0 else 0.1
    if cfg.orbit_center is not None:
        center = np.asarray(cfg.orbit_center, float)
    w, h = cfg.size
    half_h = math.radians(cfg.orbit_fov_deg) / 2
    half_v = math.atan(math.tan(half_h) * h / w)
    distance = cfg.orbit_distance or extent / math.sin(min(half_h, half_v))
    _, e1, e2 = plane_basis(up)
    az0 = 0.0
    if rig is not None:
        v = rig.C[0] - center
        az0 = math.degrees(math.atan2(v @ e2, v @ e1))
    floor_h = float(np.percentile(xyz @ up, 1))
    floor_c = center + (floor_h - center @ up) * up
    half = 1.25 * extent
    spacing = _nice_step(half / 3)
    grid = floor_grid(floor_c, up, math.ceil(half / spacing - 1e-9) * spacing, spacing)
    return _Stage(center, up, distance, az0, grid)


def _orbit_camera(stage: _Stage, cfg: RenderConfig, t: int) -> Camera:
    el = math.radians(cfg.orbit_elevation_deg)
    az = stage.azimuth0_deg + cfg.orbit_start_deg + cfg.orbit_deg_per_frame * t
    return orbit_cameras(
        stage.center,
        stage.distance * math.cos(el),
        stage.distance * math.sin(el),
        1,
        size=cfg.size,
        fov_deg=cfg.orbit_fov_deg,
        start_deg=az,
        up=stage.up,
    )[0].with_name(ORBIT)


#: Frames sampled to place the legend of an output.
_LEGEND_SAMPLES = 16


def _legend_origin(
    traj: Trajectories,
    names: list[str],
    cfg: RenderConfig,
    stage: _Stage | None,
    rig: CameraRig | None,
    kind: str,
    name: str,
) -> tuple[int, int]:
    """Where one output's legend goes: the corner covering the fewest points drawn (the
    subject), over up to :data:`_LEGEND_SAMPLES` frames spread over the store's frames (not the
    range rendered, so that runs over different ranges agree), the same in every frame so that
    it does not jump in the video."""
    if cfg.legend_corner != "auto":
        size = cfg.size if name == ORBIT else rig[name].size
        return legend_origin(size, names, cfg.legend_corner)
    alive = range(int(traj.first_frame.min()), int(traj.last_frame.max()) + 1)
    pixels = []
    for t in alive[:: max(1, -(-len(alive) // _LEGEND_SAMPLES))]:
        cam = _orbit_camera(stage, cfg, t) if name == ORBIT else rig[name]
        fs = traj.frame(t)
        xyz = fs.xyz
        if kind == "overlay" and name in traj.camera_names:
            xyz = xyz[fs.visibility[:, traj.camera_names.index(name)] > 0.5]
        proj = CameraRig([cam]).project(xyz)
        pixels.append(proj.pixels[0][proj.in_image[0]])
    size = cfg.size if name == ORBIT else rig[name].size
    radius = cfg.overlay_radius if kind == "overlay" else cfg.point_size / 2
    return legend_origin(
        size, names, "auto", np.concatenate(pixels) if pixels else None, radius=radius
    )


def _person_colors(path: Path, source: str, M: int) -> tuple[np.ndarray, list[str], np.ndarray]:
    """For ``color_by = "instance"``: the person id per trajectory, names and palette.

    Raises
    ------
    FileFormatError
        If the colours do not come from ``labels.npz`` or it has no ``instance``.
    """
    from ..npzfile import load_npz
    from .palette import person_palette

    if source != "labels.npz":
        raise FileFormatError(path, "no such file (color_by = 'instance' needs `pointtraj label`)")
    z = load_npz(path, ("labels",), "a labels file")
    if "instance" not in z:
        raise FileFormatError(path, "has no instance (rerun `pointtraj label`)")
    instance = np.asarray(z["instance"], np.int64)
    if instance.shape != (M,):
        raise FileFormatError(path, f"has {instance.shape[0]} instances, trajectories.npz {M}")
    n = int(instance.max(initial=-1)) + 1
    return instance, [f"person {i}" for i in range(n)], person_palette(n)


def _settings(kind: str, name: str, scene: _Scene, cfg: RenderConfig) -> dict:
    """What the images of one output depend on; a change makes its frames stale."""
    inputs = [
        {"path": str(p.resolve()), "bytes": p.stat().st_size, "mtime_ns": p.stat().st_mtime_ns}
        for p in scene.inputs
    ]
    keys = [
        "tail",
        "colors",
        "color_by",
        "min_length",
        "unlabelled",
        "legend",
        "legend_corner",
        "caption",
    ]
    if kind == "overlay":
        keys += ["overlay_radius"]
    else:
        keys += ["engine", "tail_fade", "point_size", "line_width", "background", "floor", "up"]
        if name == ORBIT:
            keys += ["size"] + [
                f.name for f in dataclasses.fields(cfg) if f.name.startswith("orbit_")
            ]
    values = {k: getattr(cfg, k) for k in keys}
    return json.loads(
        json.dumps(
            {"version": _PARAMS_VERSION, "kind": kind, "view": name, **values, "inputs": inputs}
        )
    )


def _prepare_folder(folder: Path, settings: dict, owned: set[Path] | None = None) -> bool:
    """Make ``folder``; if its frames were made with other settings, delete them.

    ``owned``: the files pointtraj wrote (the work folder's manifest); when given, only those
    frames are deleted. Returns True when existing frames are up to date (may be kept).
    """
    marker = folder / "render.json"
    old = None
    if marker.is_file():
        with contextlib.suppress(OSError, ValueError):
            old = json.loads(marker.read_text(encoding="utf-8"))
    if old == settings:
        return True
    stale = [p for p in folder.glob("*.png") if _FRAME_PNG.match(p.name)] if folder.is_dir() else []
    if owned is not None:
        stale = [p for p in stale if p.resolve() in owned]
    if stale:
        logger.info("%s: settings or inputs changed; deleting %d old frames", folder, len(stale))
        for p in stale:
            p.unlink()
    folder.mkdir(parents=True, exist_ok=True)
    write_text_atomic(marker, json.dumps(settings, indent=1) + "\n")
    return False


@dataclass(frozen=True)
class _DrawJob:
    """What drawing any frame of a render needs (sent once to each worker)."""

    traj: Trajectories
    colors: np.ndarray  # (M, 3) uint8
    cfg: RenderConfig
    rig: CameraRig | None
    stage: _Stage | None
    capture: Capture | None  # pickled once to each worker, which reads its own files
    legend_names: tuple[str, ...]
    legend_colors: np.ndarray  # (L, 3) uint8
    base_fps: float
    grid_color: np.ndarray  # (3,) uint8
    bg: np.ndarray  # (3,) uint8
    legend_origins: dict[tuple[str, str], tuple[int, int]] = field(default_factory=dict)


def _draw_frame(
    job: _DrawJob, kind: str, name: str, t: int, renderer: TrajectoryRenderer | None
) -> np.ndarray:
    """Frame ``t`` of one output (a view or an overlay), annotated: (H, W, 3) uint8."""
    cfg = job.cfg

    def annotate(img: np.ndarray, label: str) -> np.ndarray:
        if cfg.legend:
            origin = job.legend_origins.get((kind, name), (10, 10))
            img = draw_legend(img, list(job.legend_names), job.legend_colors, origin=origin)
        if cfg.caption:
            img = draw_caption(img, f"{label}   frame {t}   {t / job.base_fps:.2f} s")
        return img

    if kind == "overlay":
        img = draw_overlay(
            job.capture.read(name, t),
            job.rig[name],
            job.traj,
            t,
            job.colors,
            cfg.tail,
            cfg.overlay_radius,
        )
        return annotate(img, f"{name} overlay")
    cam = _orbit_camera(job.stage, cfg, t) if name == ORBIT else job.rig[name]
    pts, pc, seg, sc = frame_geometry(job.traj, t, job.colors, cfg.tail, cfg.tail_fade, job.bg)
    if cfg.floor:
        seg = np.concatenate([job.stage.grid.astype(np.float32), seg])
        sc = np.concatenate([np.tile(job.grid_color, (len(job.stage.grid), 1)), sc])
    if renderer is not None:
        img = renderer.render(cam, pts, pc, seg, sc)
    else:
        canvas = np.empty((cam.height, cam.width, 3), np.uint8)
        canvas[:] = job.bg
        img = draw_scene(
            canvas,
            cam,
            pts,
            pc,
            seg,
            sc,
            radius=int(round((cfg.point_size - 1) / 2)),
            line_width=max(1, int(round(cfg.line_width))),
        )
    return annotate(img, name)


def _draw_task(
    job: _DrawJob,
    item: tuple[str, str, tuple[int, ...], tuple[Path, ...], bool],
    renderer: TrajectoryRenderer | None = None,
) -> list[tuple[np.ndarray | None, float]]:
    """Draw frames of one output and write their PNGs atomically (a task of
    :func:`render_work`).

    Parameters
    ----------
    job : _DrawJob
    item : (kind, name, frames, paths, want_images)
    renderer : TrajectoryRenderer, optional
        The output's renderer, here. On a worker (None) an Open3D view gets a renderer made and
        closed by this task, in the task's thread (Filament aborts a process that ends with a
        renderer open, or closes it from another thread).

    Returns
    -------
    list of (image, seconds)
        Per frame, the (H, W, 3) uint8 image if ``want_images`` (for the video), else None, and
        the seconds spent drawing and writing it.
    """
    kind, name, frames, paths, want_images = item
    own = None
    if renderer is None and kind == "view" and job.cfg.engine == "open3d":
        cfg = job.cfg
        size = cfg.size if name == ORBIT else job.rig[name].size
        renderer = own = TrajectoryRenderer(
            size, cfg.point_size, cfg.line_width, tuple(job.bg / 255.0)
        )
    try:
        out = []
        for t, path in zip(frames, paths, strict=True):
            t0 = time.perf_counter()
            img = _draw_frame(job, kind, name, t, renderer)
            write_png(path, img)
            out.append(((img if want_images else None), time.perf_counter() - t0))
        return out
    finally:
        if own is not None:
            own.close()


#: Frames per render task on a cluster: at most this many (the images come back together).
_FRAMES_PER_TASK = 8


@locked("pointtraj render")
def render_work(
    work: str | os.PathLike,
    config: RenderConfig | None = None,
    *,
    force: bool = False,
    progress: Callable[[str, int, int], None] | None = None,
    executor: Executor | None = None,
) -> RenderResult:
    """Render a work folder's semantic trajectories into ``WORK/renders/``.

    Draws, per frame, the points alive coloured by label with the last ``tail`` frames of
    each trajectory as tails (the paper's figures), from the orbiting virtual camera and/or rig
    cameras, and over the input camera images (overlays). Writes
    ``renders/views/<view>/<t:06d>.png`` and ``renders/views/<view>.mp4`` per view,
    ``renders/overlays/<camera>/<t:06d>.png`` and ``.mp4`` per overlay camera, and
    ``renders/legend.png``, all atomically. Frames already rendered with the same settings and
    inputs are kept (a rerun resumes); a folder whose ``render.json`` differs is re-rendered.

    Parameters
    ----------
    work : path-like
        The work folder (``trajectories.npz``, ``labels.npz`` or ``semantic_map.npz``, and
        ``work.toml`` naming the capture, which rig-camera views and overlays need).
    config : RenderConfig, optional
    force : bool
        Re-render frames even when they are up to date.
    progress : callable, optional
        ``progress(name, done, total)`` after each image; ``name`` is the output being drawn.
    executor : Executor, optional
        Where the frames are drawn and written (default: here, one after the other). On a
        Dask cluster each worker draws frames with its own off-screen renderer and writes
        their PNGs, which come back in order for the videos; the images are the same.

    Returns
    -------
    RenderResult

    Raises
    ------
    FileFormatError
        Missing or inconsistent inputs (no trajectories, no labels with ``colors="auto"``).
    ValidationError
        Unknown view or camera (the message lists the valid ones), a bad frame range, or a
        camera view or overlay without a readable capture.
    """
    start = time.perf_counter()
    cfg = config or RenderConfig()
    work = Path(work)
    scene = _load_scene(work, cfg)
    wf = WorkFolder(work)
    owned = wf.owned() if wf.has_manifest() else None
    traj, capture = scene.trajectories, scene.capture
    rig = capture.rig if capture is not None else None
    frames = _resolve_frames(cfg.frames, traj, cfg.stride)

    valid = [ORBIT, *(rig.names if rig is not None else [])]
    for v in (*cfg.views, *cfg.overlay_cameras):
        if v not in valid:
            if rig is None:
                raise ValidationError(
                    f"view {v!r} needs the capture's cameras, but {scene.capture_problem}"
                )
            raise ValidationError(f"unknown view or camera {v!r} (valid: {', '.join(valid)})")
    if ORBIT in cfg.overlay_cameras:
        raise ValidationError("overlay_cameras: 'orbit' has no camera images; name rig cameras")
    overlay_cams: tuple[str, ...] = ()
    if cfg.overlays:
        overlay_cams = cfg.overlay_cameras or tuple(v for v in cfg.views if v != ORBIT)
        if capture is None:
            logger.warning("no overlays: %s", scene.capture_problem)
            overlay_cams = ()
        elif not overlay_cams:
            overlay_cams = (rig.names[0],)
        if not overlay_cams and not cfg.views:
            raise ValidationError(
                f"nothing to render: overlays need the capture, but {scene.capture_problem}"
            )
        if overlay_cams and frames[-1] >= capture.num_frames:
            raise ValidationError(
                f"frames: {frames.start}:{frames.stop} goes past the capture's "
                f"{capture.num_frames} frames"
            )

    labels = scene.labels
    colors = label_colors(labels, scene.palette)  # (M, 3)
    bg = np.array(cfg.background, np.uint8)
    # The legend lists the classes drawn, in class order, then "unlabelled".
    K = len(scene.class_names)
    present = np.unique(labels[(labels >= 0) & (labels < K)])
    legend_names = [scene.class_names[k] for k in present]
    legend_colors = scene.palette[present].reshape(-1, 3)
    if np.any((labels < 0) | (labels >= K)):
        legend_names.append("no person" if cfg.color_by == "instance" else "unlabelled")
        legend_colors = np.vstack([legend_colors, [UNLABELLED_COLOR]]).astype(np.uint8)

    renders = work / "renders"
    legend_path = renders / "legend.png"
    write_png(legend_path, legend_image(legend_names, legend_colors))

    stage = (
        _stage(traj, rig, cfg, capture.up if capture is not None else None) if cfg.views else None
    )
    # The floor grid: 16% of the way from the background to black (to white on dark ones).
    grid_color = blend_colors(bg[None], np.full(3, 255 if bg.mean() < 128 else 0), 0.16)[0]
    base_fps = capture.fps if capture is not None else traj.fps
    fps = cfg.fps or base_fps / cfg.stride

    legend_origins = {}
    if cfg.legend:
        for kind, name in [("view", v) for v in cfg.views] + [("overlay", c) for c in overlay_cams]:
            legend_origins[kind, name] = _legend_origin(
                traj, legend_names, cfg, stage, rig, kind, name
            )
    job = _DrawJob(
        traj=traj,
        colors=colors,
        cfg=cfg,
        rig=rig,
        stage=stage,
        capture=capture,
        legend_names=tuple(legend_names),
        legend_colors=legend_colors,
        base_fps=float(base_fps),
        grid_color=grid_color,
        bg=bg,
        legend_origins=legend_origins,
    )
    remote = executor is not None and not executor.local

    outputs = [
        RenderOutput(
            "view",
            v,
            renders / "views" / v,
            None,
            cfg.size if v == ORBIT else rig[v].size,
        )
        for v in cfg.views
    ] + [
        RenderOutput("overlay", c, renders / "overlays" / c, None, rig[c].size)
        for c in overlay_cams
    ]
    total = len(frames) * len(outputs)
    done = 0

    for out in outputs:
        fresh = _prepare_folder(out.folder, _settings(out.kind, out.name, scene, cfg), owned)
        renderer = None
        if not remote and out.kind == "view" and cfg.engine == "open3d":
            renderer = TrajectoryRenderer(
                out.size, cfg.point_size, cfg.line_width, tuple(bg / 255.0)
            )

        def draw(t: int, path: Path, out: RenderOutput = out, renderer=renderer) -> np.ndarray:
            """Draw and write frame t here, or on the executor's worker."""
            item = (out.kind, out.name, (t,), (path,), True)
            if remote:
                [(img, seconds)] = next(executor.map(_draw_task, [item], context=job))
            else:
                [(img, seconds)] = _draw_task(job, item, renderer)
            out.render_seconds += seconds
            return img

        def images(out: RenderOutput = out, draw=draw, fresh: bool = fresh) -> Iterator[np.ndarray]:
            nonlocal done
            paths = {t: out.folder / f"{t:06d}.png" for t in frames}
            keep = {t: fresh and not force and paths[t].is_file() for t in frames}
            ahead = None
            if remote:  # the frames to draw go to the workers now, and come back in order
                todo = [t for t in frames if not keep[t]]
                n = max(1, min(_FRAMES_PER_TASK, -(-len(todo) // (4 * executor.workers))))
                chunks = [todo[k : k + n] for k in range(0, len(todo), n)]
                ahead = itertools.chain.from_iterable(
                    executor.map(
                        _draw_task,
                        [
                            (out.kind, out.name, tuple(c), tuple(paths[t] for t in c), cfg.video)
                            for c in chunks
                        ],
                        label=f"{out.kind} {out.name}",
                        context=job,
                    )
                )
            for t in frames:
                img = None
                kept = keep[t]
                if kept and cfg.video:
                    try:
                        img = read_png(paths[t])
                    except FileFormatError:
                        kept = False
                if kept:
                    out.skipped += 1
                else:
                    if ahead is not None and not keep[t]:
                        img, seconds = next(ahead)
                        out.render_seconds += seconds
                    else:
                        img = draw(t, paths[t])
                    out.rendered += 1
                done += 1
                if progress is not None:
                    progress(f"{out.kind} {out.name}", done, total)
                if img is not None:
                    yield img

        try:
            if cfg.video:
                out.video = out.folder.parent / f"{out.folder.name}.mp4"
                write_video(out.video, images(), fps)
            else:
                for _ in images():
                    pass
        finally:
            if renderer is not None:
                renderer.close()
        logger.info(
            "%s %s: %d frames rendered, %d kept -> %s",
            out.kind,
            out.name,
            out.rendered,
            out.skipped,
            out.folder,
        )
    return RenderResult(
        folder=renders,
        outputs=outputs,
        legend=legend_path,
        frames=frames,
        color_source=scene.source,
        num_trajectories=traj.num_trajectories,
        classes=legend_names,
        seconds=time.perf_counter() - start,
    )
