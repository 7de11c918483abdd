"""Ground truth of synthetic captures: surface-point trajectories, visibility, label and depth maps.

Layout under ``<capture>/gt/`` (spec: ``data_specs/groundtruth.md``):

- ``points.npz``: the M ground-truth points (fixed in their part's local frame): ``geometry``,
  ``local`` (M, 3), ``label``, ``instance``, ``color`` (M, 3) uint8 albedo, ``class_names``,
  ``camera_names``, ``geometry_names``, ``fps``, ``num_frames``;
- ``frames/<t:06d>.npz`` (compressed): ``xyz`` (M, 3) float32 world positions and ``visible``
  (M, C) bool at frame t. A frame's file is written last, after all its images and maps, so its
  presence marks the frame complete;
- ``labels/<camera>/<t:06d>.png``: uint8 label map, 255 = background, else the class index;
- ``instances/<camera>/<t:06d>.png``: uint8 instance map, 255 = none, else the instance id of
  the geometry seen (figure or object; the floor has none);
- ``depth/<camera>/<t:06d>.png``: uint16 depth (camera-frame z) in millimetres, 0 = no hit.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..atomic import atomic_path, save_npz_atomic
from ..camera import CameraRig
from ..errors import FileFormatError, ValidationError, check_array
from ..npzfile import load_npz
from ..trajectories import Trajectories, quantize_visibility

__all__ = [
    "capture_scale",
    "depth_unit",
    "GroundTruth",
    "GroundTruthPoints",
    "SegmentTruth",
    "load_ground_truth",
    "segment_ground_truth",
    "label_map_path",
    "load_label_map",
    "load_depth_map",
    "save_label_map",
    "save_instance_map",
    "load_instance_map",
    "instance_map_path",
    "save_depth_map",
    "sample_ground_truth_points",
    "visibility_from_depth_maps",
    "visibility_in_view",
    "visibility_exact",
    "VISIBILITY_TOLERANCE",
    "PIXEL_SLACK",
    "GT_FORMAT_VERSION",
]

logger = logging.getLogger(__name__)

#: Depth agreement (metres) between a point and the ray-cast depth at its pixel for "visible".
VISIBILITY_TOLERANCE = 0.01
#: Pixel footprints of extra depth slack allowed when the focal length is known.
PIXEL_SLACK = 2.0
GT_FORMAT_VERSION = 1
_BACKGROUND_PNG = 255


@dataclass(eq=False)
class GroundTruthPoints:
    """The M ground-truth surface points, fixed in their geometry's local frame.

    Attributes
    ----------
    geometry : (M,) int64 ndarray
        Index of the geometry (scene part) each point lies on.
    local : (M, 3) float64 ndarray
        Local coordinates (exactly on the part's triangles).
    label : (M,) int64 ndarray
        Class index.
    instance : (M,) int64 ndarray
        Instance id.
    color : (M, 3) uint8 ndarray
        Albedo of the texture at the point.
    """

    geometry: np.ndarray
    local: np.ndarray
    label: np.ndarray
    instance: np.ndarray
    color: np.ndarray

    def __len__(self) -> int:
        return int(self.geometry.shape[0])

    def world(self, poses: np.ndarray) -> np.ndarray:
        """(M, 3) float64 world positions under ``poses`` (G, 4, 4) local-to-world matrices."""
        R = poses[self.geometry, :3, :3]  # (M, 3, 3)
        return np.einsum("mij,mj->mi", R, self.local) + poses[self.geometry, :3, 3]


def sample_ground_truth_points(scene, points_per_part: int, seed: int) -> GroundTruthPoints:
    """Sample ``points_per_part`` points uniformly (by area) on every labelled geometry.

    Parameters
    ----------
    scene : Scene
    points_per_part : int
        Points per labelled geometry (positive).
    seed : int

    Returns
    -------
    GroundTruthPoints
        Points ordered geometry by geometry.
    """
    if int(points_per_part) < 1:
        raise ValidationError(f"points_per_part must be positive, got {points_per_part}")
    rng = np.random.default_rng([int(seed), 7919])
    geo, loc, col = [], [], []
    for g, geom in enumerate(scene.geometries):
        if geom.label < 0:
            continue
        pts, _ = geom.mesh.sample_surface(int(points_per_part), rng)
        geo.append(np.full(len(pts), g, np.int64))
        loc.append(pts)
        col.append(np.clip(np.rint(geom.texture.sample(pts) * 255), 0, 255).astype(np.uint8))
    if not geo:
        raise ValidationError(f"scene {scene.name!r} has no labelled geometry")
    geometry = np.concatenate(geo)
    labels = np.array([g.label for g in scene.geometries], np.int64)
    instances = np.array([g.instance for g in scene.geometries], np.int64)
    return GroundTruthPoints(
        geometry=geometry,
        local=np.concatenate(loc),
        label=labels[geometry],
        instance=instances[geometry],
        color=np.concatenate(col),
    )


def visibility_exact(
    pixels: np.ndarray, unoccluded: np.ndarray, geometry: np.ndarray, geometry_map: np.ndarray
) -> np.ndarray:
    """Ground-truth visibility in one camera (the definition used by ``pointtraj synth``).

    A point is visible when it is inside the image, in front of the camera, nothing lies on the
    segment between the camera centre and the point (``unoccluded``, from rays cast exactly
    through the points), and the pixel it falls in (the rounded projection) shows the point's own
    part. The last condition drops points within a fraction of a pixel of a silhouette or of a
    joint, whose pixel shows something else, so label maps and visibility always agree.

    Parameters
    ----------
    pixels : (M, 2) float ndarray
        Projections (OpenCV pixel coordinates).
    unoccluded : (M,) bool ndarray
        In the image, in front, and not occluded.
    geometry : (M,) int ndarray
        Geometry (part) index of each point.
    geometry_map : (H, W) int ndarray
        Geometry index hit by each pixel's ray, -1 for none.

    Returns
    -------
    (M,) bool ndarray
    """
    vis = np.zeros(len(unoccluded), bool)
    ok = np.flatnonzero(unoccluded)
    h, w = geometry_map.shape
    u = np.clip(np.rint(pixels[ok, 0]).astype(np.int64), 0, w - 1)
    v = np.clip(np.rint(pixels[ok, 1]).astype(np.int64), 0, h - 1)
    vis[ok] = geometry_map[v, u] == np.asarray(geometry)[ok]
    return vis


def visibility_in_view(
    pixels: np.ndarray,
    depth: np.ndarray,
    in_image: np.ndarray,
    depth_map: np.ndarray,
    tolerance: float = VISIBILITY_TOLERANCE,
    *,
    geometry: np.ndarray | None = None,
    geometry_map: np.ndarray | None = None,
    focal: float | None = None,
) -> np.ndarray:
    """Which points one camera sees, given only its depth map (and optionally geometry map).

    An approximation of :func:`visibility_exact` for when only the per-image maps are at hand
    (e.g. loaded with :func:`load_depth_map`).

    A point is visible when it projects inside the image, is in front of the camera, and the
    pixel it falls in (the rounded projection) sees a surface within ``tolerance`` of the
    point's own depth (``tolerance``, widened to ``PIXEL_SLACK`` pixel footprints
    ``depth / focal`` when ``focal`` is given, since the pixel centre's ray meets a sloped surface
    up to a pixel away from the point) -- and, when ``geometry`` and ``geometry_map`` are given, that surface is
    the point's own part. So nothing occludes it, and the pixel that observes it shows its part
    (points within a fraction of a pixel of a silhouette or of a joint whose pixel centre sees
    another part are not visible).

    Parameters
    ----------
    pixels : (M, 2) float ndarray
        Projections (OpenCV pixel coordinates).
    depth : (M,) float ndarray
        Camera-frame z of the points.
    in_image : (M,) bool ndarray
    depth_map : (H, W) float ndarray
        Camera-frame z per pixel, NaN where nothing is hit.
    tolerance : float
        Metres.
    geometry : (M,) int ndarray, optional
        Geometry (part) index of each point.
    geometry_map : (H, W) int ndarray, optional
        Geometry index hit by each pixel's ray, -1 for none.
    focal : float, optional
        Focal length in pixels (widens the tolerance as described above).

    Returns
    -------
    (M,) bool ndarray
    """
    vis = np.zeros(len(depth), bool)
    ok = np.flatnonzero(in_image)
    h, w = depth_map.shape
    u = np.clip(np.rint(pixels[ok, 0]).astype(np.int64), 0, w - 1)
    v = np.clip(np.rint(pixels[ok, 1]).astype(np.int64), 0, h - 1)
    tol = tolerance if focal is None else np.maximum(tolerance, PIXEL_SLACK * depth[ok] / focal)
    with np.errstate(invalid="ignore"):
        seen = np.abs(depth_map[v, u] - depth[ok]) <= tol
    if geometry is not None and geometry_map is not None:
        seen &= geometry_map[v, u] == np.asarray(geometry)[ok]
    vis[ok] = seen
    return vis


def visibility_from_depth_maps(
    rig: CameraRig,
    xyz: np.ndarray,
    depth_maps: list[np.ndarray],
    tolerance: float = VISIBILITY_TOLERANCE,
    *,
    geometry: np.ndarray | None = None,
    geometry_maps: list[np.ndarray] | None = None,
) -> np.ndarray:
    """Which points each camera sees, by testing them against its ray-cast depth maps
    (:func:`visibility_in_view` per camera).

    A 0/1 ground-truth visibility; the paper's soft ``V(X, c)`` of a reconstruction is
    :func:`pointtraj.reconstruct.triangulate.compute_visibility`.

    Parameters
    ----------
    rig : CameraRig
        C cameras.
    xyz : (M, 3) float ndarray
        World points.
    depth_maps : list of C (H, W) float ndarray
        Camera-frame z per pixel, NaN where nothing is hit.
    tolerance : float
        Metres.
    geometry : (M,) int ndarray, optional
        Geometry index of each point.
    geometry_maps : list of C (H, W) int ndarray, optional
        Geometry index per pixel, -1 for none.

    Returns
    -------
    (M, C) bool ndarray
    """
    xyz = check_array("xyz", xyz, (None, 3))
    if len(depth_maps) != len(rig):
        raise ValidationError(f"depth_maps: expected {len(rig)} maps, got {len(depth_maps)}")
    proj = rig.project(xyz)
    return np.stack(
        [
            visibility_in_view(
                proj.pixels[c],
                proj.depth[c],
                proj.in_image[c],
                dm,
                tolerance,
                geometry=geometry,
                geometry_map=None if geometry_maps is None else geometry_maps[c],
                focal=float(rig.K[c, 0, 0]),
            )
            for c, dm in enumerate(depth_maps)
        ],
        axis=1,
    )


# -- per-image maps --------------------------------------------------------------------------
def _map_path(capture_dir: str | os.PathLike, kind: str, camera: str, frame: int) -> Path:
    if int(frame) != frame or frame < 0:
        raise ValidationError(f"frame must be a non-negative integer, got {frame!r}")
    return Path(capture_dir) / "gt" / kind / str(camera) / f"{int(frame):06d}.png"


def _write_png(path: Path, array: np.ndarray) -> None:
    import cv2

    ok, buf = cv2.imencode(".png", array, [cv2.IMWRITE_PNG_COMPRESSION, 1])
    if not ok:
        raise FileFormatError(path, "PNG encoding failed")
    with atomic_path(path) as tmp:
        tmp.write_bytes(buf.tobytes())


def _read_png(path: Path, dtype: type) -> np.ndarray:
    import cv2

    if not path.is_file():
        raise FileFormatError(path, "no such file")
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None or img.ndim != 2 or img.dtype != dtype:
        raise FileFormatError(path, f"expected a single-channel {np.dtype(dtype).name} PNG")
    return img


def _save_index_map(path: Path, values, name: str, what: str) -> Path:
    """Write an (H, W) index map (-1 = none) as a uint8 PNG, 255 standing for -1."""
    idx = np.asarray(values)
    if idx.ndim != 2:
        raise ValidationError(f"{name}: expected shape (H, W), got {idx.shape}")
    if idx.size and idx.max() >= _BACKGROUND_PNG:
        raise ValidationError(f"{name}: {what} must be below 255 to fit the PNG format")
    _write_png(path, np.where(idx < 0, _BACKGROUND_PNG, idx).astype(np.uint8))
    return path


def _load_index_map(path: Path) -> np.ndarray:
    """(H, W) int16 index map of :func:`_save_index_map`'s PNG, -1 where it has 255."""
    png = _read_png(path, np.uint8)
    out = png.astype(np.int16)
    out[png == _BACKGROUND_PNG] = -1
    return out


