"""Ground truth of a synthetic capture, turned into per-trajectory truths for evaluation.

A synthetic capture (``pointtraj synth``) holds per image a label map and a depth map, plus the
ground-truth surface trajectories (``data_specs/groundtruth.md``). Reconstructed trajectories
are not those points, so each gets a truth from the maps: its label is the majority of the label
maps at its visible projections (:func:`voted_labels`), and its 3D error is the distance to the
surface that the depth maps see (:func:`surface_errors`). Work folders whose store
is the ground truth itself (``trajectories = "ground_truth"``) take the points' own labels
(:func:`true_labels`).
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable
from pathlib import Path

import numpy as np

from ..errors import ValidationError
from ..trajectories import Trajectories

__all__ = [
    "has_ground_truth",
    "true_labels",
    "true_instances",
    "voted_labels",
    "surface_distance",
    "frame_surface_errors",
    "surface_errors",
    "SceneSurface",
]

logger = logging.getLogger(__name__)

#: A depth-map neighbour is on the centre pixel's surface when its depth differs from the
#: centre's by at most this many pixel footprints (``z / f``): a smooth surface seen at up to
#: 80 degrees of incidence changes by tan(80 deg) * sqrt(2) = 8 footprints to a diagonal
#: neighbour (:func:`surface_distance`).
SURFACE_DEPTH_STEP_PX = 8.0


def has_ground_truth(capture: str | os.PathLike) -> bool:
    """Whether ``capture`` is a synthetic capture with ground truth (``gt/points.npz``)."""
    return (Path(capture) / "gt" / "points.npz").is_file()


def voted_labels(
    capture: str | os.PathLike,
    trajectories: Trajectories,
    min_visibility: float = 0.5,
    progress: Callable[[int], None] | None = None,
    maps: str = "labels",
) -> np.ndarray:
    """Majority ground-truth label (or instance) at each trajectory's visible projections.

    Parameters
    ----------
    capture : path-like
        A synthetic capture (with ``gt/labels``).
    trajectories : Trajectories
        Cameras named as in the capture's rig.
    min_visibility : float
        A projection votes where the trajectory's visibility in that camera exceeds this.
    progress : callable, optional
        Called with 1 after each frame.
    maps : {"labels", "instances"}
        Vote with the label maps (classes) or the instance maps (figure / object ids).

    Returns
    -------
    (M,) int64 ndarray
        Class index (instance id); -1 where the majority is the background, -2 where no camera
        votes.
    """
    from ..npzfile import load_npz
    from ..session import Capture
    from ..synth.groundtruth import load_instance_map, load_label_map

    capture = Path(capture)
    rig = Capture.open(capture).rig.subset(trajectories.camera_names)
    points = load_npz(capture / "gt" / "points.npz", ["class_names", "instance"])
    if maps == "labels":
        K = int(points["class_names"].shape[0])
        load_map = load_label_map
    elif maps == "instances":
        K = int(points["instance"].max(initial=-1)) + 1
        load_map = load_instance_map
    else:
        raise ValidationError(f"maps: 'labels' or 'instances', got {maps!r}")
    votes = np.zeros((trajectories.num_trajectories, K + 1))  # column 0: background
    for t in range(trajectories.num_frames):
        fs = trajectories.frame(t)
        if len(fs.track_id):
            proj = rig.project(fs.xyz)
            for c, name in enumerate(rig.names):
                ok = proj.in_image[c] & (fs.visibility[:, c] > min_visibility)  # (N,)
                if not ok.any():
                    continue
                lm = load_map(capture, name, t)  # (H, W) int, -1 background
                px = np.rint(proj.pixels[c][ok]).astype(np.int64)  # (N', 2)
                u = px[:, 0].clip(0, lm.shape[1] - 1)
                v = px[:, 1].clip(0, lm.shape[0] - 1)
                np.add.at(votes, (fs.track_id[ok], lm[v, u] + 1), 1)
        if progress is not None:
            progress(1)
    truth = votes.argmax(axis=1) - 1
    truth[votes.sum(axis=1) == 0] = -2
    return truth


def true_labels(
    capture: str | os.PathLike,
    trajectories: Trajectories,
    progress: Callable[[int], None] | None = None,
) -> tuple[np.ndarray, str]:
    """The ground-truth class of every trajectory.

    Parameters
    ----------
    capture : path-like
        A synthetic capture.
    trajectories : Trajectories
    progress : callable, optional
        Per frame, for :func:`voted_labels`.

    Returns
    -------
    labels : (M,) int64 ndarray
        Class index; negative for trajectories on the background or never seen.
    source : {"ground truth", "voted"}
        ``"ground truth"`` when the store is the capture's ground-truth trajectories (each is a
        labelled surface point), ``"voted"`` when the labels come from :func:`voted_labels`.
    """
    from ..synth.groundtruth import load_ground_truth

    gt = load_ground_truth(capture)
    if list(trajectories.camera_names) == list(gt.camera_names):
        ref = gt.to_trajectories()
        if (
            ref.num_trajectories == trajectories.num_trajectories
            and np.array_equal(ref.offsets, trajectories.offsets)
            and np.array_equal(ref.first_frame, trajectories.first_frame)
            and np.allclose(ref.xyz, trajectories.xyz, atol=1e-6)
        ):
            return gt.label[gt.segments()[0]].astype(np.int64), "ground truth"
    return voted_labels(capture, trajectories, progress=progress), "voted"


def true_instances(
    capture: str | os.PathLike,
    trajectories: Trajectories,
    progress: Callable[[int], None] | None = None,
    truth: tuple[np.ndarray, str] | None = None,
) -> tuple[np.ndarray, str]:
    """The ground-truth person of every trajectory.

    Parameters
    ----------
    capture : path-like
        A synthetic capture.
    trajectories : Trajectories
    progress : callable, optional
        Per frame, for :func:`voted_labels`.
    truth : (labels, source), optional
        :func:`true_labels` of the same store, when the caller has it already.

    Returns
    -------
    instance : (M,) int64 ndarray
        The figure's instance id of trajectories on a figure (a body-part class); -1 elsewhere
        (background, objects, never seen).
    source : {"ground truth", "voted"}
        As :func:`true_labels`: exact for the capture's ground-truth trajectories, else the
        majority of the instance maps (``gt/instances``) at the visible projections.
    """
    from ..labelset import LabelSet
    from ..synth.groundtruth import load_ground_truth

    gt = load_ground_truth(capture)
    labels, source = truth or true_labels(capture, trajectories, progress=progress)
    kinds = np.array(LabelSet.load(Path(capture) / "labels.toml").kinds)
    if source == "ground truth":
        instance = gt.instance[gt.segments()[0]].astype(np.int64)
    else:
        instance = voted_labels(capture, trajectories, progress=progress, maps="instances")
    on_figure = (labels >= 0) & (kinds[np.maximum(labels, 0)] == "body")
    return np.where(on_figure & (instance >= 0), instance, -1), source


def _backproject(cam, pixels: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """(..., 3) world points of ``pixels`` (..., 2) at camera depths ``depth`` (...)."""
    from ..camera import CameraRig

    shape = pixels.shape[:-1]
    xy = CameraRig([cam]).normalized(pixels.reshape(1, -1, 2))[0].reshape(*shape, 2)
    cam_pts = np.concatenate([xy * depth[..., None], depth[..., None]], axis=-1)  # (..., 3)
    return cam_pts @ cam.R + cam.C  # R^T x_cam + C


def surface_distance(
    cam,
    depth_map: np.ndarray,
    xyz: np.ndarray,
    pixels: np.ndarray,
    label_map: np.ndarray | None = None,
) -> np.ndarray:
    """Distance of points to the surface that one camera's ground-truth depth map sees.

    The depth map's 3x3 pixels around each projection are back-projected. The distance is the
    smaller of two:

    * to the nearest of those samples (each is a point of the true surface, so this is an upper
      bound of the distance to it);
    * to the patch of the samples **on the centre pixel's surface**: the centre pixel (where
      the point projects) and those neighbours whose depth is within
      :data:`SURFACE_DEPTH_STEP_PX` pixel footprints (``z / f``) of the centre's and, with a
      label map, whose ground-truth label is the centre's; at least 3 of them, not on one
      line. The patch is the disc of the plane fitted through them, centred on their mean,
      that reaches the farthest of them. Point-to-patch removes the bias of the distance to
      the nearest sample, which is a sizeable part of a pixel's footprint (6 mm at 2.4 m for
      f = 380 px).

    A window across a silhouette (the figure's edge over the floor, an arm over the torso) thus
    never mixes two surfaces into one plane, and a point beside a limb, whose ray grazes it,
    is not measured to the limb's tangent plane beyond the limb (issue #17: the former test
    fitted one unbounded plane to the whole window when its depths spread less than 5 %).

    Parameters
    ----------
    cam : Camera
    depth_map : (H, W) float ndarray
        Depth along the optical axis (m); NaN where no surface.
    xyz : (N, 3) float ndarray
        World points.
    pixels : (N, 2) float ndarray
        Their projections in ``cam``.
    label_map : (H, W) int ndarray, optional
        The ground-truth label map of the same view (class index, -1 background).

    Returns
    -------
    (N,) float64 ndarray
        Metres; NaN where the window holds no surface.
    """
    H, W = depth_map.shape
    N = len(xyz)
    d = np.arange(-1, 2)
    u = np.rint(pixels[:, 0]).astype(np.int64)[:, None, None] + d[None, None, :]  # (N, 1, 3)
    v = np.rint(pixels[:, 1]).astype(np.int64)[:, None, None] + d[None, :, None]  # (N, 3, 1)
    u, v = np.broadcast_arrays(u.clip(0, W - 1), v.clip(0, H - 1))  # (N, 3, 3)
    z = depth_map[v, u].reshape(N, 9).astype(np.float64)  # (N, 9); column 4 is the centre
    pix = np.stack([u, v], axis=-1).reshape(N, 9, 2).astype(np.float64)
    finite = np.isfinite(z)
    pts = _backproject(cam, pix, np.where(finite, z, 1.0))  # (N, 9, 3)
    xyz = np.asarray(xyz, np.float64)
    dist = np.where(finite, np.linalg.norm(pts - xyz[:, None, :], axis=2), np.inf)
    nearest = dist.min(axis=1)  # (N,) inf where no sample
    zc = z[:, 4:5]  # (N, 1)
    step = SURFACE_DEPTH_STEP_PX * zc / float(cam.K[0, 0])  # (N, 1) metres
    with np.errstate(invalid="ignore"):
        same = finite & np.isfinite(zc) & (np.abs(z - zc) <= step)  # (N, 9)
    if label_map is not None:
        lab = label_map[v, u].reshape(N, 9)
        same &= lab == lab[:, 4:5]
    out = np.where(np.isfinite(nearest), nearest, np.nan)
    fit = same.sum(axis=1) >= 3
    if fit.any():
        w = same[fit].astype(np.float64)[..., None]  # (S, 9, 1)
        p = pts[fit]  # (S, 9, 3)
        centre = (w * p).sum(axis=1) / w.sum(axis=1)  # (S, 3)
        q = (p - centre[:, None]) * w
        vals, vecs = np.linalg.eigh(np.einsum("ski,skj->sij", q, q))  # ascending eigenvalues
        normal = vecs[:, :, 0]  # (S, 3)
        off = xyz[fit] - centre  # (S, 3)
        signed = np.einsum("si,si->s", off, normal)  # (S,)
        # The plane stands for the surface only over the patch: the distance is to a disc of
        # the samples' reach about their centre (a ray grazing a limb's silhouette lies almost
        # in its tangent plane; beyond the patch the surface has curved away).
        foot = np.linalg.norm(off - signed[:, None] * normal, axis=1)  # (S,)
        reach = np.sqrt(np.max(np.sum(q * q, axis=2), axis=1))  # (S,) weights are 0 or 1
        disc = np.hypot(signed, np.maximum(foot - reach, 0.0))  # (S,)
        flat = vals[:, 1] > 0.01 * vals[:, 2]  # a patch, not samples on one line
        idx = np.flatnonzero(fit)[flat]
        out[idx] = np.minimum(disc[flat], nearest[idx])
    return out


def frame_surface_errors(
    capture: str | os.PathLike,
    rig,
    frame: int,
    xyz: np.ndarray,
    use: np.ndarray | None = None,
    projection=None,
) -> np.ndarray:
    """Distance of one frame's points to its ground-truth surface, over chosen cameras.

    Parameters
    ----------
    capture : path-like
    rig : CameraRig
        C cameras.
    frame : int
    xyz : (N, 3) float ndarray
    use : (C, N) bool ndarray, optional
        The cameras whose depth map measures each point (default: every camera whose image it
        projects into).
    projection : Projection, optional
        ``rig.project(xyz)`` when the caller has it.

    Returns
    -------
    (N,) float64 ndarray
        Metres: the smallest :func:`surface_distance` over the point's cameras (each is an
        upper bound of the distance to the whole surface); NaN where none has surface near it.
    """
    from ..synth.groundtruth import load_depth_map, load_label_map

    xyz = np.asarray(xyz, np.float64)
    proj = rig.project(xyz) if projection is None else projection
    use = proj.in_image if use is None else use
    err = np.full(len(xyz), np.inf)
    for c, cam in enumerate(rig):
        if use[c].any():
            dm = load_depth_map(capture, cam.name, frame)
            lm = load_label_map(capture, cam.name, frame)
            e = surface_distance(cam, dm, xyz[use[c]], proj.pixels[c][use[c]], lm)
            err[use[c]] = np.fmin(err[use[c]], e)
    return np.where(np.isfinite(err), err, np.nan)


def surface_errors(
    capture: str | os.PathLike,
    rig,
    trajectories: Trajectories,
    frames: range | None = None,
    progress: Callable[[int], None] | None = None,
) -> np.ndarray:
    """Distance of each point-frame to the ground-truth surface of its frame.

    For each camera whose image the point projects into, :func:`surface_distance` to the
    surface that camera's depth map sees; the point's error is the smallest over those cameras.
    Each camera's figure is a distance to a true surface (of samples, or of a patch of them),
    so each bounds the distance to the whole surface from above; a camera that does not see
    the point (an occluder in front, a figure's far side) only adds surfaces to measure to.
    Before issue #17 only the cameras the point is visible in counted: on the demo 32 of its
    11,460 point-frames of every third frame then had no surface near, against 1 now, and the
    figure agreed less with the exact distance to the scene's meshes (within 2 mm for 85 %
    of the point-frames, against 90 % now; ``benchmarks/study_surface_error.py``).

    Parameters
    ----------
    capture : path-like
    rig : CameraRig
        The cameras of ``trajectories``, in its order.
    trajectories : Trajectories
    frames : range, optional
        Frames to measure (default: all).
    progress : callable, optional
        Called with 1 after each frame.

    Returns
    -------
    (P',) float64 ndarray
        Metres, for the point-frames of ``frames`` in frame order (NaN where no camera's depth
        map has surface near the point's projection).
    """
    frames = range(trajectories.num_frames) if frames is None else frames
    out = []
    for t in frames:
        rows = trajectories.frame_rows(t)
        if len(rows):
            xyz = trajectories.xyz[rows].astype(np.float64)  # (N, 3)
            out.append(frame_surface_errors(capture, rig, t, xyz))
        if progress is not None:
            progress(1)
    return np.concatenate(out) if out else np.zeros(0)


class SceneSurface:
    """The true surface of a synthetic capture: its scene's meshes, posed frame by frame.

    An independent check of :func:`surface_errors`: the exact distance of points to the nearest
    triangle of every mesh of the scene (figures, objects, floor) at a frame, with
    ``open3d.t.geometry.RaycastingScene.compute_distance``. The scene is rebuilt from the
    capture's ``gt/synth.toml`` (scene, seed, fps), as ``pointtraj synth`` made it.

    Parameters
    ----------
    capture : path-like
        A synthetic capture (``gt/synth.toml``).

    Raises
    ------
    FileFormatError
        If ``gt/synth.toml`` is missing or lacks ``scene``, ``seed`` or ``fps``.
    """

    def __init__(self, capture: str | os.PathLike) -> None:
        from ..config import load_toml
        from ..errors import FileFormatError
        from ..session import Capture
        from ..synth.render import Renderer
        from ..synth.scenes import make_scene

        path = Path(capture) / "gt" / "synth.toml"
        if not path.is_file():
            raise FileFormatError(path, "no such file (not a synthetic capture)")
        made = load_toml(path)
        missing = [k for k in ("scene", "seed", "fps") if k not in made]
        if missing:
            raise FileFormatError(path, f"missing {', '.join(missing)}")
        self.fps = float(made["fps"])
        self.scene = make_scene(str(made["scene"]), int(made["seed"]))
        self._renderer = Renderer(self.scene, Capture.open(capture).rig)

    def distance(self, frame: int, xyz: np.ndarray) -> np.ndarray:
        """Distance of points to the scene's surface at ``frame``.

        Parameters
        ----------
        frame : int
        xyz : (N, 3) float ndarray
            World points (metres).

        Returns
        -------
        (N,) float64 ndarray
            Metres (float32 precision: well under 1 um at the scale of a room).
        """
        import open3d as o3d

        rs, _ = self._renderer.build_raycasting_scene(self.scene.poses(frame / self.fps))
        q = o3d.core.Tensor(np.ascontiguousarray(np.asarray(xyz, np.float32).reshape(-1, 3)))
        return rs.compute_distance(q).numpy().astype(np.float64)
