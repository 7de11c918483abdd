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
from ..executor import Executor, SerialExecutor
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
    M = trajectories.num_trajectories
    votes = np.zeros(M * (K + 1), np.int64)  # (M, K + 1) flat; column 0: background
    for t in range(trajectories.num_frames):
        fs = trajectories.frame(t)
        if len(fs.track_id):
            proj = rig.project(fs.xyz)
            keys = []  # track * (K + 1) + vote, all the frame's cameras: one bincount
            for c, name in enumerate(rig.names):
                ok = proj.in_image[c] & (fs.visibility[:, c] > min_visibility)  # (N,)
                if not ok.any():
                    continue
                lm = load_map(capture, name, t)  # (H, W) int, -1 background
                px = np.rint(proj.pixels[c][ok]).astype(np.int64)  # (N', 2)
                u = px[:, 0].clip(0, lm.shape[1] - 1)
                v = px[:, 1].clip(0, lm.shape[0] - 1)
                keys.append(fs.track_id[ok].astype(np.int64) * (K + 1) + lm[v, u] + 1)
            if keys:
                votes += np.bincount(np.concatenate(keys), minlength=votes.size)
        if progress is not None:
            progress(1)
    votes = votes.reshape(M, K + 1)
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


#: The 3x3 window of a depth map around a projection: (du, dv) per sample, the centre 4th.
_WINDOW = np.array([(du, dv) for dv in (-1, 0, 1) for du in (-1, 0, 1)], np.int64)  # (9, 2)


def _backproject(cam, u: np.ndarray, v: np.ndarray, depth: np.ndarray) -> tuple[np.ndarray, ...]:
    """World coordinates x, y, z (each shaped as ``u``) of integer pixels ``(u, v)`` at camera
    depths ``depth`` (all the same shape)."""
    from ..camera import CameraRig

    pix = np.stack([u.ravel(), v.ravel()], axis=-1).astype(np.float64)  # (M, 2)
    xy = CameraRig([cam]).normalized(pix[None])[0]  # (M, 2)
    d = depth.ravel()
    cx, cy = xy[:, 0] * d, xy[:, 1] * d  # camera frame (x, y, d)
    R, C = cam.R, cam.C
    # R^T x_cam + C, coordinate by coordinate
    return tuple(
        (R[0, j] * cx + R[1, j] * cy + R[2, j] * d + C[j]).reshape(u.shape) for j in range(3)
    )


