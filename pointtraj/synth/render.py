"""Ray-cast rendering of synthetic scenes with Open3D (CPU, no display).

For each frame, one ``open3d.t.geometry.RaycastingScene`` holds every posed mesh (geometry id =
index in :attr:`Scene.geometries`). One ray per pixel is cast through each pixel centre
(OpenCV convention: pixel ``(u, v)`` is centred on integer coordinates); rays of several cameras
are batched into one ``cast_rays`` call of at most ``max_rays`` rays. From the hits come:

- the RGB image: the part's solid texture at the hit point expressed in the part's LOCAL frame
  (barycentric interpolation of the local vertices), times Lambertian shading from a fixed light
  plus ambient (smooth normals), plus seeded Gaussian sensor noise;
- the label map: class index of the hit geometry, -1 for background (miss or unlabelled);
- the depth map: z of the hit point in the camera frame, metres, NaN where nothing is hit.
"""

from __future__ import annotations

import logging
import os
import time
from collections import deque
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..atomic import remove_stale_temporaries
from ..camera import CameraRig
from ..config import load_toml, save_toml
from ..errors import ValidationError
from ..executor import Executor, worker_cache
from .scenes import Scene

__all__ = [
    "RenderSettings",
    "synthetic_world",
    "RenderedView",
    "Renderer",
    "RenderTimings",
    "CaptureSummary",
    "render_capture",
]

logger = logging.getLogger(__name__)

#: Memory allowed for cached per-camera ray directions (bytes).
_DIRECTION_CACHE_BYTES = 256 * 2**20


@dataclass(frozen=True)
class RenderSettings:
    """Shading and batching parameters of the renderer.

    Attributes
    ----------
    light : (3,) tuple
        Direction towards the light (world, normalised internally).
    ambient, diffuse : float
        Shading ``albedo * (ambient + diffuse * max(0, n . l))``.
    background : (3,) tuple
        RGB in [0, 1] of pixels that hit nothing.
    noise_sigma : float
        Standard deviation of the sensor noise, in 8-bit grey levels.
    max_rays : int
        Most rays per ``cast_rays`` call (bounds memory: about 150 bytes per ray).
    threads : int
        Cameras shaded in parallel within a ``cast_rays`` batch (1 = serial).
    """

    light: tuple[float, float, float] = (0.35, 0.45, 1.0)
    ambient: float = 0.4
    diffuse: float = 0.65
    background: tuple[float, float, float] = (0.12, 0.12, 0.14)
    noise_sigma: float = 1.5
    max_rays: int = 3_000_000
    threads: int = 2


@dataclass
class RenderedView:
    """One camera's rendering of one frame.

    Attributes
    ----------
    camera : int
        Index in the rig.
    image : (H, W, 3) uint8 ndarray
        RGB.
    label : (H, W) int16 ndarray
        Class index, -1 background.
    depth : (H, W) float32 ndarray
        Camera-frame z in metres, NaN where no surface is hit.
    geometry : (H, W) int32 ndarray
        Geometry index hit, -1 where nothing is hit.
    """

    camera: int
    image: np.ndarray
    label: np.ndarray
    depth: np.ndarray
    geometry: np.ndarray


@dataclass
class RenderTimings:
    """Accumulated seconds spent per rendering step."""

    build: float = 0.0
    cast: float = 0.0
    shade: float = 0.0
    extra: dict[str, float] = field(default_factory=dict)