def save_label_map(capture_dir: str | os.PathLike, camera: str, frame: int, label) -> Path:
    """Write ``gt/labels/<camera>/<frame:06d>.png`` (uint8, 255 = background).

    Parameters
    ----------
    label : (H, W) int ndarray
        Class index, -1 background; indices must be below 255.
    """
    return _save_index_map(
        label_map_path(capture_dir, camera, frame), label, "label", "class indices"
    )


def save_instance_map(capture_dir: str | os.PathLike, camera: str, frame: int, instance) -> Path:
    """Write ``gt/instances/<camera>/<frame:06d>.png`` (uint8, 255 = none).

    Parameters
    ----------
    instance : (H, W) int ndarray
        Instance id of the geometry seen, -1 where none; ids must be below 255.
    """
    return _save_index_map(
        instance_map_path(capture_dir, camera, frame), instance, "instance", "ids"
    )


def instance_map_path(capture_dir: str | os.PathLike, camera: str, frame: int) -> Path:
    """``<capture>/gt/instances/<camera>/<frame:06d>.png`` (:func:`load_instance_map`)."""
    return _map_path(capture_dir, "instances", camera, frame)


def load_instance_map(capture_dir: str | os.PathLike, camera: str, frame: int) -> np.ndarray:
    """The ground-truth instance map of one image (captures rendered before it existed have none).

    Returns
    -------
    (H, W) int16 ndarray
        Instance id of the geometry seen (``gt/points.npz`` ``instance``), -1 = none.

    Raises
    ------
    FileFormatError
        If the map is missing or not a uint8 PNG.
    """
    return _load_index_map(instance_map_path(capture_dir, camera, frame))