def smallest_eigenpairs(
    a: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray, e: np.ndarray, f: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues and the smallest one's eigenvector of symmetric 3x3 matrices, in closed form.

    The matrices are ``[[a, d, f], [d, b, e], [f, e, c]]``, one per element of the (S,)
    arrays. The eigenvalues come from the trigonometric solution of the characteristic cubic;
    the eigenvector is the longest cross product of two rows of ``A - l0 I``. numpy's
    ``linalg.eigh`` calls LAPACK once per matrix, about 30 times slower on millions of them.

    Parameters
    ----------
    a, b, c, d, e, f : (S,) float64 ndarray

    Returns
    -------
    values : (S, 3) float64 ndarray
        Ascending.
    vector : (S, 3) float64 ndarray
        Unit eigenvector of ``values[:, 0]`` (sign arbitrary; zero for the zero matrix).
    """
    q = (a + b + c) / 3.0
    p1 = d * d + e * e + f * f
    aq, bq, cq = a - q, b - q, c - q
    p = np.sqrt((aq * aq + bq * bq + cq * cq + 2.0 * p1) / 6.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        inv = np.where(p > 0, 1.0 / p, 0.0)
        # det((A - q I) / p) / 2, clipped to the cubic's range
        r = (aq * (bq * cq - e * e) - d * (d * cq - e * f) + f * (d * e - bq * f)) * inv**3 / 2
    phi = np.arccos(np.clip(r, -1.0, 1.0)) / 3.0
    l2 = q + 2.0 * p * np.cos(phi)
    l0 = q + 2.0 * p * np.cos(phi + 2.0 * np.pi / 3.0)
    l1 = 3.0 * q - l0 - l2
    values = np.stack([l0, np.clip(l1, l0, l2), l2], axis=1)
    r0 = (a - l0, d, f)
    r1 = (d, b - l0, e)
    r2 = (f, e, c - l0)

    def cross(x, y):
        return (x[1] * y[2] - x[2] * y[1], x[2] * y[0] - x[0] * y[2], x[0] * y[1] - x[1] * y[0])

    best = np.zeros((3, len(a)))
    norm = np.zeros(len(a))
    for x, y in ((r0, r1), (r0, r2), (r1, r2)):
        v = np.stack(cross(x, y))  # (3, S)
        n = np.einsum("ks,ks->s", v, v)
        longer = n > norm
        best[:, longer] = v[:, longer]
        norm = np.where(longer, n, norm)
    with np.errstate(invalid="ignore", divide="ignore"):
        vector = (best / np.where(norm > 0, np.sqrt(norm), 1.0)).T
    return values, vector


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

    The arrays are laid out as (9, N), a row per window sample, so that every step is an
    elementwise operation on contiguous rows, and the plane comes from
    :func:`smallest_eigenpairs` (this is the evaluation's hottest loop: every point-frame in
    every camera it projects into).

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
    xyz = np.asarray(xyz, np.float64)
    u = (np.rint(pixels[:, 0]).astype(np.int64)[None] + _WINDOW[:, :1]).clip(0, W - 1)  # (9, N)
    v = (np.rint(pixels[:, 1]).astype(np.int64)[None] + _WINDOW[:, 1:]).clip(0, H - 1)
    z = depth_map[v, u].astype(np.float64)  # (9, N); row 4 is the centre
    finite = np.isfinite(z)
    px, py, pz = _backproject(cam, u, v, np.where(finite, z, 1.0))  # (9, N) each
    ox, oy, oz = px - xyz[:, 0], py - xyz[:, 1], pz - xyz[:, 2]  # samples less the point
    dist = np.where(finite, np.sqrt(ox * ox + oy * oy + oz * oz), np.inf)
    nearest = dist.min(axis=0)  # (N,) inf where no sample
    zc = z[4]  # (N,)
    step = SURFACE_DEPTH_STEP_PX * zc / float(cam.K[0, 0])  # (N,) metres
    with np.errstate(invalid="ignore"):
        same = finite & np.isfinite(zc) & (np.abs(z - zc) <= step)  # (9, N)
    if label_map is not None:
        lab = label_map[v, u]  # (9, N)
        same &= lab == lab[4]
    out = np.where(np.isfinite(nearest), nearest, np.nan)
    fit = np.flatnonzero(same.sum(axis=0) >= 3)
    if fit.size:
        w = same[:, fit].astype(np.float64)  # (9, S)
        ws = w.sum(axis=0)
        # the patch's samples relative to the point: the plane's distance does not change
        qx, qy, qz = ox[:, fit], oy[:, fit], oz[:, fit]
        mx, my, mz = ((w * g).sum(axis=0) / ws for g in (qx, qy, qz))  # centre less the point
        qx, qy, qz = (qx - mx) * w, (qy - my) * w, (qz - mz) * w
        values, normal = smallest_eigenpairs(
            (qx * qx).sum(axis=0),
            (qy * qy).sum(axis=0),
            (qz * qz).sum(axis=0),
            (qx * qy).sum(axis=0),
            (qy * qz).sum(axis=0),
            (qx * qz).sum(axis=0),
        )
        # the point less the centre
        signed = -(mx * normal[:, 0] + my * normal[:, 1] + mz * normal[:, 2])  # (S,)
        fx = -mx - signed * normal[:, 0]
        fy = -my - signed * normal[:, 1]
        fz = -mz - signed * normal[:, 2]
        foot = np.sqrt(fx * fx + fy * fy + fz * fz)
        # The plane stands for the surface only over the patch: the distance is to a disc of
        # the samples' reach about their centre (a ray grazing a limb's silhouette lies almost
        # in its tangent plane; beyond the patch the surface has curved away).
        reach = np.sqrt((qx * qx + qy * qy + qz * qz).max(axis=0))  # weights are 0 or 1
        disc = np.hypot(signed, np.maximum(foot - reach, 0.0))
        flat = values[:, 1] > 0.01 * values[:, 2]  # a patch, not samples on one line
        idx = fit[flat]
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
    executor: Executor | None = None,
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
    executor : Executor, optional
        Where the frames are measured, one task each (default: serially, here); the workers
        read the capture's depth and label maps from its path.

    Returns
    -------
    (P',) float64 ndarray
        Metres, for the point-frames of ``frames`` in frame order (NaN where no camera's depth
        map has surface near the point's projection).
    """
    frames = range(trajectories.num_frames) if frames is None else frames
    rows = [(t, trajectories.frame_rows(t)) for t in frames]
    occupied = [(t, r) for t, r in rows if len(r)]
    if progress is not None and len(occupied) < len(frames):
        progress(len(frames) - len(occupied))  # frames without points: nothing to measure
    items = ((t, trajectories.xyz[r]) for t, r in occupied)
    executor = executor or SerialExecutor()
    out = []
    for err in executor.map(
        _frame_errors_task,
        items,
        label="3D error",
        total=len(occupied),
        context=(os.fspath(capture), rig),
    ):
        out.append(err)
        if progress is not None:
            progress(1)
    return np.concatenate(out) if out else np.zeros(0)


def _frame_errors_task(context: tuple, item: tuple) -> np.ndarray:
    """One frame of :func:`surface_errors` (an executor task): ``context`` is (capture, rig),
    ``item`` (frame, (N, 3) points)."""
    capture, rig = context
    t, xyz = item
    return frame_surface_errors(capture, rig, int(t), xyz)


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
