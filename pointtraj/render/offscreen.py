"""The Open3D engine: :class:`TrajectoryRenderer`, off-screen rendering with Filament.

``open3d.visualization.rendering.OffscreenRenderer`` runs through Vulkan; on a machine without a
GPU it runs on Mesa's llvmpipe, which needs the Debian packages ``libvulkan1
mesa-vulkan-drivers``. Post-processing is off so label colours stay exact. Lens distortion is
ignored (pinhole views). The clipping planes are set per view around the geometry drawn
(:func:`clip_planes`), not Open3D's fixed 0.1 m near plane, so scenes of any scale render. Only one renderer may be open at a time in a process: Filament aborts
the process when a second one is destroyed.
"""

from __future__ import annotations

import contextlib
import logging
import os
import sys
import tempfile
import weakref
from collections.abc import Iterator

import numpy as np

from ..camera import Camera
from ..errors import ValidationError
from ..trajectories import Trajectories
from .scene import frame_geometry

__all__ = ["TrajectoryRenderer", "clip_planes"]

logger = logging.getLogger(__name__)


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

#: The far clipping plane is at most this many times the near one (depth buffer precision).
_MAX_FAR_OVER_NEAR = 1e5


def clip_planes(
    camera: Camera, points: np.ndarray, segments: np.ndarray | None = None
) -> tuple[float, float]:
    """Near and far clipping distances that hold the geometry in front of ``camera``.

    The depths (along the optical axis) of the points and segment ends in front of the camera
    span ``[z_min, z_max]``; the planes are ``z_min / 2`` and ``2 z_max``, so that the scene is
    drawn at any scale (a subject of 1 cm seen from 5 cm as well as a room seen from 5 m).
    The near plane is raised to ``far / 1e5`` if needed, which keeps the depth buffer's
    precision: geometry nearer than that (a point almost on the camera) is clipped.

    Parameters
    ----------
    camera : Camera
    points : (N, 3) float ndarray
    segments : (S, 2, 3) float ndarray, optional

    Returns
    -------
    near, far : float
        Metres, ``0 < near < far``; ``(0.1, 100.0)``, Open3D's own, when nothing is in front.
    """
    xyz = [np.asarray(points, float).reshape(-1, 3)]
    if segments is not None:
        xyz.append(np.asarray(segments, float).reshape(-1, 3))
    X = np.concatenate(xyz)
    z = (X - camera.C) @ camera.R[2]  # (N + 2 S,) depth along the optical axis
    z = z[np.isfinite(z) & (z > 0)]
    if len(z) == 0:
        return 0.1, 100.0
    far = 2.0 * float(z.max())
    near = max(0.5 * float(z.min()), far / _MAX_FAR_OVER_NEAR)
    return near, far


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
        # setup_camera must come after add_geometry, or Filament renders a blank image. Its
        # near plane is a fixed 0.1 m, which clips a scene nearer than that (a small-scale
        # rig): replace its projection by one with clipping planes around the geometry.
        self._renderer.setup_camera(camera.K, extrinsic, *self.size)
        near, far = clip_planes(camera, points, segments)
        scene.camera.set_projection(camera.K, near, far, *self.size)
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
        pts, pc, seg, sc = frame_geometry(trajectories, t, colors, tail)
        return self.render(camera, pts, pc, seg, sc)
