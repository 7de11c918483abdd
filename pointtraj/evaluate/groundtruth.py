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
]

logger = logging.getLogger(__name__)


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


def surface_distance(cam, depth_map: np.ndarray, xyz: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    """Distance of points to the surface that one camera's ground-truth depth map sees.

    The depth map's 3x3 pixels around each projection are back-projected; where they are all
    on the surface and form a smooth patch (depth spread below 5 % of the depth), the distance is
    to the plane fitted through them, otherwise to the nearest of them. Point-to-plane removes
    the bias of the distance to the nearest sample, which is a sizeable part of a pixel's
    footprint (6 mm at 2.4 m for f = 380 px).

    Parameters
    ----------
    cam : Camera
    depth_map : (H, W) float ndarray
        Depth along the optical axis (m); NaN where no surface.
    xyz : (N, 3) float ndarray
        World points.
    pixels : (N, 2) float ndarray
        Their projections in ``cam``.

    Returns
    -------
    (N,) float64 ndarray
        Metres; NaN where the window holds no surface.
    """
    H, W = depth_map.shape
    d = np.arange(-1, 2)
    u = np.rint(pixels[:, 0]).astype(np.int64)[:, None, None] + d[None, None, :]  # (N, 1, 3)
    v = np.rint(pixels[:, 1]).astype(np.int64)[:, None, None] + d[None, :, None]  # (N, 3, 1)
    u, v = np.broadcast_arrays(u.clip(0, W - 1), v.clip(0, H - 1))  # (N, 3, 3)
    z = depth_map[v, u].reshape(len(xyz), 9).astype(np.float64)  # (N, 9)
    pix = np.stack([u, v], axis=-1).reshape(len(xyz), 9, 2).astype(np.float64)
    finite = np.isfinite(z)
    pts = _backproject(cam, pix, np.where(finite, z, 1.0))  # (N, 9, 3)
    diff = pts - xyz[:, None, :].astype(np.float64)
    dist = np.where(finite, np.linalg.norm(diff, axis=2), np.inf)
    nearest = dist.min(axis=1)  # (N,)
    zf = np.where(finite, z, np.nan)
    smooth = finite.all(axis=1)  # (N,) a whole window on the surface ...
    if smooth.any():  # ... whose depths spread little: a smooth patch
        zs = zf[smooth]
        smooth[smooth] = (zs.max(axis=1) - zs.min(axis=1)) < 0.05 * zs.min(axis=1)
    out = np.where(np.isfinite(nearest), nearest, np.nan)
    if smooth.any():
        p = pts[smooth]  # (S, 9, 3)
        centre = p.mean(axis=1)  # (S, 3)
        q = p - centre[:, None]
        _, vecs = np.linalg.eigh(np.einsum("ski,skj->sij", q, q))  # ascending eigenvalues
        normal = vecs[:, :, 0]  # (S, 3)
        plane = np.abs(np.einsum("si,si->s", xyz[smooth] - centre, normal))
        out[smooth] = np.minimum(plane, nearest[smooth])
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
    from ..synth.groundtruth import load_depth_map

    xyz = np.asarray(xyz, np.float64)
    proj = rig.project(xyz) if projection is None else projection
    use = proj.in_image if use is None else use
    err = np.full(len(xyz), np.inf)
    for c, cam in enumerate(rig):
        if use[c].any():
            dm = load_depth_map(capture, cam.name, frame)
            e = surface_distance(cam, dm, xyz[use[c]], proj.pixels[c][use[c]])
            err[use[c]] = np.fmin(err[use[c]], e)
    return np.where(np.isfinite(err), err, np.nan)


def surface_errors(
    capture: str | os.PathLike,
    rig,
    trajectories: Trajectories,
    frames: range | None = None,
    min_visibility: float = 0.5,
    progress: Callable[[int], None] | None = None,
) -> np.ndarray:
    """Distance of each point-frame to the ground-truth surface of its frame.

    For each camera in which a point is visible (visibility above ``min_visibility``; all
    cameras whose image it projects into when there is none), :func:`surface_distance` to the
    surface that camera's depth map sees; the point's error is the smallest over those cameras
    (each is an upper bound of the distance to the whole surface).

    Parameters
    ----------
    capture : path-like
    rig : CameraRig
        The cameras of ``trajectories``, in its order.
    trajectories : Trajectories
    frames : range, optional
        Frames to measure (default: all).
    min_visibility : float
    progress : callable, optional
        Called with 1 after each frame.

    Returns
    -------
    (P',) float64 ndarray
        Metres, for the point-frames of ``frames`` in frame order (NaN where no camera's depth
        map has surface near the point's projection).
    """
    from ..trajectories import dequantize_visibility

    frames = range(trajectories.num_frames) if frames is None else frames
    out = []
    for t in frames:
        rows = trajectories.frame_rows(t)
        if len(rows):
            xyz = trajectories.xyz[rows].astype(np.float64)  # (N, 3)
            proj = rig.project(xyz)
            use = proj.in_image & (
                dequantize_visibility(trajectories.visibility[rows]).T > min_visibility
            )
            use |= proj.in_image & ~use.any(axis=0)[None]  # (C, N): no visible camera: all
            out.append(frame_surface_errors(capture, rig, t, xyz, use, projection=proj))
        if progress is not None:
            progress(1)
    return np.concatenate(out) if out else np.zeros(0)
