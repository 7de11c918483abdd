"""Rendering semantic trajectories: Open3D off-screen views, OpenCV drawing, and ``renders/``.

Two engines draw the same thing, the points alive at frame t coloured by label with the last
``tail`` frames of each trajectory as a polyline (the paper's figures):

- ``open3d``: :class:`TrajectoryRenderer` uses ``open3d.visualization.rendering.OffscreenRenderer``
  (Filament through Vulkan; on a machine without a GPU it runs on Mesa's llvmpipe, which needs the
  Debian packages ``libvulkan1 mesa-vulkan-drivers``). Post-processing is off so label colours
  stay exact. Lens distortion is ignored (pinhole views). Only one renderer may be open at a time
  in a process: Filament aborts the process when a second one is destroyed.
- ``opencv``: :func:`draw_scene` projects with the full camera model (distortion included) and
  draws with ``cv2.polylines`` and a depth-sorted disc splat: 10-30x faster, for long videos and
  overlays on the input images (:func:`draw_overlay`).

:func:`render_work` renders a labelled work folder into ``WORK/renders/`` (PNG frames and an MP4
per view, overlays on the camera images, a legend), resuming where a previous run stopped; see
``data_specs/work_folder.md``.
"""

from __future__ import annotations

import colorsys
import contextlib
import dataclasses
import json
import logging
import math
import os
import re
import sys
import tempfile
import time
import weakref
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Literal

import numpy as np

from .atomic import atomic_path, write_text_atomic
from .camera import Camera, CameraRig
from .errors import FileFormatError, ValidationError, WriteError
from .trajectories import Trajectories
from .workdir import WorkFolder, locked

if TYPE_CHECKING:
    from .labelset import LabelSet
    from .session import Capture

__all__ = [
    "RenderConfig",
    "RenderOutput",
    "RenderResult",
    "render_work",
    "TrajectoryRenderer",
    "tail_segments",
    "draw_scene",
    "draw_overlay",
    "draw_legend",
    "draw_caption",
    "legend_image",
    "floor_grid",
    "orbit_cameras",
    "label_colors",
    "class_palette",
    "read_png",
    "write_png",
    "write_video",
]

logger = logging.getLogger(__name__)

#: Colour of unlabelled trajectories (label -1).
UNLABELLED_COLOR = (128, 128, 128)

#: The view name of the orbiting virtual camera.
ORBIT = "orbit"

#: Text colour of legends and captions.
_TEXT_COLOR = (30, 30, 30)

#: Version of the ``render.json`` written beside each folder of frames.
_PARAMS_VERSION = 1

_FRAME_PNG = re.compile(r"^\d{6}\.png$")


# -- colours -------------------------------------------------------------------------------------
def label_colors(labels: np.ndarray, palette: np.ndarray) -> np.ndarray:
    """Per-trajectory RGB colours from labels.

    Parameters
    ----------
    labels : (M,) int ndarray
        Class index per trajectory; -1 (or any out-of-range value) is unlabelled.
    palette : (K, 3) uint8 ndarray
        Colour per class.

    Returns
    -------
    (M, 3) uint8 ndarray
    """
    labels = np.asarray(labels, dtype=np.int64)
    palette = np.asarray(palette, dtype=np.uint8)
    ok = (labels >= 0) & (labels < len(palette))
    out = np.empty((len(labels), 3), np.uint8)
    out[:] = UNLABELLED_COLOR
    out[ok] = palette[labels[ok]]
    return out


def class_palette(class_names: Sequence[str], label_set: LabelSet | None = None) -> np.ndarray:
    """Display colour of each class, looked up by name.

    Parameters
    ----------
    class_names : sequence of K str
        Classes in class-index order (for example ``labels.npz`` ``class_names``).
    label_set : LabelSet, optional
        The capture's label set (``labels.toml``). Names it lacks take the colour of
        :meth:`LabelSet.default`, else a distinct generated colour.

    Returns
    -------
    (K, 3) uint8 ndarray
    """
    from .labelset import LabelSet

    sets = [s for s in (label_set, LabelSet.default()) if s is not None]
    out = np.empty((len(class_names), 3), np.uint8)
    for k, name in enumerate(class_names):
        for s in sets:
            if name in s.names:
                out[k] = s.colors[s.names.index(name)]
                break
        else:
            # Golden-ratio hues: distinct, deterministic colours for unknown classes.
            r, g, b = colorsys.hsv_to_rgb((0.13 + 0.618034 * k) % 1.0, 0.75, 0.9)
            out[k] = np.rint(np.array([r, g, b]) * 255)
    return out


def _blend(colors: np.ndarray, target: np.ndarray, weight: np.ndarray | float) -> np.ndarray:
    """``colors + weight (target - colors)``, rounded to uint8; ``weight`` (S,) or scalar."""
    c = np.asarray(colors, np.float64)
    w = np.asarray(weight, np.float64)
    if w.ndim == 1:
        w = w[:, None]
    return np.rint(c + (np.asarray(target, np.float64) - c) * w).astype(np.uint8)