def capture_scale(capture_dir: str | os.PathLike) -> float:
    """The scene scale of a synthetic capture (``gt/synth.toml`` ``scale``; 1 when absent).

    A scaled scene's depth maps are in units of ``scale`` millimetres, and the ground truth's
    tolerances (visibility, the view audit's) are scaled by it.
    """
    path = Path(capture_dir) / "gt" / "synth.toml"
    try:
        mtime = path.stat().st_mtime_ns
    except OSError:
        return 1.0
    key = (str(path.resolve()), mtime)
    if key not in _SCALES:
        from ..config import load_toml

        _SCALES[key] = float(load_toml(path).get("scale", 1.0))
    return _SCALES[key]


_SCALES: dict[tuple[str, int], float] = {}


def depth_unit(capture_dir: str | os.PathLike) -> float:
    """Metres per count of the capture's depth maps: 1 mm times :func:`capture_scale`."""
    return 0.001 * capture_scale(capture_dir)


def save_depth_map(capture_dir: str | os.PathLike, camera: str, frame: int, depth) -> Path:
    """Write ``gt/depth/<camera>/<frame:06d>.png`` (uint16 in :func:`depth_unit`: millimetres
    for a human-sized scene; 0 = no hit).

    Parameters
    ----------
    depth : (H, W) float ndarray
        Metres, NaN where nothing is hit; clipped to [1, 65535] units.
    """
    d = np.asarray(depth, np.float64)
    if d.ndim != 2:
        raise ValidationError(f"depth: expected shape (H, W), got {d.shape}")
    unit = depth_unit(capture_dir)
    per = 1000.0 if unit == 0.001 else 1.0 / unit  # the human-scale case exactly as before
    mm = np.where(np.isfinite(d), np.clip(np.rint(d * per), 1, 65535), 0).astype(np.uint16)
    path = _map_path(capture_dir, "depth", camera, frame)
    _write_png(path, mm)
    return path


