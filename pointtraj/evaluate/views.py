"""Ground-truth audit of the views of reconstructed points (issue #20).

Which cameras does the tracker keep for each reconstructed point, against the cameras that
truly see it? On a synthetic capture (``pointtraj synth``) the ground truth holds, per frame,
the world positions of M surface samples of the figures and objects (``gt/frames/<t>.npz``)
and per camera a depth map (``gt/depth``). The definitions (issue #20):

* A reconstructed point-frame is **on an actor** (a figure or the ball) when its nearest
  ground-truth surface sample of that frame (``scipy.spatial.cKDTree``) lies within ``radius``.
* A (point-frame, camera) view is **truly visible** when that camera sees the point's nearest
  ground-truth sample: the sample projects inside the image, in front of the camera, and its
  depth matches the camera's ground-truth depth map at its rounded pixel within ``depth_tol``
  (:func:`true_visibility`). The test is made at the sample, not at the reconstructed point,
  whose 3D error would otherwise count as occlusion.
* A view is **observed** when the point's visibility in that camera (the store's uint8,
  dequantised) exceeds ``visibility_threshold`` (the tracker's
  ``ReconstructConfig.visibility_threshold``).
* **View recall** = observed and truly visible / truly visible; **view precision** = observed
  and truly visible / observed; both over the views of actor point-frames.
* **>= 3-view share**: among actor point-frames whose sample is truly visible in >= 3 cameras,
  the share observed in >= 3 cameras.
* **Two-view share**: the share of all live point-frames observed in exactly 2 cameras.
* **Trajectory length**: median length (point-frames within the audited frames) of the
  trajectories on the actors (more than half of their audited point-frames on an actor);
  against the ground truth's median **visible run**: for each sample, the maximal runs of
  consecutive audited frames in which it is truly visible in >= 2 cameras.
* **3D error** of actor point-frames
  (:func:`pointtraj.evaluate.groundtruth.surface_errors`), split by the number of observed
  views (2, 3, 4+); point-frames with no ground-truth surface near them are counted apart.

The 1 cm depth test is strict on sloped surfaces at coarse resolutions: the pixel centre's ray
meets the surface up to a pixel away from the sample (7 mm at 2.8 m for f = 380 px), which is why
the capture's stored ``visible`` flags widen it to two pixel footprints. On the demo capture
(ring8), 2 cm instead of 1 cm raises the truly visible views per actor point-frame from 3.0 to
3.4 and the view precision from 0.74 to 0.81, and lengthens the median ground-truth visible run
from 7 to 17 frames (a sample that flickers in one camera breaks its run); the report also gives
the runs by the stored flags.

Every figure comes with its support (the count it is a share or a statistic of). The audit
streams frame by frame: one frame's samples and, camera after camera, one depth map at a time.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..trajectories import Trajectories, dequantize_visibility

__all__ = [
    "ViewAudit",
    "OcclusionAudit",
    "FrameTruth",
    "frame_truth",
    "true_visibility",
    "nearest_sample",
    "view_audit",
    "false_occlusion_rate",
]

logger = logging.getLogger(__name__)

#: Buckets of observed views for the 3D error split: label -> (lowest, highest) view count.
VIEW_BUCKETS = {"2": (2, 2), "3": (3, 3), "4+": (4, 1 << 30)}


def _ratio(num: float, den: float) -> float:
    return float(num) / float(den) if den else float("nan")


def _median(a: np.ndarray) -> float:
    return float(np.median(a)) if len(a) else float("nan")


def _percentile(a: np.ndarray, p: float) -> float:
    return float(np.percentile(a, p)) if len(a) else float("nan")


@dataclass(frozen=True)
class FrameTruth:
    """The ground truth of one frame, in a rig's camera order.

    Attributes
    ----------
    xyz : (M', 3) float64 ndarray
        World positions of the samples that exist in this frame.
    index : (M',) int64 ndarray
        Their index among the M samples of ``gt/points.npz``.
    visible : (M', C) bool ndarray
        Truly visible (:func:`true_visibility`).
    in_image : (M', C) bool ndarray
        In front of the camera and inside its image.
    flags : (M', C) bool ndarray
        The capture's stored ``visible`` flags.
    """

    xyz: np.ndarray
    index: np.ndarray
    visible: np.ndarray
    in_image: np.ndarray
    flags: np.ndarray


def true_visibility(
    capture: str | os.PathLike, rig, frame: int, xyz: np.ndarray, depth_tol: float = 0.01
) -> tuple[np.ndarray, np.ndarray]:
    """Which cameras truly see ground-truth surface samples.

    A sample is truly visible in a camera when it projects inside the image, in front of the
    camera, and its camera-frame depth is within ``depth_tol`` of the ground-truth depth map
    (``gt/depth``, 1 mm resolution) at its rounded pixel. Unlike the capture's stored
    ``visible`` flags (:func:`pointtraj.synth.groundtruth.visibility_exact`, which also check
    the part seen at the pixel and widen the tolerance to two pixel footprints), this needs only
    the depth maps.

    Parameters
    ----------
    capture : path-like
        A synthetic capture.
    rig : CameraRig
        C cameras of the capture.
    frame : int
    xyz : (M, 3) float ndarray
        Surface samples (world, metres).
    depth_tol : float
        Metres.

    Returns
    -------
    visible : (M, C) bool ndarray
    in_image : (M, C) bool ndarray
    """
    from ..synth.groundtruth import load_depth_map

    proj = rig.project(np.asarray(xyz, np.float64))
    visible = np.zeros(proj.in_image.shape[::-1], bool)  # (M, C)
    for c, cam in enumerate(rig):
        ok = np.flatnonzero(proj.in_image[c])
        if not len(ok):
            continue
        dm = load_depth_map(capture, cam.name, frame)  # (H, W), NaN = no hit
        h, w = dm.shape
        u = np.clip(np.rint(proj.pixels[c, ok, 0]).astype(np.int64), 0, w - 1)
        v = np.clip(np.rint(proj.pixels[c, ok, 1]).astype(np.int64), 0, h - 1)
        with np.errstate(invalid="ignore"):
            visible[ok, c] = np.abs(dm[v, u] - proj.depth[c, ok]) <= depth_tol
    return visible, proj.in_image.T.copy()


def _gt_camera_order(capture: Path, names: list[str]) -> np.ndarray:
    """(C,) column of each of ``names`` in the ground truth's ``visible`` flags."""
    from ..errors import ValidationError
    from ..npzfile import load_npz

    gt_names = [
        str(s) for s in load_npz(capture / "gt" / "points.npz", ["camera_names"])["camera_names"]
    ]
    missing = [n for n in names if n not in gt_names]
    if missing:
        raise ValidationError(f"cameras {missing} are not in the capture's ground truth")
    return np.array([gt_names.index(n) for n in names], np.int64)


def frame_truth(
    capture: str | os.PathLike,
    rig,
    frame: int,
    depth_tol: float = 0.01,
    columns: np.ndarray | None = None,
) -> FrameTruth:
    """Load one frame's ground-truth samples and measure their true visibility.

    Parameters
    ----------
    capture : path-like
    rig : CameraRig
        C cameras of the capture, in the order wanted.
    frame : int
    depth_tol : float
        Metres, for :func:`true_visibility`.
    columns : (C,) int ndarray, optional
        Column of each of ``rig``'s cameras in the stored flags (default: looked up).

    Returns
    -------
    FrameTruth
    """
    from ..npzfile import load_npz
    from ..synth.groundtruth import frame_file

    capture = Path(capture)
    cols = _gt_camera_order(capture, rig.names) if columns is None else columns
    fr = load_npz(frame_file(capture, frame), ["xyz", "visible"], "a ground-truth file")
    xyz = fr["xyz"].astype(np.float64)  # (M, 3)
    index = np.flatnonzero(np.isfinite(xyz).all(axis=1))
    visible, in_image = true_visibility(capture, rig, frame, xyz[index], depth_tol)
    flags = np.asarray(fr["visible"], bool)[index][:, cols]
    return FrameTruth(xyz[index], index, visible, in_image, flags)


def nearest_sample(
    truth: FrameTruth, xyz: np.ndarray, radius: float
) -> tuple[np.ndarray, np.ndarray]:
    """Nearest ground-truth sample of each point, and whether the point is on an actor.

    Parameters
    ----------
    truth : FrameTruth
    xyz : (N, 3) float ndarray
    radius : float
        A point is on an actor when its nearest sample lies within this (metres).

    Returns
    -------
    nearest : (N,) int64 ndarray
        Row of ``truth`` (0 where there is no sample).
    on_actor : (N,) bool ndarray
    """
    from scipy.spatial import cKDTree

    if len(truth.xyz) == 0 or len(xyz) == 0:
        return np.zeros(len(xyz), np.int64), np.zeros(len(xyz), bool)
    d, idx = cKDTree(truth.xyz).query(np.asarray(xyz, np.float64), k=1)
    return idx.astype(np.int64), d <= radius


@dataclass
class ViewAudit:
    """The figures of the view audit (see the module's definitions), with their supports.

    Attributes
    ----------
    live_point_frames : int
        Point-frames of the audited frames.
    actor_point_frames : int
        Those on an actor.
    true_views, observed_views, hit_views : int
        Views of actor point-frames: truly visible, observed, both.
    two_view_point_frames : int
        Live point-frames observed in exactly 2 cameras.
    three_view_truth, three_view_hit : int
        Actor point-frames truly visible in >= 3 cameras; those of them observed in >= 3.
    surface_two, surface_three : int
        Ground-truth sample-frames truly visible in >= 2 cameras; those of them in >= 3: what
        the rig's geometry allows, whatever the reconstruction does.
    actor_lengths : (K,) int64 ndarray
        Audited length of each trajectory on the actors.
    visible_runs : (R,) int64 ndarray
        Lengths of the ground truth's runs truly visible in >= 2 cameras.
    flag_runs : (R',) int64 ndarray
        The same with the capture's stored ``visible`` flags.
    flag_views, flag_agree, flag_only, true_only : int
        In-image sample-views; those where the stored flags agree with true visibility; flagged
        but not truly visible; truly visible but not flagged.
    errors : dict of str to (n,) float64 ndarray
        3D error (m) of actor point-frames by observed views (``"2"``, ``"3"``, ``"4+"``); empty
        when not measured. Point-frames with no ground-truth surface near them are left out
        and counted in ``no_surface``.
    no_surface : dict of str to int
        Actor point-frames by observed views whose 3D error has no surface to measure to.
    radius, depth_tol, visibility_threshold : float
        The settings.
    frames : int
        Audited frames.
    """

    live_point_frames: int = 0
    actor_point_frames: int = 0
    true_views: int = 0
    observed_views: int = 0
    hit_views: int = 0
    two_view_point_frames: int = 0
    three_view_truth: int = 0
    three_view_hit: int = 0
    surface_two: int = 0
    surface_three: int = 0
    actor_lengths: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    visible_runs: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    flag_runs: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    flag_views: int = 0
    flag_agree: int = 0
    flag_only: int = 0
    true_only: int = 0
    errors: dict[str, np.ndarray] = field(default_factory=dict)
    no_surface: dict[str, int] = field(default_factory=dict)
    radius: float = 0.03
    depth_tol: float = 0.01
    visibility_threshold: float = 0.05
    frames: int = 0

    @property
    def recall(self) -> float:
        """Observed and truly visible / truly visible views of actor point-frames."""
        return _ratio(self.hit_views, self.true_views)

    @property
    def precision(self) -> float:
        """Observed and truly visible / observed views of actor point-frames."""
        return _ratio(self.hit_views, self.observed_views)

    @property
    def three_view_share(self) -> float:
        """Share observed in >= 3 cameras of actor point-frames truly visible in >= 3."""
        return _ratio(self.three_view_hit, self.three_view_truth)

    @property
    def surface_three_view_share(self) -> float:
        """Share truly visible in >= 3 cameras of the surface samples visible in >= 2."""
        return _ratio(self.surface_three, self.surface_two)

    @property
    def two_view_share(self) -> float:
        """Share of live point-frames observed in exactly 2 cameras."""
        return _ratio(self.two_view_point_frames, self.live_point_frames)

    def to_metrics(self) -> dict[str, float | int]:
        """Flat ``gt.views.*`` metrics, each figure with its ``.support``.

        Returns
        -------
        dict
        """
        m: dict[str, float | int] = {
            "gt.views.recall": self.recall,
            "gt.views.recall.support": self.true_views,
            "gt.views.precision": self.precision,
            "gt.views.precision.support": self.observed_views,
            "gt.views.true_per_point": _ratio(self.true_views, self.actor_point_frames),
            "gt.views.observed_per_point": _ratio(self.observed_views, self.actor_point_frames),
            "gt.views.per_point.support": self.actor_point_frames,
            "gt.views.actor_share": _ratio(self.actor_point_frames, self.live_point_frames),
            "gt.views.actor_share.support": self.live_point_frames,
            "gt.views.three_view_share": self.three_view_share,
            "gt.views.three_view_share.support": self.three_view_truth,
            "gt.views.three_view_truth": _ratio(self.three_view_truth, self.actor_point_frames),
            "gt.views.three_view_truth.support": self.actor_point_frames,
            "gt.views.surface_three_view": self.surface_three_view_share,
            "gt.views.surface_three_view.support": self.surface_two,
            "gt.views.two_view_share": self.two_view_share,
            "gt.views.two_view_share.support": self.live_point_frames,
            "gt.views.trajectory_length.median": _median(self.actor_lengths),
            "gt.views.trajectory_length.support": len(self.actor_lengths),
            "gt.views.visible_run.median": _median(self.visible_runs),
            "gt.views.visible_run.support": len(self.visible_runs),
            "gt.views.flag_run.median": _median(self.flag_runs),
            "gt.views.flag_run.support": len(self.flag_runs),
            "gt.views.flags_agreement": _ratio(self.flag_agree, self.flag_views),
            "gt.views.flags_agreement.support": self.flag_views,
            "gt.views.flags_only": self.flag_only,
            "gt.views.true_only": self.true_only,
            "gt.views.radius_m": self.radius,
            "gt.views.depth_tol_m": self.depth_tol,
            "gt.views.visibility_threshold": self.visibility_threshold,
            "gt.views.frames": self.frames,
        }
        for name, err in self.errors.items():
            m[f"gt.views.error_m.{name}.median"] = _median(err)
            m[f"gt.views.error_m.{name}.p90"] = _percentile(err, 90)
            m[f"gt.views.error_m.{name}.support"] = len(err)
            m[f"gt.views.error_m.{name}.no_surface"] = self.no_surface.get(name, 0)
        return m


class _Runs:
    """Lengths of the maximal runs of True per sample, fed one frame at a time."""

    def __init__(self, size: int) -> None:
        self.current = np.zeros(size, np.int64)
        self.done: list[np.ndarray] = []

    def update(self, ok: np.ndarray) -> None:
        """Add a frame: ``ok`` (M,) bool per sample."""
        ended = (self.current > 0) & ~ok
        self.done.append(self.current[ended])
        self.current = np.where(ok, self.current + 1, 0)

    def lengths(self) -> np.ndarray:
        """(R,) int64 lengths of all runs, those still open at the end included."""
        return np.concatenate([*self.done, self.current[self.current > 0]])


def _frame_errors(capture: Path, rig, trajectories: Trajectories, t: int) -> np.ndarray:
    """(N_t,) 3D error of frame ``t``'s point-frames (NaN: no surface near), in ``frame_rows``
    order."""
    from .groundtruth import surface_errors

    return surface_errors(capture, rig, trajectories, frames=range(t, t + 1))


def view_audit(
    capture: str | os.PathLike,
    trajectories: Trajectories,
    frames: range | None = None,
    radius: float = 0.03,
    depth_tol: float = 0.01,
    visibility_threshold: float = 0.05,
    progress: Callable[[int], None] | None = None,
    *,
    errors: bool = True,
) -> ViewAudit:
    """Audit the views of reconstructed points against the ground truth (issue #20).

    The definitions are the module's (:mod:`pointtraj.evaluate.views`).

    Parameters
    ----------
    capture : path-like
        A synthetic capture with ground truth.
    trajectories : Trajectories
        P point-frames, cameras named as in the capture's rig.
    frames : range, optional
        Frames to audit (default: all of the store's).
    radius : float
        Metres from the nearest ground-truth sample for a point to be on an actor.
    depth_tol : float
        Metres between a sample's depth and the depth map for it to be truly visible.
    visibility_threshold : float
        A view is observed when the visibility exceeds this.
    progress : callable, optional
        Called with 1 after each frame.
    errors : bool
        Measure the 3D error split by observed views (one more pass over the depth maps).

    Returns
    -------
    ViewAudit
    """
    from ..session import Capture

    capture = Path(capture)
    frames = range(trajectories.num_frames) if frames is None else frames
    rig = Capture.open(capture).rig.subset(trajectories.camera_names)
    columns = _gt_camera_order(capture, rig.names)
    audit = ViewAudit(
        radius=radius,
        depth_tol=depth_tol,
        visibility_threshold=visibility_threshold,
        frames=len(frames),
    )
    on_actor = np.zeros(trajectories.num_trajectories, np.int64)  # audited actor point-frames
    alive = np.zeros(trajectories.num_trajectories, np.int64)  # audited point-frames
    runs = flag_runs = None
    err_parts: dict[str, list[np.ndarray]] = {k: [] for k in VIEW_BUCKETS} if errors else {}
    for t in frames:
        truth = frame_truth(capture, rig, t, depth_tol, columns)
        if runs is None:
            M = int(truth.index.max()) + 1 if len(truth.index) else 0
            runs, flag_runs = _Runs(M), _Runs(M)
        _update_runs(runs, flag_runs, truth)
        _update_flags(audit, truth)
        rows = trajectories.frame_rows(t)
        if len(rows):
            xyz = trajectories.xyz[rows].astype(np.float64)  # (N, 3)
            observed = dequantize_visibility(trajectories.visibility[rows]) > visibility_threshold
            nearest, actor = nearest_sample(truth, xyz, radius)
            _update_views(audit, observed, truth.visible[nearest[actor]], actor)
            track = trajectories.row_track[rows]
            np.add.at(alive, track, 1)
            np.add.at(on_actor, track, actor)
            if errors and actor.any():
                err = _frame_errors(capture, rig, trajectories, t)[actor]
                n_obs = observed[actor].sum(axis=1)
                for name, (lo, hi) in VIEW_BUCKETS.items():
                    e = err[(n_obs >= lo) & (n_obs <= hi)]
                    err_parts[name].append(e[np.isfinite(e)])
                    audit.no_surface[name] = audit.no_surface.get(name, 0) + int(np.isnan(e).sum())
        if progress is not None:
            progress(1)
    actor_tracks = (alive > 0) & (2 * on_actor > alive)
    audit.actor_lengths = alive[actor_tracks]
    if runs is not None:
        audit.visible_runs, audit.flag_runs = runs.lengths(), flag_runs.lengths()
    audit.errors = {k: np.concatenate(v) if v else np.zeros(0) for k, v in err_parts.items()}
    logger.info(
        "view audit: recall %.3f, precision %.3f over %d actor point-frames",
        audit.recall,
        audit.precision,
        audit.actor_point_frames,
    )
    return audit


def _update_runs(runs: _Runs, flag_runs: _Runs, truth: FrameTruth) -> None:
    """Feed a frame's samples truly visible (and flagged) in >= 2 cameras to the run counters."""
    size = len(runs.current)
    for counter, views in ((runs, truth.visible), (flag_runs, truth.flags)):
        ok = np.zeros(size, bool)
        ok[truth.index] = views.sum(axis=1) >= 2
        counter.update(ok)


def _update_flags(audit: ViewAudit, truth: FrameTruth) -> None:
    """Count the agreement of the stored flags with true visibility over in-image views, and
    the samples truly visible in >= 2 and >= 3 cameras."""
    n_true = truth.visible.sum(axis=1)
    audit.surface_two += int((n_true >= 2).sum())
    audit.surface_three += int((n_true >= 3).sum())
    ii = truth.in_image
    audit.flag_views += int(ii.sum())
    audit.flag_agree += int((ii & (truth.flags == truth.visible)).sum())
    audit.flag_only += int((ii & truth.flags & ~truth.visible).sum())
    audit.true_only += int((ii & ~truth.flags & truth.visible).sum())


def _update_views(
    audit: ViewAudit, observed: np.ndarray, true_vis: np.ndarray, actor: np.ndarray
) -> None:
    """Add one frame's views.

    Parameters
    ----------
    audit : ViewAudit
    observed : (N, C) bool ndarray
        Observed views of the frame's point-frames.
    true_vis : (A, C) bool ndarray
        Truly visible views of its A actor point-frames.
    actor : (N,) bool ndarray
    """
    n_obs = observed.sum(axis=1)  # (N,)
    audit.live_point_frames += len(observed)
    audit.two_view_point_frames += int((n_obs == 2).sum())
    obs = observed[actor]  # (A, C)
    audit.actor_point_frames += len(obs)
    audit.true_views += int(true_vis.sum())
    audit.observed_views += int(obs.sum())
    audit.hit_views += int((obs & true_vis).sum())
    three = true_vis.sum(axis=1) >= 3
    audit.three_view_truth += int(three.sum())
    audit.three_view_hit += int((obs[three].sum(axis=1) >= 3).sum())


@dataclass(frozen=True)
class OcclusionAudit:
    """How an occlusion mask compares with true visibility (see :func:`false_occlusion_rate`).

    Attributes
    ----------
    marked : int
        Views of actor points marked occluded.
    marked_visible : int
        Of those, the truly visible ones.
    occluded : int
        Truly occluded in-image views of actor points (the sample is in the image, in front,
        and not truly visible).
    occluded_marked : int
        Of those, the ones marked.
    """

    marked: int = 0
    marked_visible: int = 0
    occluded: int = 0
    occluded_marked: int = 0

    @property
    def false_rate(self) -> float:
        """Share of marked views that are truly visible (support :attr:`marked`; 0 when none)."""
        return _ratio(self.marked_visible, self.marked) if self.marked else 0.0

    @property
    def recall(self) -> float:
        """Share of truly occluded in-image views that are marked (support :attr:`occluded`)."""
        return _ratio(self.occluded_marked, self.occluded)

    def __add__(self, other: OcclusionAudit) -> OcclusionAudit:
        return OcclusionAudit(
            self.marked + other.marked,
            self.marked_visible + other.marked_visible,
            self.occluded + other.occluded,
            self.occluded_marked + other.occluded_marked,
        )


def false_occlusion_rate(
    capture: str | os.PathLike,
    rig,
    frame: int,
    xyz: np.ndarray,
    occluded: np.ndarray,
    radius: float = 0.03,
    depth_tol: float = 0.01,
    truth: FrameTruth | None = None,
) -> OcclusionAudit:
    """Compare a frame's occlusion mask with the ground truth's true visibility.

    Only points on an actor count (nearest ground-truth sample within ``radius``); a view is
    truly visible, or truly occluded, by the camera's view of the point's nearest sample
    (:func:`true_visibility`): truly occluded when the sample projects inside the image, in
    front of the camera, and is not truly visible.

    Parameters
    ----------
    capture : path-like
        A synthetic capture.
    rig : CameraRig
        C cameras of the capture.
    frame : int
    xyz : (N, 3) float ndarray
        The frame's points.
    occluded : (N, C) bool ndarray
        The mask, as from :func:`pointtraj.reconstruct.occlusion.occlusion_test`.
    radius, depth_tol : float
        Metres, as in :func:`view_audit`.
    truth : FrameTruth, optional
        ``frame_truth(capture, rig, frame, depth_tol)`` when the caller has it.

    Returns
    -------
    OcclusionAudit
        ``false_rate`` (share of marked views truly visible, support ``marked``) and ``recall``
        (share of truly occluded in-image views marked, support ``occluded``).
    """
    truth = frame_truth(capture, rig, frame, depth_tol) if truth is None else truth
    nearest, actor = nearest_sample(truth, xyz, radius)
    occ = np.asarray(occluded, bool)[actor]  # (A, C)
    vis = truth.visible[nearest[actor]]
    hidden = truth.in_image[nearest[actor]] & ~vis
    return OcclusionAudit(
        marked=int(occ.sum()),
        marked_visible=int((occ & vis).sum()),
        occluded=int(hidden.sum()),
        occluded_marked=int((hidden & occ).sum()),
    )