# -- geometry ------------------------------------------------------------------------------------
def tail_segments(
    trajectories: Trajectories, t: int, tail: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Line segments of the last ``tail`` frames of the trajectories alive at frame ``t``.

    Parameters
    ----------
    trajectories : Trajectories
    t : int
        Current frame.
    tail : int
        Number of past frames drawn (0 draws none).

    Returns
    -------
    segments : (S, 2, 3) float32 ndarray
        Start and end of each segment, world coordinates; a segment joins frames f and f + 1
        of one trajectory, ``t - tail <= f < t``.
    track : (S,) int64 ndarray
        Trajectory of each segment.
    age : (S,) int64 ndarray
        ``t - f``, from 1 (the segment ending at frame t) to ``tail``.
    """
    if tail <= 0:
        return np.zeros((0, 2, 3), np.float32), np.zeros(0, np.int64), np.zeros(0, np.int64)
    alive = np.zeros(trajectories.num_trajectories, bool)
    alive[trajectories.row_track[trajectories.frame_rows(t)]] = True
    frames = range(max(0, t - tail), t)
    rows = np.concatenate([trajectories.frame_rows(f) for f in frames] or [np.zeros(0, np.int64)])
    track = trajectories.row_track[rows]
    # A row and the next one belong to the same trajectory unless it ends there.
    keep = alive[track] & (rows + 1 < trajectories.offsets[track + 1])
    rows, track = rows[keep], track[keep]
    seg = np.stack([trajectories.xyz[rows], trajectories.xyz[rows + 1]], axis=1)  # (S, 2, 3)
    return seg, track, t - trajectories.row_frame[rows]


def _frame_geometry(
    trajectories: Trajectories,
    t: int,
    colors: np.ndarray,
    tail: int,
    fade: float = 0.0,
    background: Sequence[int] = (255, 255, 255),
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Frame t's points and tails with their colours; tails fade towards ``background``.

    Returns
    -------
    points : (N, 3) float32, point_colors : (N, 3) uint8,
    segments : (S, 2, 3) float32, segment_colors : (S, 3) uint8
    """
    fs = trajectories.frame(t)
    seg, track, age = tail_segments(trajectories, t, tail)
    seg_col = colors[track]
    if fade > 0 and tail > 1 and len(seg):
        # The newest segment keeps the label colour; the oldest moves ``fade`` of the way.
        seg_col = _blend(seg_col, background, fade * (age - 1) / (tail - 1))
    return fs.xyz, colors[fs.track_id], seg, seg_col


def _plane_basis(up: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit ``up`` and two unit vectors spanning the plane perpendicular to it (right-handed)."""
    u = np.asarray(up, float)
    u = u / np.linalg.norm(u)
    for axis in (np.array([1.0, 0, 0]), np.array([0, 1.0, 0])):
        e1 = axis - (axis @ u) * u
        if np.linalg.norm(e1) > 1e-6:
            break
    e1 /= np.linalg.norm(e1)
    return u, e1, np.cross(u, e1)


def floor_grid(
    center: Iterable[float],
    up: Iterable[float],
    half_size: float,
    spacing: float,
    piece: float | None = None,
) -> np.ndarray:
    """Segments of a square grid in the plane through ``center`` perpendicular to ``up``.

    Each grid line is cut into pieces of length ``piece`` so that a camera that sees only part
    of a line still draws that part (the OpenCV engine drops segments leaving the image).

    Parameters
    ----------
    center : (3,) array-like
        Centre of the grid (world, metres).
    up : (3,) array-like
        Normal of the grid plane.
    half_size : float
        Half the side of the square.
    spacing : float
        Distance between grid lines.
    piece : float, optional
        Length of the pieces (default ``spacing / 4``).

    Returns
    -------
    (S, 2, 3) float64 ndarray
    """
    if half_size <= 0 or spacing <= 0:
        raise ValidationError(
            f"floor_grid: half_size and spacing must be positive, got {half_size}, {spacing}"
        )
    c = np.asarray(list(center), float)
    _, e1, e2 = _plane_basis(np.asarray(list(up), float))
    n = int(math.floor(half_size / spacing + 1e-9))
    ticks = np.arange(-n, n + 1) * spacing  # (L,)
    m = max(1, int(math.ceil(2 * half_size / (piece or spacing / 4))))
    s = np.linspace(-half_size, half_size, m + 1)  # (m + 1,)
    segs = []
    for a, b in ((e1, e2), (e2, e1)):
        pts = c + s[None, :, None] * a + ticks[:, None, None] * b  # (L, m + 1, 3)
        segs.append(np.stack([pts[:, :-1], pts[:, 1:]], axis=2).reshape(-1, 2, 3))
    return np.concatenate(segs)


def orbit_cameras(
    center: Iterable[float],
    radius: float,
    height: float,
    n: int,
    size: tuple[int, int] = (1280, 1024),
    fov_deg: float = 50.0,
    start_deg: float = 0.0,
    sweep_deg: float = 360.0,
    up: Iterable[float] = (0.0, 0.0, 1.0),
) -> CameraRig:
    """Virtual cameras on a circle around ``center``, looking at it.

    Parameters
    ----------
    center : (3,) array-like
        Point looked at (world, metres).
    radius, height : float
        Circle radius and height above ``center`` (along ``up``).
    n : int
        Number of views.
    size : (int, int)
        Image (width, height).
    fov_deg : float
        Horizontal field of view.
    start_deg, sweep_deg : float
        First azimuth and the angle swept by the ``n`` views. Azimuth 0 is the direction of
        world x projected on the plane perpendicular to ``up`` (of y if up is x).
    up : (3,) array-like
        World up direction; it points up in the images.

    Returns
    -------
    CameraRig
        Cameras named ``orbit000``, ``orbit001``, ...
    """
    if n < 1:
        raise ValidationError(f"orbit_cameras: n must be at least 1, got {n}")
    c = np.asarray(list(center), dtype=float)
    u, e1, e2 = _plane_basis(np.asarray(list(up), float))
    focal = size[0] / 2 / np.tan(np.radians(fov_deg) / 2)
    step = sweep_deg / n if abs(sweep_deg) >= 360 else sweep_deg / max(n - 1, 1)
    az = np.radians(start_deg + step * np.arange(n))
    cams = [
        Camera.look_at(
            f"orbit{i:03d}",
            c + radius * (np.cos(a) * e1 + np.sin(a) * e2) + height * u,
            c,
            size,
            focal,
            up=u,
        )
        for i, a in enumerate(az)
    ]
    return CameraRig(cams)


# -- Open3D engine -------------------------------------------------------------------------------
@contextlib.contextmanager
def _native_output_to_log(what: str) -> Iterator[None]:
    """Send what native code prints on file descriptors 1 and 2 to the debug log.

    Filament prints a banner on stdout when an engine starts; this keeps CLI output clean.
    """
    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(1), os.dup(2)]
    with tempfile.TemporaryFile() as tmp:
        try:
            os.dup2(tmp.fileno(), 1)
            os.dup2(tmp.fileno(), 2)
            yield
        finally:
            with contextlib.suppress(Exception):
                import ctypes

                ctypes.CDLL(None).fflush(None)  # flush C stdio buffers into the temp file
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            for fd in saved:
                os.close(fd)
            tmp.seek(0)
            text = tmp.read().decode("utf-8", "replace").strip()
    if text:
        logger.debug("%s printed:\n%s", what, text)


_open_renderer: weakref.ref | None = None


class TrajectoryRenderer:
    """Off-screen Open3D renderer of labelled trajectories, reused across frames.

    Only one may be open at a time in a process (Filament aborts when a second off-screen renderer
    is destroyed); use it as a context manager, or :meth:`close` it, before making another.

    Parameters
    ----------
    size : (int, int)
        Image (width, height); every view must have this size.
    point_size : float
        Point size in pixels.
    line_width : float
        Tail width in pixels.
    background : (3,) float
        Background RGB in [0, 1].

    Raises
    ------
    ValidationError
        If another renderer is open.
    """

    def __init__(
        self,
        size: tuple[int, int],
        point_size: float = 3.0,
        line_width: float = 1.5,
        background: tuple[float, float, float] = (1.0, 1.0, 1.0),
    ) -> None:
        global _open_renderer
        self._renderer = None
        other = _open_renderer() if _open_renderer is not None else None
        if other is not None and other._renderer is not None:
            raise ValidationError(
                "another TrajectoryRenderer is open; close() it before making a new one "
                "(Filament aborts when a second off-screen renderer is destroyed)"
            )
        from open3d.visualization import rendering

        self.size = (int(size[0]), int(size[1]))
        with _native_output_to_log("open3d OffscreenRenderer"):
            self._renderer = rendering.OffscreenRenderer(*self.size)
        _open_renderer = weakref.ref(self)
        scene = self._renderer.scene
        scene.set_background([*background, 1.0])
        scene.view.set_post_processing(False)  # keep label colours exact
        self._point_mat = rendering.MaterialRecord()
        self._point_mat.shader = "defaultUnlit"
        self._point_mat.point_size = float(point_size)
        self._line_mat = rendering.MaterialRecord()
        self._line_mat.shader = "unlitLine"
        self._line_mat.line_width = float(line_width)

    def close(self) -> None:
        """Release the renderer (its geometry first, as Filament requires). Idempotent."""
        if self._renderer is not None:
            self._renderer.scene.clear_geometry()
            self._renderer = None

    def __enter__(self) -> TrajectoryRenderer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:
        with contextlib.suppress(Exception):
            self.close()

    def render(
        self,
        camera: Camera,
        points: np.ndarray,
        point_colors: np.ndarray,
        segments: np.ndarray | None = None,
        segment_colors: np.ndarray | None = None,
    ) -> np.ndarray:
        """Render points and line segments seen from ``camera``.

        Parameters
        ----------
        camera : Camera
            The view; its image size must equal the renderer's. Distortion is ignored.
        points : (N, 3) float ndarray
        point_colors : (N, 3) uint8 ndarray
        segments : (S, 2, 3) float ndarray, optional
        segment_colors : (S, 3) uint8 ndarray, optional

        Returns
        -------
        (H, W, 3) uint8 ndarray
            RGB image.

        Raises
        ------
        ValidationError
            If the camera's size differs from the renderer's, or the renderer is closed.
        """
        import open3d as o3d

        if self._renderer is None:
            raise ValidationError("this TrajectoryRenderer is closed")
        if tuple(camera.size) != self.size:
            raise ValidationError(
                f"camera {camera.name!r} is {camera.size[0]}x{camera.size[1]}, "
                f"the renderer {self.size[0]}x{self.size[1]}"
            )
        scene = self._renderer.scene
        scene.clear_geometry()
        if len(points):
            pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, float)))
            pcd.colors = o3d.utility.Vector3dVector(np.asarray(point_colors, float) / 255.0)
            scene.add_geometry("points", pcd, self._point_mat)
        if segments is not None and len(segments):
            seg = np.asarray(segments, float).reshape(-1, 3)
            lines = o3d.geometry.LineSet(
                o3d.utility.Vector3dVector(seg),
                o3d.utility.Vector2iVector(np.arange(len(seg)).reshape(-1, 2)),
            )
            lines.colors = o3d.utility.Vector3dVector(np.asarray(segment_colors, float) / 255.0)
            scene.add_geometry("tails", lines, self._line_mat)
        extrinsic = np.eye(4)
        extrinsic[:3, :3] = camera.R
        extrinsic[:3, 3] = camera.t
        # setup_camera must come after add_geometry, or Filament renders a blank image.
        self._renderer.setup_camera(camera.K, extrinsic, *self.size)
        return np.asarray(self._renderer.render_to_image()).copy()

    def render_frame(
        self,
        trajectories: Trajectories,
        t: int,
        camera: Camera,
        colors: np.ndarray,
        tail: int = 10,
    ) -> np.ndarray:
        """Render frame ``t`` of ``trajectories`` with per-trajectory ``colors`` (M, 3) uint8."""
        pts, pc, seg, sc = _frame_geometry(trajectories, t, colors, tail)
        return self.render(camera, pts, pc, seg, sc)


# -- OpenCV engine -------------------------------------------------------------------------------
def draw_scene(
    image: np.ndarray,
    camera: Camera,
    points: np.ndarray,
    point_colors: np.ndarray,
    segments: np.ndarray | None = None,
    segment_colors: np.ndarray | None = None,
    *,
    radius: int = 2,
    line_width: int = 1,
) -> np.ndarray:
    """Draw points and line segments seen from ``camera`` over an image (OpenCV engine).

    Projection uses the full camera model, distortion included. Segments are drawn first,
    anti-aliased; a segment with an end outside the image or behind the camera is dropped.
    Points are discs, the nearest drawn last.

    Parameters
    ----------
    image : (H, W, 3) uint8 ndarray
        RGB image of ``camera`` (or a blank canvas of its size); not modified.
    camera : Camera
    points : (N, 3) float ndarray
    point_colors : (N, 3) uint8 ndarray
    segments : (S, 2, 3) float ndarray, optional
    segment_colors : (S, 3) uint8 ndarray, optional
    radius : int
        Point radius in pixels (0 draws single pixels).
    line_width : int
        Segment thickness in pixels.

    Returns
    -------
    (H, W, 3) uint8 ndarray
        A new image.
    """
    import cv2

    out = np.ascontiguousarray(image, dtype=np.uint8).copy()
    h, w = out.shape[:2]
    rig = CameraRig([camera])
    if segments is not None and len(segments):
        proj = rig.project(np.asarray(segments, float).reshape(-1, 3))
        pix = proj.pixels[0].reshape(-1, 2, 2)
        ok = proj.in_image[0].reshape(-1, 2).all(axis=1)
        seg_col = np.asarray(segment_colors, np.uint8)[ok]
        pts = np.rint(pix[ok] * 16).astype(np.int32)  # 4 bits of sub-pixel precision
        # One polylines call per colour: few calls, many segments each. Colours are drawn in
        # the order of their first segment, so earlier segments (a floor, old tails) go under.
        uniq, inv = np.unique(seg_col, axis=0, return_inverse=True)
        inv = inv.reshape(-1)
        first = np.full(len(uniq), len(inv))
        np.minimum.at(first, inv, np.arange(len(inv)))
        order = np.argsort(inv, kind="stable")
        bounds = np.searchsorted(inv[order], np.arange(len(uniq) + 1))
        for k in np.argsort(first):
            col = uniq[k]
            sel = order[bounds[k] : bounds[k + 1]]
            color = tuple(int(c) for c in col)
            cv2.polylines(out, list(pts[sel]), False, color, int(line_width), cv2.LINE_AA, 4)
    if len(points):
        proj = rig.project(np.asarray(points, float))
        ok = proj.in_image[0]
        far_first = np.argsort(-proj.depth[0][ok], kind="stable")
        pix = np.rint(proj.pixels[0][ok][far_first]).astype(np.int64)  # (N', 2)
        col = np.asarray(point_colors, np.uint8)[ok][far_first]
        r = max(int(radius), 0)
        dy, dx = np.mgrid[-r : r + 1, -r : r + 1]
        disc = (dx**2 + dy**2) <= r**2
        off = np.stack([dx[disc], dy[disc]], axis=1)  # (D, 2)
        # Point-major order, so a nearer point's disc overwrites a farther one's.
        q = (pix[:, None, :] + off[None]).reshape(-1, 2)  # (N' D, 2)
        c = np.repeat(col, len(off), axis=0)
        inside = (q[:, 0] >= 0) & (q[:, 0] < w) & (q[:, 1] >= 0) & (q[:, 1] < h)
        out[q[inside, 1], q[inside, 0]] = c[inside]
    return out


def draw_overlay(
    image: np.ndarray,
    camera: Camera,
    trajectories: Trajectories,
    t: int,
    colors: np.ndarray,
    tail: int = 10,
    radius: int = 2,
    visible_only: bool = True,
) -> np.ndarray:
    """Draw frame ``t``'s labelled points and tails over a camera image (OpenCV engine).

    Parameters
    ----------
    image : (H, W, 3) uint8 ndarray
        RGB image of ``camera`` (or a blank canvas of its size).
    camera : Camera
    trajectories : Trajectories
    t : int
    colors : (M, 3) uint8 ndarray
        Colour per trajectory.
    tail : int
        Past frames drawn as polylines.
    radius : int
        Point radius in pixels.
    visible_only : bool
        Draw only points (and their tails) whose stored visibility in this camera is above 0.5,
        when the store has this camera; otherwise every point in front of it.

    Returns
    -------
    (H, W, 3) uint8 ndarray
        A new image.
    """
    fs = trajectories.frame(t)
    keep = np.ones(len(fs.track_id), bool)
    if visible_only and camera.name in trajectories.camera_names:
        keep = fs.visibility[:, trajectories.camera_names.index(camera.name)] > 0.5
    seg, seg_track, _ = tail_segments(trajectories, t, tail)
    seg_keep = np.isin(seg_track, fs.track_id[keep])
    return draw_scene(
        image,
        camera,
        fs.xyz[keep],
        colors[fs.track_id[keep]],
        seg[seg_keep],
        colors[seg_track[seg_keep]],
        radius=radius,
    )


# -- annotations ---------------------------------------------------------------------------------
def _text_metrics(scale: float) -> tuple[int, int, int]:
    """Font thickness, text height and line pitch (pixels) at ``scale``."""
    import cv2

    thick = max(1, int(round(scale * 1.6)))
    (_, th), _ = cv2.getTextSize("Hg", cv2.FONT_HERSHEY_SIMPLEX, scale, thick)
    return thick, th, int(round(th * 1.9))


def _default_scale(height: int) -> float:
    return max(0.4, height / 1700)


def _legend_box(names: Sequence[str], scale: float) -> tuple[int, int]:
    import cv2

    thick, th, pitch = _text_metrics(scale)
    pad = max(4, th // 2)
    widths = [cv2.getTextSize(n, cv2.FONT_HERSHEY_SIMPLEX, scale, thick)[0][0] for n in names]
    return 3 * pad + th + max(widths, default=0), 2 * pad + pitch * len(names) - (pitch - th)


def draw_legend(
    image: np.ndarray,
    names: Sequence[str],
    colors: np.ndarray,
    *,
    origin: tuple[int, int] = (10, 10),
    scale: float | None = None,
) -> np.ndarray:
    """Draw a legend (a colour swatch and a name per class) in a light box.

    Entries that do not fit in the image height are replaced by a last line ``+N more``.

    Parameters
    ----------
    image : (H, W, 3) uint8 ndarray
        Not modified.
    names : sequence of n str
    colors : (n, 3) uint8 ndarray
        RGB colour per name.
    origin : (int, int)
        Top-left corner (x, y) of the box.
    scale : float, optional
        OpenCV font scale (default from the image height: 0.6 at 1024 rows, at least 0.4).

    Returns
    -------
    (H, W, 3) uint8 ndarray
    """
    import cv2

    out = np.ascontiguousarray(image, dtype=np.uint8).copy()
    names = list(names)
    colors = np.asarray(colors, np.uint8).reshape(-1, 3)
    if not names:
        return out
    h, w = out.shape[:2]
    scale = _default_scale(h) if scale is None else scale
    thick, th, pitch = _text_metrics(scale)
    pad = max(4, th // 2)
    x0, y0 = origin
    fit = max(1, (h - y0 - 2 * pad + (pitch - th)) // pitch)
    if len(names) > fit:
        more = len(names) - fit + 1
        names, colors = names[: fit - 1] + [f"+{more} more"], colors[: fit - 1]
    bw, bh = _legend_box(names, scale)
    x1, y1 = min(w, x0 + bw), min(h, y0 + bh)
    box = out[y0:y1, x0:x1].astype(np.float32)
    out[y0:y1, x0:x1] = np.rint(box * 0.2 + 255 * 0.8).astype(np.uint8)
    for i, name in enumerate(names):
        top = y0 + pad + i * pitch
        if i < len(colors):
            col = tuple(int(c) for c in colors[i])
            cv2.rectangle(out, (x0 + pad, top), (x0 + pad + th, top + th), col, -1)
            cv2.rectangle(out, (x0 + pad, top), (x0 + pad + th, top + th), _TEXT_COLOR, 1)
        org = (x0 + 2 * pad + th, top + th)
        cv2.putText(
            out, name, org, cv2.FONT_HERSHEY_SIMPLEX, scale, _TEXT_COLOR, thick, cv2.LINE_AA
        )
    return out


def legend_image(names: Sequence[str], colors: np.ndarray, scale: float = 0.7) -> np.ndarray:
    """A legend on its own, as an image just large enough for it.

    Parameters
    ----------
    names : sequence of n str
    colors : (n, 3) uint8 ndarray
    scale : float
        OpenCV font scale.

    Returns
    -------
    (H, W, 3) uint8 ndarray
    """
    bw, bh = _legend_box(list(names) or [""], scale)
    canvas = np.full((bh + 2, bw + 2, 3), 255, np.uint8)
    return draw_legend(canvas, names, colors, origin=(1, 1), scale=scale)


def draw_caption(image: np.ndarray, text: str, *, scale: float | None = None) -> np.ndarray:
    """Write one line of text in a light box at the bottom-left corner.

    Parameters
    ----------
    image : (H, W, 3) uint8 ndarray
        Not modified.
    text : str
    scale : float, optional
        OpenCV font scale (default from the image height).

    Returns
    -------
    (H, W, 3) uint8 ndarray
    """
    import cv2

    out = np.ascontiguousarray(image, dtype=np.uint8).copy()
    h, w = out.shape[:2]
    scale = _default_scale(h) if scale is None else scale
    thick, th, _ = _text_metrics(scale)
    pad = max(4, th // 2)
    tw = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, thick)[0][0]
    x0, y1 = 10, h - 10
    y0, x1 = max(0, y1 - th - 2 * pad), min(w, x0 + tw + 2 * pad)
    box = out[y0:y1, x0:x1].astype(np.float32)
    out[y0:y1, x0:x1] = np.rint(box * 0.2 + 255 * 0.8).astype(np.uint8)
    org = (x0 + pad, y1 - pad)
    cv2.putText(out, text, org, cv2.FONT_HERSHEY_SIMPLEX, scale, _TEXT_COLOR, thick, cv2.LINE_AA)
    return out


# -- files ---------------------------------------------------------------------------------------
def read_png(path: str | os.PathLike) -> np.ndarray:
    """Read an image file as RGB uint8 (H, W, 3).

    Raises
    ------
    FileFormatError
        If the file is missing, truncated or cannot be decoded (:func:`pointtraj.images.read_rgb`).
    """
    from .images import read_rgb

    return read_rgb(path)


def write_png(path: str | os.PathLike, image: np.ndarray) -> None:
    """Write an RGB image as PNG, atomically."""
    import cv2

    with atomic_path(path) as tmp:
        if not cv2.imwrite(str(tmp), np.ascontiguousarray(image[..., ::-1])):
            raise WriteError(path, "OpenCV could not write the PNG")


def write_video(path: str | os.PathLike, frames: Iterable[np.ndarray], fps: float = 30.0) -> int:
    """Write RGB frames to an MP4 (codec ``mp4v``), atomically.

    Parameters
    ----------
    path : path-like
        Destination ``.mp4``.
    frames : iterable of (H, W, 3) uint8 ndarray
        All the same size; consumed lazily, one at a time.
    fps : float

    Returns
    -------
    int
        Number of frames written (no file is written for none).
    """
    import cv2

    path = Path(path)
    writer = None
    n = 0
    with atomic_path(path) as tmp:
        try:
            for img in frames:
                if writer is None:
                    h, w = img.shape[:2]
                    writer = cv2.VideoWriter(str(tmp), cv2.VideoWriter_fourcc(*"mp4v"), fps, (w, h))
                    if not writer.isOpened():
                        raise WriteError(path, "OpenCV cannot open an mp4v video writer")
                writer.write(np.ascontiguousarray(img[..., ::-1]))
                n += 1
        finally:
            if writer is not None:
                writer.release()
        if n == 0:
            raise ValidationError(f"{path}: no frames to write")
    return n


# -- rendering a work folder ---------------------------------------------------------------------
@dataclass(frozen=True)
class RenderConfig:
    """What :func:`render_work` draws, and how.

    Parameters
    ----------
    engine : {"open3d", "opencv"}
        Renderer of the views: Open3D off-screen (Filament; pinhole, about 1-2 s a 1280x1024
        frame on a CPU) or OpenCV projection and drawing (distortion included, 10-30x faster).
        Overlays on camera images always use OpenCV.
    views : tuple of str
        Views rendered on a plain background: ``"orbit"`` (a virtual camera circling the scene)
        and/or names of rig cameras (rendered at the camera's image size). May be empty when
        overlays are on.
    tail : int
        Past frames drawn as a polyline behind each point (the paper draws 10 or 30).
    tail_fade : float
        How far, in [0, 1], the oldest tail segment's colour moves towards the background (the
        newest keeps the label colour), so tails show direction. Views only.
    frames : (int or None, int or None), optional
        Frames ``A:B`` rendered (B exclusive; negative values count from the end of the store's
        T frames; None is 0 or T); default the frames where trajectories exist.
    stride : int
        Render every ``stride``-th frame of the range.
    size : (int, int)
        ``(width, height)`` of the orbit view.
    point_size : float
        Point diameter in pixels in the views.
    line_width : float
        Tail width in pixels in the views.
    background : (int, int, int)
        RGB background of the views.
    orbit_fov_deg : float
        Horizontal field of view of the orbit camera.
    orbit_elevation_deg : float
        Angle of the orbit camera above the horizontal plane through the scene centre.
    orbit_start_deg : float
        Azimuth of the orbit camera at frame 0, measured from the rig's first camera (from world
        x when there is no rig).
    orbit_deg_per_frame : float
        Degrees the orbit camera turns per frame (0: a fixed virtual camera). The camera of
        frame t is the same in every run, whatever the range.
    orbit_distance : float, optional
        Distance from the scene centre in metres (default: a sphere holding 95% of the points,
        enlarged by 10%, fills the view).
    orbit_center : (float, float, float), optional
        Point the orbit camera looks at (default: the median of all point positions, so
        outliers do not move it).
    floor : bool
        Draw a light grid on the floor (the 1st percentile of the points' heights) in the
        views.
    fps : float, optional
        Frame rate of the MP4s (default the capture's, else the store's, divided by
        ``stride``: real time).
    video : bool
        Write an MP4 per view and per overlay camera.
    overlays : bool
        Draw the labelled points and tails over the input camera images.
    overlay_cameras : tuple of str
        Cameras of the overlays (default: the rig cameras among ``views``, else the rig's
        first camera).
    overlay_radius : int
        Point radius of the overlays in pixels.
    colors : {"auto", "labels", "semantic_map", "grey"}
        Colour source: ``labels.npz`` (``pointtraj label``), the argmax of ``semantic_map.npz``
        (``pointtraj semantics``), or grey for all. ``"auto"`` takes the first that exists and
        is an error when neither does.
    min_length : int
        Draw only trajectories living at least this many frames (1 draws all).
    unlabelled : bool
        Draw the unlabelled trajectories (label -1, grey). Off shows only the labelled people
        and objects of a real capture, whose room is mostly unlabelled.
    legend : bool
        Draw the legend (class name and colour of each class drawn) in the images; it is
        written to ``renders/legend.png`` in any case.
    caption : bool
        Write the view name and frame number at the bottom-left of each image.
    """

    engine: Literal["open3d", "opencv"] = "open3d"
    views: tuple[str, ...] = (ORBIT,)
    tail: int = 10
    tail_fade: float = 0.6
    frames: tuple[int | None, int | None] | None = None
    stride: int = 1
    size: tuple[int, int] = (1280, 1024)
    point_size: float = 4.0
    line_width: float = 1.5
    background: tuple[int, int, int] = (255, 255, 255)
    orbit_fov_deg: float = 40.0
    orbit_elevation_deg: float = 20.0
    orbit_start_deg: float = 30.0
    orbit_deg_per_frame: float = 1.0
    orbit_distance: float | None = None
    orbit_center: tuple[float, float, float] | None = None
    floor: bool = True
    fps: float | None = None
    video: bool = True
    overlays: bool = True
    overlay_cameras: tuple[str, ...] = ()
    overlay_radius: int = 2
    colors: Literal["auto", "labels", "semantic_map", "grey"] = "auto"
    min_length: int = 1
    unlabelled: bool = True
    legend: bool = True
    caption: bool = True

    def __post_init__(self) -> None:
        def bad(name: str, what: str) -> ValidationError:
            return ValidationError(f"{name}: {what}, got {getattr(self, name)!r}")

        for name in ("views", "overlay_cameras"):
            value = getattr(self, name)
            if isinstance(value, str):
                value = (value,)
            # Drop repeats, keep the order.
            object.__setattr__(self, name, tuple(dict.fromkeys(str(v) for v in value)))
        if self.engine not in ("open3d", "opencv"):
            raise bad("engine", "must be 'open3d' or 'opencv'")
        if self.colors not in ("auto", "labels", "semantic_map", "grey"):
            raise bad("colors", "must be 'auto', 'labels', 'semantic_map' or 'grey'")
        if not self.views and not self.overlays:
            raise ValidationError("views: empty and overlays off: nothing to render")
        for name in ("tail", "stride", "min_length", "overlay_radius"):
            v = getattr(self, name)
            if isinstance(v, bool) or int(v) != v:
                raise bad(name, "must be an integer")
        if self.tail < 0 or self.overlay_radius < 0:
            raise bad("tail" if self.tail < 0 else "overlay_radius", "must be non-negative")
        if self.stride < 1 or self.min_length < 1:
            raise bad("stride" if self.stride < 1 else "min_length", "must be at least 1")
        if not 0 <= self.tail_fade <= 1:
            raise bad("tail_fade", "must be in [0, 1]")
        if self.frames is not None and len(self.frames) != 2:
            raise bad("frames", "must be (A, B)")
        if len(self.size) != 2 or min(self.size) < 16 or any(int(s) != s for s in self.size):
            raise bad("size", "must be (width, height), integers of at least 16")
        object.__setattr__(self, "size", (int(self.size[0]), int(self.size[1])))
        if self.point_size <= 0 or self.line_width <= 0:
            raise bad("point_size" if self.point_size <= 0 else "line_width", "must be positive")
        if len(self.background) != 3 or any(not 0 <= c <= 255 for c in self.background):
            raise bad("background", "must be 3 values in 0..255")
        if not 1 <= self.orbit_fov_deg <= 170:
            raise bad("orbit_fov_deg", "must be in [1, 170]")
        if not -89 <= self.orbit_elevation_deg <= 89:
            raise bad("orbit_elevation_deg", "must be in [-89, 89]")
        if self.orbit_distance is not None and not self.orbit_distance > 0:
            raise bad("orbit_distance", "must be positive")
        if self.orbit_center is not None and len(self.orbit_center) != 3:
            raise bad("orbit_center", "must be 3 coordinates")
        if self.fps is not None and not self.fps > 0:
            raise bad("fps", "must be positive")


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
    from .config import load_toml
    from .labelset import LabelSet, check_class_names
    from .session import Capture

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
        from .npzfile import load_npz

        z = load_npz(labels_path, ("labels", "class_names"), "a labels file")
        labels = np.asarray(z["labels"], np.int64)
        names = [str(s) for s in z["class_names"]]
        source = "labels.npz"
        inputs.append(labels_path)
    elif cfg.colors == "labels":
        raise FileFormatError(labels_path, "no such file (run `pointtraj label` first)")
    if labels is None and cfg.colors in ("auto", "semantic_map"):
        if smap_path.is_file():
            from .semantics.semantic_map import SemanticMap

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
    if capture is not None and (capture.path / "rig.toml").is_file():
        inputs.append(capture.path / "rig.toml")
    label_set = None
    if capture is not None and capture.labels_path is not None:
        label_set = LabelSet.load(capture.labels_path)
        if source != "grey":
            made = labels_path if source == "labels.npz" else smap_path
            check_class_names(capture.labels_path, label_set.names, made, names)
        inputs.append(capture.labels_path)
    palette = class_palette(names, label_set)
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


def _stage(traj: Trajectories, rig: CameraRig | None, cfg: RenderConfig) -> _Stage:
    # Up: the mean of the rig cameras' image-up directions (-y of each camera), else world +z.
    up = np.array([0.0, 0.0, 1.0])
    if rig is not None:
        u = -rig.R[:, 1, :].mean(axis=0)
        if np.linalg.norm(u) > 0.3:
            up = u / np.linalg.norm(u)
    xyz = traj.xyz
    xyz = xyz[:: max(1, len(xyz) // 400_000)]
    xyz = xyz[np.isfinite(xyz).all(axis=1)].astype(np.float64)
    if len(xyz) == 0:
        raise ValidationError("the trajectory store has no finite positions")
    # Robust framing: the median point, and the radius holding 95% of the points (x 1.1).
    center = np.median(xyz, axis=0)
    extent = max(1.1 * float(np.percentile(np.linalg.norm(xyz - center, axis=1), 95)), 0.1)
    if cfg.orbit_center is not None:
        center = np.asarray(cfg.orbit_center, float)
    w, h = cfg.size
    half_h = math.radians(cfg.orbit_fov_deg) / 2
    half_v = math.atan(math.tan(half_h) * h / w)
    distance = cfg.orbit_distance or extent / math.sin(min(half_h, half_v))
    _, e1, e2 = _plane_basis(up)
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


def _settings(kind: str, name: str, scene: _Scene, cfg: RenderConfig) -> dict:
    """What the images of one output depend on; a change makes its frames stale."""
    inputs = [
        {"path": str(p.resolve()), "bytes": p.stat().st_size, "mtime_ns": p.stat().st_mtime_ns}
        for p in scene.inputs
    ]
    keys = ["tail", "colors", "min_length", "unlabelled", "legend", "caption"]
    if kind == "overlay":
        keys += ["overlay_radius"]
    else:
        keys += ["engine", "tail_fade", "point_size", "line_width", "background", "floor"]
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


@locked("pointtraj render")
def render_work(
    work: str | os.PathLike,
    config: RenderConfig | None = None,
    *,
    force: bool = False,
    progress: Callable[[str, int, int], None] | None = None,
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
        legend_names.append("unlabelled")
        legend_colors = np.vstack([legend_colors, [UNLABELLED_COLOR]]).astype(np.uint8)

    renders = work / "renders"
    legend_path = renders / "legend.png"
    write_png(legend_path, legend_image(legend_names, legend_colors))

    stage = _stage(traj, rig, cfg) if cfg.views else None
    # The floor grid: 16% of the way from the background to black (to white on dark ones).
    grid_color = _blend(bg[None], np.full(3, 255 if bg.mean() < 128 else 0), 0.16)[0]
    base_fps = capture.fps if capture is not None else traj.fps
    fps = cfg.fps or base_fps / cfg.stride

    def annotate(img: np.ndarray, label: str, t: int) -> np.ndarray:
        if cfg.legend:
            img = draw_legend(img, legend_names, legend_colors)
        if cfg.caption:
            img = draw_caption(img, f"{label}   frame {t}   {t / base_fps:.2f} s")
        return img

    def view_camera(name: str, t: int) -> Camera:
        return _orbit_camera(stage, cfg, t) if name == ORBIT else rig[name]

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
        if out.kind == "view" and cfg.engine == "open3d":
            renderer = TrajectoryRenderer(
                out.size, cfg.point_size, cfg.line_width, tuple(bg / 255.0)
            )

        def draw(t: int, out: RenderOutput = out, renderer=renderer) -> np.ndarray:
            if out.kind == "overlay":
                cam = rig[out.name]
                img = draw_overlay(
                    capture.read(out.name, t), cam, traj, t, colors, cfg.tail, cfg.overlay_radius
                )
                return annotate(img, f"{out.name} overlay", t)
            cam = view_camera(out.name, t)
            pts, pc, seg, sc = _frame_geometry(traj, t, colors, cfg.tail, cfg.tail_fade, bg)
            if cfg.floor:
                seg = np.concatenate([stage.grid.astype(np.float32), seg])
                sc = np.concatenate([np.tile(grid_color, (len(stage.grid), 1)), sc])
            if renderer is not None:
                img = renderer.render(cam, pts, pc, seg, sc)
            else:
                canvas = np.empty((cam.height, cam.width, 3), np.uint8)
                canvas[:] = bg
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
            return annotate(img, out.name, t)

        def images(out: RenderOutput = out, draw=draw, fresh: bool = fresh) -> Iterator[np.ndarray]:
            nonlocal done
            for t in frames:
                path = out.folder / f"{t:06d}.png"
                keep = fresh and not force and path.is_file()
                img = None
                if keep and cfg.video:
                    try:
                        img = read_png(path)
                    except FileFormatError:
                        keep = False
                if keep:
                    out.skipped += 1
                else:
                    t0 = time.perf_counter()
                    img = draw(t)
                    write_png(path, img)
                    out.render_seconds += time.perf_counter() - t0
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