def label_map_path(capture_dir: str | os.PathLike, camera: str, frame: int) -> Path:
    """``<capture>/gt/labels/<camera>/<frame:06d>.png``, the file :func:`load_label_map` reads."""
    return _map_path(capture_dir, "labels", camera, frame)


def load_label_map(capture_dir: str | os.PathLike, camera: str, frame: int) -> np.ndarray:
    """The ground-truth label map of one image.

    Parameters
    ----------
    capture_dir : path-like
    camera : str
        Camera name.
    frame : int

    Returns
    -------
    (H, W) int16 ndarray
        Class index into labels.toml, -1 = background.

    Raises
    ------
    FileFormatError
        If the map is missing or not a uint8 PNG.
    """
    return _load_index_map(label_map_path(capture_dir, camera, frame))


def load_depth_map(capture_dir: str | os.PathLike, camera: str, frame: int) -> np.ndarray:
    """The ground-truth depth map of one image.

    Parameters
    ----------
    capture_dir : path-like
    camera : str
        Camera name.
    frame : int

    Returns
    -------
    (H, W) float32 ndarray
        Camera-frame z in metres (:func:`depth_unit` resolution: 1 mm on a human-sized scene),
        NaN where nothing is hit.

    Raises
    ------
    FileFormatError
        If the map is missing or not a uint16 PNG.
    """
    mm = _read_png(_map_path(capture_dir, "depth", camera, frame), np.uint16)
    out = mm.astype(np.float32) * np.float32(depth_unit(capture_dir))
    out[mm == 0] = np.nan
    return out