class Renderer:
    """Renders a :class:`Scene` seen by a :class:`CameraRig`.

    Parameters
    ----------
    scene : Scene
    rig : CameraRig
    seed : int
        Seeds the sensor noise (with the frame and camera index).
    settings : RenderSettings, optional
    """

    def __init__(
        self, scene: Scene, rig: CameraRig, seed: int = 0, settings: RenderSettings | None = None
    ) -> None:
        self.scene = scene
        self.rig = rig
        self.seed = int(seed)
        self.settings = settings or RenderSettings()
        if self.settings.max_rays < 1:
            raise ValidationError(f"max_rays must be positive, got {self.settings.max_rays}")
        geoms = scene.geometries
        self._local_vertices = np.concatenate([g.mesh.vertices for g in geoms]).astype(np.float32)
        self._local_normals = np.concatenate([g.mesh.normals for g in geoms]).astype(np.float32)
        nv = np.array([len(g.mesh.vertices) for g in geoms])
        nf = np.array([len(g.mesh.triangles) for g in geoms])
        self._vert_offset = np.concatenate([[0], np.cumsum(nv)])
        self._tri_offset = np.concatenate([[0], np.cumsum(nf)]).astype(np.int64)
        self._triangles = np.concatenate(
            [g.mesh.triangles + o for g, o in zip(geoms, self._vert_offset[:-1])]
        ).astype(np.int64)
        self._vertex_geometry = np.repeat(np.arange(len(geoms)), nv)
        self._geometry_label = np.array([g.label for g in geoms], np.int16)
        light = np.asarray(self.settings.light, np.float32)
        self._light = light / np.linalg.norm(light)
        self._dir_cache: dict[tuple, np.ndarray] = {}
        self._noise_buffer: np.ndarray | None = None
        #: The RaycastingScene of the last rendered frame (used by :meth:`unoccluded`).
        self.scene_at_frame = None
        self.timings = RenderTimings()

    # -- rays --------------------------------------------------------------------------------
    def _camera_directions(self, c: int) -> np.ndarray:
        """(H*W, 3) float32 ray directions of camera ``c`` in its own frame (z = 1)."""
        cam = self.rig[c]
        # Pinhole cameras sharing K and size share their directions; distorted ones are cached
        # per camera while the cache stays under _DIRECTION_CACHE_BYTES.
        key = (cam.size, cam.K.tobytes(), cam.dist.tobytes())
        d = self._dir_cache.get(key)
        if d is not None:
            return d
        w, h = cam.size
        if cam.has_distortion:
            u, v = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
            pix = np.stack([u.ravel(), v.ravel()], axis=1)
            xy = self.rig.subset([c]).normalized(pix[None])[0]  # undistorted (X/Z, Y/Z)
            d = np.concatenate([xy, np.ones((len(xy), 1))], axis=1).astype(np.float32)
        else:
            K = cam.K
            v, u = np.mgrid[0:h, 0:w].astype(np.float64)
            y = (v - K[1, 2]) / K[1, 1]
            x = (u - K[0, 2] - K[0, 1] * y) / K[0, 0]
            d = np.stack([x, y, np.ones_like(x)], axis=-1).reshape(-1, 3).astype(np.float32)
        if sum(a.nbytes for a in self._dir_cache.values()) + d.nbytes <= _DIRECTION_CACHE_BYTES:
            self._dir_cache[key] = d
        return d

    def _noise(self, frame: int, camera: int, size: int) -> np.ndarray:
        """(size,) float32 Gaussian sensor noise of one image, seeded by (seed, frame, camera).

        A window at a random offset into one long pre-drawn sequence (drawing ~4 M normals per
        HD image would cost more than shading it); offsets differ per frame and camera, so
        a pixel's noise is independent over time.
        """
        slack = 1 << 20
        if self._noise_buffer is None or len(self._noise_buffer) < size + slack:
            n = 3 * int(np.prod(self.rig.sizes, axis=1).max()) + slack
            rng = np.random.default_rng([self.seed, 0x5E4501])
            buf = rng.standard_normal(max(n, size + slack), dtype=np.float32)
            buf *= np.float32(self.settings.noise_sigma)
            self._noise_buffer = buf
        off = int(np.random.default_rng([self.seed, int(frame), int(camera)]).integers(slack))
        return self._noise_buffer[off : off + size]

    def camera_chunks(self, cameras: list[int] | None = None) -> list[list[int]]:
        """Groups of camera indices whose rays fit in one ``cast_rays`` call."""
        cams = list(range(len(self.rig))) if cameras is None else list(cameras)
        chunks: list[list[int]] = []
        cur: list[int] = []
        n = 0
        for c in cams:
            px = int(np.prod(self.rig[c].size))
            if cur and n + px > self.settings.max_rays:
                chunks.append(cur)
                cur, n = [], 0
            cur.append(c)
            n += px
        if cur:
            chunks.append(cur)
        return chunks

    # -- scene -------------------------------------------------------------------------------
    def build_raycasting_scene(self, poses: np.ndarray):
        """An ``open3d.t.geometry.RaycastingScene`` of every geometry posed by ``poses``.

        Parameters
        ----------
        poses : (G, 4, 4) float ndarray
            Local-to-world matrices.

        Returns
        -------
        scene : open3d.t.geometry.RaycastingScene
        world_normals : (V, 3) float32 ndarray
            Vertex normals of all geometries in world coordinates.
        """
        import open3d as o3d

        rs = o3d.t.geometry.RaycastingScene()
        R = poses[self._vertex_geometry, :3, :3].astype(np.float32)  # (V, 3, 3)
        t = poses[self._vertex_geometry, :3, 3].astype(np.float32)  # (V, 3)
        world = np.einsum("vij,vj->vi", R, self._local_vertices) + t  # (V, 3)
        normals = np.einsum("vij,vj->vi", R, self._local_normals)  # (V, 3)
        for g, geom in enumerate(self.scene.geometries):
            a, b = self._vert_offset[g], self._vert_offset[g + 1]
            gid = rs.add_triangles(
                o3d.core.Tensor(np.ascontiguousarray(world[a:b])),
                o3d.core.Tensor(geom.mesh.triangles.astype(np.uint32)),
            )
            if gid != g:  # pragma: no cover - Open3D assigns ids in order
                raise RuntimeError(f"Open3D gave geometry id {gid}, expected {g}")
        return rs, normals

    def unoccluded(self, points: np.ndarray, tolerance: float = 0.002) -> np.ndarray:
        """Whether the segment from each camera centre to each point is free of surfaces.

        Casts one ray per camera and point, exactly through the point, in the scene of the last
        :meth:`render_frame` call.

        Parameters
        ----------
        points : (M, 3) float ndarray
            World points (normally on the surfaces themselves).
        tolerance : float
            A hit closer than ``distance - tolerance`` occludes the point (metres).

        Returns
        -------
        (M, C) bool ndarray
        """
        import open3d as o3d

        rs = self.scene_at_frame
        if rs is None:
            raise ValidationError("unoccluded: render a frame first")
        X = np.asarray(points, np.float64)
        out = np.zeros((len(X), len(self.rig)), bool)
        per = max(1, self.settings.max_rays // max(len(X), 1))
        for c0 in range(0, len(self.rig), per):
            cams = np.arange(c0, min(c0 + per, len(self.rig)))
            d = X[None] - self.rig.C[cams][:, None]  # (c, M, 3)
            dist = np.linalg.norm(d, axis=2)  # (c, M)
            d /= np.maximum(dist, 1e-12)[..., None]
            o = np.broadcast_to(self.rig.C[cams][:, None], d.shape)
            rays = np.concatenate([o, d], axis=2).reshape(-1, 6).astype(np.float32)
            hit = rs.cast_rays(o3d.core.Tensor(rays), nthreads=0)["t_hit"].numpy()
            out[:, cams] = (hit.reshape(len(cams), -1) >= dist - tolerance).T
        return out

    # -- rendering ---------------------------------------------------------------------------
    def render_frame(
        self, frame: int, time_s: float | None = None, cameras: list[int] | None = None
    ) -> Iterator[RenderedView]:
        """Render one frame, camera by camera (streamed: one chunk of cameras at a time).

        Parameters
        ----------
        frame : int
            Frame index (seeds the noise; the time is ``frame / fps`` unless ``time_s``).
        time_s : float, optional
            Scene time in seconds (default ``frame / 30``).
        cameras : list of int, optional
            Camera indices to render (default all).

        Yields
        ------
        RenderedView
            In camera order.
        """
        import open3d as o3d

        t0 = time.perf_counter()
        t_scene = frame / 30.0 if time_s is None else float(time_s)
        poses = self.scene.poses(t_scene)
        rs, world_normals = self.build_raycasting_scene(poses)
        self.scene_at_frame = rs
        self.timings.build += time.perf_counter() - t0
        for chunk in self.camera_chunks(cameras):
            t1 = time.perf_counter()
            sizes = [int(np.prod(self.rig[c].size)) for c in chunk]
            rays = np.empty((sum(sizes), 6), np.float32)  # origin, direction per pixel
            start = 0
            for c, n in zip(chunk, sizes):
                rays[start : start + n, :3] = self.rig.C[c]
                np.einsum(
                    "ni,ij->nj",
                    self._camera_directions(c),
                    self.rig.R[c].astype(np.float32),  # R^T d, row-vector form
                    out=rays[start : start + n, 3:],
                )
                start += n
            d_all = rays[:, 3:]  # (N, 3) world directions (not unit)
            hits = rs.cast_rays(o3d.core.Tensor.from_numpy(rays), nthreads=0)
            t_hit = hits["t_hit"].numpy()
            gid = hits["geometry_ids"].numpy().astype(np.int64)
            pid = hits["primitive_ids"].numpy().astype(np.int64)
            uv = hits["primitive_uvs"].numpy()
            del hits
            t2 = time.perf_counter()
            self.timings.cast += t2 - t1
            starts = np.concatenate([[0], np.cumsum(sizes)]).astype(int)
            jobs = [
                (
                    [c],
                    [n],
                    *(a[starts[i] : starts[i + 1]] for a in (d_all, t_hit, gid, pid, uv)),
                    world_normals,
                    frame,
                )
                for i, (c, n) in enumerate(zip(chunk, sizes))
            ]
            if self.settings.threads > 1 and len(chunk) > 1:
                # NumPy and OpenCV release the GIL in the heavy loops: shade cameras in parallel.
                with ThreadPoolExecutor(max_workers=self.settings.threads) as pool:
                    views = [v[0] for v in pool.map(lambda job: self._shade(*job), jobs)]
            else:
                views = [self._shade(*job)[0] for job in jobs]
            self.timings.shade += time.perf_counter() - t2
            yield from views

    def _shade(
        self,
        chunk: list[int],
        sizes: list[int],
        d_all: np.ndarray,
        t_hit: np.ndarray,
        gid: np.ndarray,
        pid: np.ndarray,
        uv: np.ndarray,
        world_normals: np.ndarray,
        frame: int,
    ) -> list[RenderedView]:
        s = self.settings
        hit = np.isfinite(t_hit)
        hit_idx = np.flatnonzero(hit)
        g = gid[hit_idx]
        tri = self._triangles[self._tri_offset[g] + pid[hit_idx]]  # (n, 3) global vertex ids
        w1, w2 = uv[hit_idx, 0:1], uv[hit_idx, 1:2]
        w0 = 1.0 - w1 - w2
        # Barycentric interpolation of [local position, world normal] in one pass.
        attr = np.concatenate([self._local_vertices, world_normals], axis=1)  # (V, 6)
        both = w0 * attr[tri[:, 0]]
        both += w1 * attr[tri[:, 1]]
        both += w2 * attr[tri[:, 2]]  # (n, 6)
        local, nrm = both[:, :3], both[:, 3:]
        # Lambert term of the unit normal turned towards the camera (open quads are two-sided).
        d_hit = d_all[hit_idx]
        norm2 = np.einsum("ij,ij->i", nrm, nrm)
        lambert = np.einsum("ij,j->i", nrm, self._light)
        lambert /= np.sqrt(np.maximum(norm2, np.float32(1e-24)))
        facing_away = np.einsum("ij,ij->i", nrm, d_hit) > 0
        np.negative(lambert, out=lambert, where=facing_away)
        del d_hit, norm2, facing_away
        albedo = np.empty((len(hit_idx), 3), np.float32)
        order = np.argsort(g.astype(np.int16), kind="stable")  # radix sort
        bounds = np.searchsorted(g[order], np.arange(len(self.scene.geometries) + 1))
        for k, geom in enumerate(self.scene.geometries):
            sel = order[bounds[k] : bounds[k + 1]]
            if len(sel):
                albedo[sel] = geom.texture.sample(local[sel])
        shade = np.float32(255 * s.ambient) + np.float32(255 * s.diffuse) * np.maximum(lambert, 0)
        # 8-bit colour plus 0.5, so that truncation after the noise rounds to nearest.
        colour = np.empty((len(t_hit), 3), np.float32)
        colour[:] = np.asarray(s.background, np.float32) * 255 + 0.5
        albedo *= shade[:, None]
        albedo += np.float32(0.5)
        colour[hit_idx] = albedo
        del albedo, local, nrm, both
        label = np.full(len(t_hit), -1, np.int16)
        label[hit_idx] = self._geometry_label[g]
        geometry = np.full(len(t_hit), -1, np.int32)
        geometry[hit_idx] = g
        views = []
        start = 0
        for c, n in zip(chunk, sizes):
            w, h = self.rig[c].size
            sl = slice(start, start + n)
            start += n
            # Camera-frame z = t * (d . optical axis); d is in world coordinates.
            z_dir = np.einsum("ni,i->n", d_all[sl], self.rig.R[c][2].astype(np.float32))
            depth = t_hit[sl] * z_dir
            depth[~hit[sl]] = np.nan
            img = colour[sl]
            if s.noise_sigma > 0:
                img += self._noise(frame, c, img.size).reshape(img.shape)
            np.clip(img, 0, 255, out=img)
            image = img.astype(np.uint8).reshape(h, w, 3)
            views.append(
                RenderedView(
                    camera=c,
                    image=image,
                    label=label[sl].reshape(h, w),
                    depth=depth.astype(np.float32, copy=False).reshape(h, w),
                    geometry=geometry[sl].reshape(h, w),
                )
            )
        return views


@dataclass
class CaptureSummary:
    """What :func:`render_capture` made.

    Attributes
    ----------
    path : pathlib.Path
    cameras, frames : int
        C and T of the capture.
    rendered, skipped : int
        Frames rendered now, and frames found complete and skipped (resume).
    images : int
        Camera images in the capture (C * T).
    gt_points : int
        M ground-truth points.
    seconds : float
        Wall time of this call.
    timings : RenderTimings
        Seconds spent building scenes, casting rays, shading, and (in ``extra``) computing
        ground truth and writing files (``write`` is busy time of the writer thread, which
        overlaps rendering).
    """

    path: Path
    cameras: int
    frames: int
    rendered: int
    skipped: int
    images: int
    gt_points: int
    seconds: float
    timings: RenderTimings

    @property
    def seconds_per_frame(self) -> float:
        """Wall seconds per rendered frame (NaN if none was rendered)."""
        return self.seconds / self.rendered if self.rendered else float("nan")


def synthetic_world(
    preset: str,
    scene: str,
    seed: int = 0,
    scale: float | None = None,
    rig_scale: float = 1.0,
    rig: CameraRig | None = None,
) -> tuple[Any, Any]:
    """The rig and the scene of a synthetic capture (the one place both are made).

    Parameters
    ----------
    preset, scene : str
    seed : int
    scale : float, optional
        The scene's size against its human size (default: the preset's ``scene_scale``, 1 but
        for ``narrow7``; 1 with ``rig``); its stage centre is placed at the preset's target.
    rig_scale : float
        The rig's camera centres scaled about the preset's target (``narrow7`` with
        ``scale = 1, rig_scale = 250`` is ``narrow7``'s capture at 250 times its size).
    rig : CameraRig, optional
        Cameras already in the scenes' frame (a synthetic twin,
        :func:`~.presets.twin_rig`) instead of the preset's; ``preset`` is then only a name.

    Returns
    -------
    rig : CameraRig
    scene : Scene
    """
    from .presets import PRESETS, make_rig, scale_rig
    from .scenes import make_scene, scale_scene

    if rig is not None:
        if rig_scale != 1.0:
            raise ValidationError("rig_scale applies to a preset's rig, not to a given rig")
        return rig, scale_scene(make_scene(scene, seed), 1.0 if scale is None else float(scale))
    rig = make_rig(preset)  # refuses an unknown preset
    spec = PRESETS[preset]
    factor = spec.scene_scale if scale is None else float(scale)
    rig = scale_rig(rig, rig_scale, spec.target)
    return rig, scale_scene(make_scene(scene, seed), factor, spec.target)


def render_capture(
    out: str | os.PathLike,
    *,
    preset: str = "tiny4",
    scene: str = "dribble",
    frames: int = 10,
    seed: int = 0,
    points_per_part: int = 300,
    image_format: str = "jpg",
    settings: RenderSettings | None = None,
    on_frame: Callable[[int, bool], None] | None = None,
    executor: Executor | None = None,
    rig: CameraRig | None = None,
    fps: float | None = None,
    scale: float | None = None,
    rig_scale: float = 1.0,
) -> CaptureSummary:
    """Render a synthetic capture folder with ground truth, streaming frame by frame.

    Writes ``rig.toml``, ``capture.toml``, ``labels.toml``, ``frames/<camera>/<t:06d>.<ext>``
    and ``gt/`` (see :mod:`pointtraj.synth.groundtruth`). Frames whose ground-truth file exists
    are complete and are skipped, so an interrupted render resumes; rerunning with more frames
    extends the capture. Only one frame's images are in memory at a time.

    Parameters
    ----------
    out : path-like
        Capture folder (created).
    preset : str
        Rig preset (:data:`pointtraj.synth.presets.PRESETS`).
    scene : str
        Scene (:data:`pointtraj.synth.scenes.SCENES`).
    frames : int
        Number of frames T (positive).
    seed : int
        Seeds textures, motion parameters, ground-truth sampling and sensor noise.
    points_per_part : int
        Ground-truth points per labelled part.
    image_format : {"jpg", "png"}
    settings : RenderSettings, optional
    on_frame : callable, optional
        ``on_frame(t, rendered)`` after each frame (``rendered`` False when skipped).
    executor : Executor, optional
        Where the frames are rendered and written, one task a frame (default: here, with a
        writer thread). Every frame's noise is seeded by the frame and the camera, so the files
        are the same on any executor; on a cluster ``out`` must be a path the workers share.
    rig : CameraRig, optional
        Cameras to render with instead of the preset's, in the scenes' frame (a synthetic twin
        of a real rig: :func:`pointtraj.synth.presets.twin_rig`); ``preset`` then only names
        them in ``gt/synth.toml``.
    fps : float, optional
        Frame rate (default: the preset's, or 30 with ``rig``).
    scale : float, optional
        The scene's size against its human size (default: the preset's ``scene_scale``);
        geometry, motion, texture and ground truth are scaled (:func:`synthetic_world`).
    rig_scale : float
        The rig's size against the preset's (about its target).

    Returns
    -------
    CaptureSummary

    Raises
    ------
    ValidationError
        On a bad option, or if ``out`` holds a different capture.
    """
    from ..labelset import LabelSet, body_joints
    from ..session import Capture
    from . import groundtruth as gtio
    from .presets import PRESETS
    from .scenes import STAGE_CENTRE

    if int(frames) != frames or frames < 1:
        raise ValidationError(f"frames must be a positive integer, got {frames!r}")
    if image_format not in ("jpg", "png"):
        raise ValidationError(f"image_format must be 'jpg' or 'png', got {image_format!r}")
    if int(points_per_part) < 1:
        raise ValidationError(f"points_per_part must be positive, got {points_per_part}")
    frames = int(frames)
    start = time.perf_counter()
    twin = rig is not None
    if fps is not None and not (np.isfinite(fps) and fps > 0):
        raise ValidationError(f"fps must be a positive number, got {fps!r}")
    rig, sc = synthetic_world(preset, scene, seed, scale, rig_scale, rig)
    fps = float(fps) if fps is not None else (30.0 if twin else PRESETS[preset].fps)
    out = Path(out)
    params = {
        "preset": preset,
        "scene": scene,
        "seed": int(seed),
        "points_per_part": int(points_per_part),
        "image_format": image_format,
    }
    if twin:  # the same capture only with the same cameras
        params["rig_digest"] = _rig_digest(rig)
        if sc.scale != 1.0:
            params["scale"] = float(sc.scale)
    else:
        moved = tuple(PRESETS[preset].target) != STAGE_CENTRE  # the scene is placed at the target
        if sc.scale != 1.0 or rig_scale != 1.0 or moved:  # only then: older captures still match
            params.update(scale=float(sc.scale), rig_scale=float(rig_scale))
    if out.exists() and not out.is_dir():
        raise ValidationError(f"{out} is a file; the output must be a folder")
    marker = out / "gt" / "synth.toml"
    if marker.is_file():
        old = load_toml(marker)
        diff = [k for k, v in params.items() if old.get(k) != v]
        if diff:
            raise ValidationError(
                f"{out} holds a different synthetic capture ("
                + ", ".join(f"{k}={old.get(k)!r}" for k in diff)
                + "); choose another output folder"
            )
        stale = remove_stale_temporaries(out)  # of an interrupted render of this capture
        if stale:
            logger.info("%s: removed %d temporary files of an interrupted run", out, len(stale))
        if int(old.get("frames", 0)) > frames:
            raise ValidationError(
                f"{out} already holds {old['frames']} frames; ask for at least as many "
                "(--frames) or choose another output folder"
            )
    elif out.exists() and any(out.iterdir()):
        raise ValidationError(
            f"{out} exists and is not a synthetic capture; choose an empty folder"
        )
    cap = Capture.create(out, rig, fps, image_format=image_format)
    save_toml(
        out / "capture.toml",
        {
            "fps": float(fps),
            "image_format": image_format,
            "source": "pointtraj synth",
            "description": (
                f"synthetic capture: scene {scene}, rig preset {preset}, seed {int(seed)}, "
                f"{frames} frames"
            ),
        },
    )
    save_toml(marker, {**params, "frames": frames, "fps": fps})
    LabelSet(
        sc.class_names,
        sc.class_colors,
        kinds=sc.class_kinds,
        recognizers=sc.extras.get("recognizers", {}),
        joints=body_joints(sc.class_names),
    ).save(out / "labels.toml")
    points = gtio.sample_ground_truth_points(sc, points_per_part, seed)
    gtio.save_points(
        out,
        points,
        class_names=sc.class_names,
        camera_names=rig.names,
        geometry_names=[g.name for g in sc.geometries],
        fps=fps,
        num_frames=frames,
    )
    rendered = skipped = 0
    if executor is not None and not executor.local:
        job = _FrameJob(
            str(out),
            preset,
            scene,
            int(seed),
            int(points_per_part),
            image_format,
            sc.scale,
            float(rig_scale),
            fps,
            twin,
        )
        timings = RenderTimings()
        timings.extra.update(write=0.0, ground_truth=0.0)
        todo = []
        for t in range(frames):
            if gtio.frame_file(out, t).is_file():
                skipped += 1
                if on_frame is not None:
                    on_frame(t, False)
            else:
                todo.append(t)
        for t, took in zip(
            todo, executor.map(_render_frame_task, todo, label="synth", context=(job, settings))
        ):
            timings.build += took.build
            timings.cast += took.cast
            timings.shade += took.shade
            for k, v in took.extra.items():
                timings.extra[k] = timings.extra.get(k, 0.0) + v
            rendered += 1
            if on_frame is not None:
                on_frame(t, True)
    else:
        renderer = Renderer(sc, rig, seed=seed, settings=settings)
        timings = renderer.timings
        timings.extra.setdefault("write", 0.0)
        timings.extra.setdefault("ground_truth", 0.0)

        # One writer thread encodes and writes images (OpenCV releases the GIL) while the main
        # thread renders; at most ``backlog`` views wait, which bounds memory.
        backlog = max(2, 2 * max(len(ch) for ch in renderer.camera_chunks()))
        instances = np.array([g.instance for g in sc.geometries], np.int16)
        pending: deque[Future] = deque()

        def drain(keep: int) -> None:
            while len(pending) > keep:
                timings.extra["write"] += pending.popleft().result()

        with ThreadPoolExecutor(max_workers=1, thread_name_prefix="synth-writer") as pool:

            def write(t: int, view: RenderedView) -> None:
                pending.append(pool.submit(_write_view, cap, out, t, view, instances))
                drain(backlog)

            for t in range(frames):
                if gtio.frame_file(out, t).is_file():
                    skipped += 1
                    if on_frame is not None:
                        on_frame(t, False)
                    continue
                t_frame = time.perf_counter()
                xyz, visible = _render_frame(renderer, points, t, fps, write)
                drain(0)  # every image and map of frame t is on disk ...
                gtio.save_frame(out, t, xyz, visible)  # ... before its completeness marker
                rendered += 1
                logger.debug("frame %d rendered in %.2f s", t, time.perf_counter() - t_frame)
                if on_frame is not None:
                    on_frame(t, True)
    return CaptureSummary(
        path=out,
        cameras=len(rig),
        frames=frames,
        rendered=rendered,
        skipped=skipped,
        images=len(rig) * frames,
        gt_points=len(points),
        seconds=time.perf_counter() - start,
        timings=timings,
    )


def _render_frame(
    renderer: Renderer,
    points: Any,
    t: int,
    fps: float,
    write: Callable[[int, RenderedView], None],
) -> tuple[np.ndarray, np.ndarray]:
    """Render frame ``t``'s views, hand each to ``write(t, view)``, and find which ground-truth
    points each camera sees (the serial loop's and a frame task's one implementation).

    Returns
    -------
    xyz : (M, 3) ndarray
        The ground-truth points at frame t.
    visible : (M, C) bool ndarray
        Which points each camera sees.
    """
    from . import groundtruth as gtio

    rig = renderer.rig
    time_s = t / fps
    xyz = points.world(renderer.scene.poses(time_s))  # (M, 3)
    proj = rig.project(xyz)
    visible = np.zeros((len(points), len(rig)), bool)
    free = None
    for view in renderer.render_frame(t, time_s=time_s):
        c = view.camera
        t0 = time.perf_counter()
        if free is None:
            free = renderer.unoccluded(xyz, tolerance=0.002 * renderer.scene.scale)  # (M, C)
        visible[:, c] = gtio.visibility_exact(
            proj.pixels[c], proj.in_image[c] & free[:, c], points.geometry, view.geometry
        )
        renderer.timings.extra["ground_truth"] += time.perf_counter() - t0
        write(t, view)
    return xyz, visible


def _write_view(cap: Any, out: Path, t: int, view: RenderedView, instances: np.ndarray) -> float:
    """Write one rendered view's image, label, instance and depth maps; returns the seconds
    taken. ``instances`` (G,) is the instance id of each geometry."""
    from . import groundtruth as gtio

    t1 = time.perf_counter()
    name = cap.rig.names[view.camera]
    cap.write_frame(view.camera, t, view.image)
    gtio.save_label_map(out, name, t, view.label)
    lut = np.append(np.asarray(instances, np.int16), np.int16(-1))  # geometry -1: nothing hit
    gtio.save_instance_map(out, name, t, lut[view.geometry])
    gtio.save_depth_map(out, name, t, view.depth)
    return time.perf_counter() - t1


@dataclass(frozen=True)
class _FrameJob:
    """A synthetic capture being rendered: what a frame task needs to remake its scene."""

    out: str
    preset: str
    scene: str
    seed: int
    points_per_part: int
    image_format: str
    scale: float = 1.0
    rig_scale: float = 1.0
    fps: float = 30.0
    twin: bool = False  # cameras from the capture's rig.toml, not the preset


def _rig_digest(rig: CameraRig) -> str:
    """A short digest of a rig's cameras (names, sizes, intrinsics, poses, distortion)."""
    import hashlib

    h = hashlib.sha256()
    for cam in rig:
        h.update(cam.name.encode())
        for a in (cam.size, cam.K, cam.R, cam.C, cam.dist):
            h.update(np.round(np.asarray(a, np.float64), 9).tobytes())
    return h.hexdigest()[:16]


def _frame_tools(job: _FrameJob, settings: RenderSettings | None) -> tuple[Any, ...]:
    """(rig, fps, ground-truth points, renderer, writable capture), made once per worker."""
    from ..rigio import load_rig
    from ..session import Capture
    from . import groundtruth as gtio

    def make() -> tuple[Any, ...]:
        given = load_rig(Path(job.out) / "rig.toml") if job.twin else None
        rig, sc = synthetic_world(job.preset, job.scene, job.seed, job.scale, job.rig_scale, given)
        fps = job.fps
        points = gtio.sample_ground_truth_points(sc, job.points_per_part, job.seed)
        renderer = Renderer(sc, rig, seed=job.seed, settings=settings)
        cap = Capture(Path(job.out), rig, None, 0, fps, True, job.image_format)
        return rig, fps, points, renderer, cap

    return worker_cache(("synth", job, repr(settings)), make)


def _render_frame_task(context: tuple[_FrameJob, RenderSettings | None], t: int) -> RenderTimings:
    """Render frame ``t`` of a synthetic capture and write its images, maps and ground truth
    (a task of :func:`render_capture`; the frame's ground-truth file, written last, marks it
    complete).

    Returns
    -------
    RenderTimings
        The seconds this frame took per step.
    """
    from . import groundtruth as gtio

    job, settings = context
    rig, fps, points, renderer, cap = _frame_tools(job, settings)
    out = Path(job.out)
    timings = renderer.timings = RenderTimings()
    timings.extra.update(write=0.0, ground_truth=0.0)
    instances = np.array([g.instance for g in renderer.scene.geometries], np.int16)

    def write(t: int, view: RenderedView) -> None:
        timings.extra["write"] += _write_view(cap, out, t, view, instances)

    xyz, visible = _render_frame(renderer, points, t, fps, write)
    gtio.save_frame(out, t, xyz, visible)  # after every image and map of frame t
    return timings