# -- trajectories ----------------------------------------------------------------------------
def frame_file(capture_dir: str | os.PathLike, frame: int) -> Path:
    """``gt/frames/<frame:06d>.npz``: the completeness marker and data of one frame."""
    return Path(capture_dir) / "gt" / "frames" / f"{int(frame):06d}.npz"


def save_points(
    capture_dir: str | os.PathLike,
    points: GroundTruthPoints,
    *,
    class_names: list[str],
    camera_names: list[str],
    geometry_names: list[str],
    fps: float,
    num_frames: int,
) -> Path:
    """Write ``gt/points.npz`` (the static description of the ground-truth points)."""
    path = Path(capture_dir) / "gt" / "points.npz"
    save_npz_atomic(
        path,
        compress=True,
        format_version=np.int64(GT_FORMAT_VERSION),
        geometry=points.geometry,
        local=points.local,
        label=points.label,
        instance=points.instance,
        color=points.color,
        class_names=np.array(class_names, dtype=str),
        camera_names=np.array(camera_names, dtype=str),
        geometry_names=np.array(geometry_names, dtype=str),
        fps=np.float64(fps),
        num_frames=np.int64(num_frames),
    )
    return path


def save_frame(capture_dir: str | os.PathLike, frame: int, xyz, visible) -> Path:
    """Write ``gt/frames/<frame:06d>.npz`` with ``xyz`` (M, 3) and ``visible`` (M, C)."""
    path = frame_file(capture_dir, frame)
    save_npz_atomic(
        path,
        compress=True,
        xyz=np.asarray(xyz, np.float32),
        visible=np.asarray(visible, bool),
    )
    return path


def _load_npz(path: Path, need: list[str]) -> dict[str, np.ndarray]:
    return load_npz(path, need, "a ground-truth file")


@dataclass(eq=False)
class GroundTruth:
    """Ground-truth trajectories of a synthetic capture.

    Attributes
    ----------
    xyz : (M, T, 3) float32 ndarray
        World positions, metres (NaN where the point does not exist).
    visible : (M, T, C) bool ndarray
        In front of camera c, inside its image and unoccluded.
    label : (M,) int64 ndarray
        Class index into labels.toml.
    instance : (M,) int64 ndarray
    class_names : list of str
    camera_names : list of str
    fps : float
    color : (M, 3) uint8 ndarray
        Texture albedo at each point.
    geometry : (M,) int64 ndarray
        Scene geometry (part) index of each point.
    geometry_names : list of str
        Names of the scene's geometries (``person0/left_hand``, ``ball``, ...).
    """

    xyz: np.ndarray
    visible: np.ndarray
    label: np.ndarray
    instance: np.ndarray
    class_names: list[str]
    camera_names: list[str]
    fps: float
    color: np.ndarray
    geometry: np.ndarray
    geometry_names: list[str]

    @property
    def num_points(self) -> int:
        """M."""
        return int(self.xyz.shape[0])

    @property
    def num_frames(self) -> int:
        """T."""
        return int(self.xyz.shape[1])

    def segments(self, min_visible: int = 2) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Maximal runs of frames where a point is seen by at least ``min_visible`` cameras.

        Returns
        -------
        point : (S,) int64 ndarray
            Point index of each run, in the order of :meth:`to_trajectories`.
        first_frame : (S,) int64 ndarray
        length : (S,) int64 ndarray
        """
        ok = (self.visible.sum(axis=2) >= int(min_visible)) & np.all(
            np.isfinite(self.xyz), axis=2
        )  # (M, T)
        M, T = ok.shape
        pad = np.zeros((M, T + 2), bool)
        pad[:, 1:-1] = ok
        step = np.diff(pad.astype(np.int8), axis=1)  # (M, T + 1)
        sm, st = np.nonzero(step == 1)  # run starts, row-major (point, then frame)
        em, et = np.nonzero(step == -1)  # run ends (exclusive)
        return sm.astype(np.int64), st.astype(np.int64), (et - st).astype(np.int64)

    def to_trajectories(self, min_visible: int = 2) -> Trajectories:
        """The ground truth as a ragged :class:`Trajectories` store.

        A point becomes one trajectory per maximal run of frames in which at least
        ``min_visible`` cameras see it (so trajectory k is point ``segments()[0][k]``);
        visibility is 1.0 where visible, reprojection error 0, colour the texture albedo.

        Parameters
        ----------
        min_visible : int

        Returns
        -------
        Trajectories
        """
        point, first, length = self.segments(min_visible)
        if len(point) == 0:
            return Trajectories.empty(self.camera_names, self.fps, self.num_frames)
        rows_pt = np.repeat(point, length)  # (P,)
        starts = np.concatenate([[0], np.cumsum(length)[:-1]])
        rows_t = np.arange(int(length.sum())) - np.repeat(starts - first, length)  # (P,)
        return Trajectories(
            first_frame=first,
            offsets=np.concatenate([[0], np.cumsum(length)]),
            xyz=self.xyz[rows_pt, rows_t],
            visibility=quantize_visibility(self.visible[rows_pt, rows_t].astype(np.float32)),
            reprojection_error=np.zeros(len(rows_pt), np.float32),
            color=self.color[rows_pt],
            camera_names=list(self.camera_names),
            fps=self.fps,
            num_frames=self.num_frames,
        )


def load_ground_truth(capture_dir: str | os.PathLike) -> GroundTruth:
    """Load the ground truth of a synthetic capture (``<capture_dir>/gt/``).

    Parameters
    ----------
    capture_dir : path-like
        A folder written by ``pointtraj synth``.

    Returns
    -------
    GroundTruth

    Raises
    ------
    FileFormatError
        If ``gt/points.npz`` or a frame file is missing or malformed (an unfinished render).
    """
    root = Path(capture_dir)
    meta = _load_npz(
        root / "gt" / "points.npz",
        ["geometry", "local", "label", "instance", "class_names", "camera_names", "num_frames"],
    )
    M = int(meta["geometry"].shape[0])
    T = int(meta["num_frames"])
    C = int(meta["camera_names"].shape[0])
    xyz = np.full((M, T, 3), np.nan, np.float32)
    visible = np.zeros((M, T, C), bool)
    for t in range(T):
        path = frame_file(root, t)
        if not path.is_file():
            raise FileFormatError(
                path, f"ground truth of frame {t} is missing (the render is unfinished)"
            )
        fr = _load_npz(path, ["xyz", "visible"])
        if fr["xyz"].shape != (M, 3) or fr["visible"].shape != (M, C):
            raise FileFormatError(
                path,
                f"expected xyz ({M}, 3) and visible ({M}, {C}), got {fr['xyz'].shape} and "
                f"{fr['visible'].shape}",
            )
        xyz[:, t] = fr["xyz"]
        visible[:, t] = fr["visible"]
    return GroundTruth(
        xyz=xyz,
        visible=visible,
        label=meta["label"].astype(np.int64),
        instance=meta["instance"].astype(np.int64),
        class_names=[str(s) for s in meta["class_names"]],
        camera_names=[str(s) for s in meta["camera_names"]],
        fps=float(meta.get("fps", 30.0)),
        color=meta.get("color", np.full((M, 3), 200, np.uint8)).astype(np.uint8),
        geometry=meta["geometry"].astype(np.int64),
        geometry_names=[str(s) for s in meta.get("geometry_names", [])],
    )


@dataclass(eq=False)
class SegmentTruth:
    """Exact part poses and joint centres of a synthetic capture's figures.

    Attributes
    ----------
    part_label : (G,) int64 ndarray
        Class of each labelled part (geometry).
    part_instance : (G,) int64 ndarray
        Its instance (figure) id.
    part_poses : (G, T, 4, 4) float64 ndarray
        Local-to-world matrix of each part at each frame.
    joint_names : list of J str
        :data:`pointtraj.labelset.BODY_JOINTS` names, per figure.
    joint_instance : (J,) int64 ndarray
    joints : (J, T, 3) float64 ndarray
        World joint centres: the origin of the child part's local frame (every part's local
        origin is its proximal joint, :mod:`pointtraj.synth.figure`).
    """

    part_label: np.ndarray
    part_instance: np.ndarray
    part_poses: np.ndarray
    joint_names: list[str]
    joint_instance: np.ndarray
    joints: np.ndarray


def segment_ground_truth(capture_dir: str | os.PathLike) -> SegmentTruth:
    """The exact part poses and joint centres of a synthetic capture, from its generator.

    The scene is rebuilt from ``gt/synth.toml`` (scene, seed, frames, fps) and posed at every
    frame's time ``t / fps``, as the renderer posed it.

    Parameters
    ----------
    capture_dir : path-like
        A folder written by ``pointtraj synth``.

    Returns
    -------
    SegmentTruth

    Raises
    ------
    FileFormatError
        If ``gt/synth.toml`` is missing or lacks a key.
    """
    from ..config import load_toml
    from ..labelset import BODY_JOINTS
    from .scenes import make_scene, scale_scene

    path = Path(capture_dir) / "gt" / "synth.toml"
    doc = load_toml(path)
    missing = [k for k in ("scene", "seed", "frames", "fps") if k not in doc]
    if missing:
        raise FileFormatError(path, f"missing key {missing[0]!r}")
    scene = make_scene(str(doc["scene"]), int(doc["seed"]))
    if "scale" in doc:  # a scaled scene (pointtraj synth --scale), at the preset's target
        from .presets import PRESETS

        target = PRESETS[str(doc["preset"])].target
        scene = scale_scene(scene, float(doc["scale"]), target)
    T, fps = int(doc["frames"]), float(doc["fps"])
    parts = np.flatnonzero(
        [g.label >= 0 and scene.class_kinds[g.label] == "body" for g in scene.geometries]
    )
    poses = np.stack([scene.poses(t / fps)[parts] for t in range(T)], axis=1)  # (G, T, 4, 4)
    label = np.array([scene.geometries[g].label for g in parts], np.int64)
    inst = np.array([scene.geometries[g].instance for g in parts], np.int64)
    where = {(scene.class_names[k], i): n for n, (k, i) in enumerate(zip(label, inst))}
    names, insts, joints = [], [], []
    for person in sorted(set(inst.tolist())):
        for jn, parent, child in BODY_JOINTS:
            if (parent, person) in where and (child, person) in where:
                names.append(jn)
                insts.append(person)
                joints.append(poses[where[(child, person)], :, :3, 3])
    return SegmentTruth(
        part_label=label,
        part_instance=inst,
        part_poses=poses,
        joint_names=names,
        joint_instance=np.array(insts, np.int64),
        joints=np.array(joints, np.float64).reshape(len(names), T, 3),
    )
