"""Trajectories that survive losing a view: one-view points carried by their neighbours' motion.

A two-view point dies with either view: an occluder passes in front of one camera, Lucas-Kanade
loses it there for a frame, or the occlusion test zeroes it. Yet its other view is still tracked,
and its neighbours on the same body part still know how the part moved. A live point whose
views drop to one goes on for at most ``frames`` frames when two things agree:

1. **The neighbours' motion.** Its ``neighbors`` nearest live points within ``radius_m`` that
   were triangulated at both frames give a rigid motion (a least-squares SE(3) fit,
   Kabsch/Umeyama without scale); the fit must explain them within ``max_fit_m`` (RMS). The
   point's previous position moved by it is its prediction.
2. **Its remaining view.** The prediction projects within ``max_px`` of the view's tracked
   position.

The point is then placed on that view's ray, nearest the prediction, and keeps that one view.
Its other cameras stay searched by view discovery every frame; once a second view returns, the
RANSAC re-triangulation takes over again. A point that keeps fewer than two views for more
than ``frames`` frames, or whose view and neighbours disagree, ends; the one-view rows at the
end of a trajectory are then dropped (:func:`trim_one_view_tails`): only those that bridge to
triangulated rows stay.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ..camera import CameraRig
from ..errors import ValidationError, check_array
from ..geometry import pixel_distance
from ..scale import SceneLength

if TYPE_CHECKING:
    from ..trajectories import Trajectories

__all__ = ["SurviveConfig", "predict_rigid", "carry_one_view", "trim_one_view_tails"]

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class SurviveConfig:
    """Parameters of one-view survival (TOML table ``[reconstruct.survive]``).

    Attributes
    ----------
    frames : int
        Frames a point may go on with fewer than two views (0 turns survival off).
    radius_m : float
        Neighbours farther than this (metres, at the previous frame) do not vote.
    neighbors : int
        Nearest neighbours the rigid motion is fitted to.
    min_neighbors : int
        Fewer neighbours within ``radius_m``: no prediction, the point ends.
    max_fit_m : float
        RMS residual (metres) of the neighbours' rigid fit above which their motion is not
        rigid enough to carry the point.
    max_px : float
        The prediction must project this close (pixels) to the remaining view's tracked
        position; 0 takes twice the RANSAC inlier threshold (``ransac_threshold_px``).
        It is also the radius within which a lost view is searched for (``reacquire``).
    reacquire : bool
        Search the camera that lost a carried point's view for the point's patch from that
        camera's last image of it (:mod:`~.reacquire`).
    reacquire_ncc : float
        Least NCC of a re-acquired view.
    reacquire_margin : float
        Least NCC by which a re-acquired view's peak must exceed every other peak of its
        search.
    """

    frames: int = 3
    radius_m: float = SceneLength(0.15)
    neighbors: int = 8
    min_neighbors: int = 4
    max_fit_m: float = SceneLength(0.01)
    max_px: float = 0.0
    reacquire: bool = True
    reacquire_ncc: float = 0.8
    reacquire_margin: float = 0.05

    def __post_init__(self) -> None:
        checks = {
            "frames": self.frames >= 0,
            "radius_m": self.radius_m > 0,
            "neighbors": self.neighbors >= 3,
            "min_neighbors": 3 <= self.min_neighbors <= self.neighbors,
            "max_fit_m": self.max_fit_m > 0,
            "max_px": self.max_px >= 0,
            "reacquire_ncc": -1 <= self.reacquire_ncc <= 1,
            "reacquire_margin": self.reacquire_margin >= 0,
        }
        bad = [k for k, ok in checks.items() if not ok]
        if bad:
            raise ValidationError(f"SurviveConfig.{bad[0]} out of range: {getattr(self, bad[0])!r}")


def predict_rigid(
    before: np.ndarray,
    after: np.ndarray,
    points: np.ndarray,
    config: SurviveConfig | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Move points by the rigid motion of their nearest anchors.

    Parameters
    ----------
    before, after : (A, 3) float ndarray
        The anchors' positions at the previous and the current frame.
    points : (n, 3) float ndarray
        Positions at the previous frame.
    config : SurviveConfig, optional
        ``neighbors``, ``min_neighbors``, ``radius_m`` and ``max_fit_m``.

    Returns
    -------
    predicted : (n, 3) float64 ndarray
        NaN where there is no prediction.
    ok : (n,) bool ndarray
        Enough anchors within the radius, moving rigidly within ``max_fit_m``.
    """
    from scipy.spatial import cKDTree

    from ..geometry import fit_rigid

    cfg = config or SurviveConfig()
    P = check_array("before", before, (None, 3))
    Q = check_array("after", after, (P.shape[0], 3))
    X = check_array("points", points, (None, 3))
    n = len(X)
    out = np.full((n, 3), np.nan)
    if n == 0 or len(P) < cfg.min_neighbors:
        return out, np.zeros(n, bool)
    k = min(cfg.neighbors, len(P))
    dist, idx = cKDTree(P).query(X, k=k, distance_upper_bound=cfg.radius_m)
    dist, idx = dist.reshape(n, k), idx.reshape(n, k)
    w = np.isfinite(dist).astype(np.float64)  # (n, k); missing neighbours have idx == len(P)
    idx = np.where(w > 0, idx, 0)
    count = w.sum(axis=1)
    ok = count >= cfg.min_neighbors
    if not ok.any():
        return out, ok
    w, idx, count, Xo = w[ok], idx[ok], count[ok], X[ok]
    a, b = P[idx], Q[idx]  # (m, k, 3)
    fit = fit_rigid(a, b, w)
    R, t = fit.rotation, fit.translation  # (m, 3, 3), (m, 3)
    fitted = np.einsum("mij,mkj->mki", R, a) + t[:, None]
    rms = np.sqrt((w * ((fitted - b) ** 2).sum(axis=2)).sum(axis=1) / count)
    pred = np.einsum("mij,mj->mi", R, Xo) + t
    good = fit.valid & (rms <= cfg.max_fit_m)
    sel = np.flatnonzero(ok)
    out[sel[good]] = pred[good]
    ok[sel[~good]] = False
    return out, ok


def carry_one_view(
    rig: CameraRig,
    predicted: np.ndarray,
    observations: np.ndarray,
    max_px: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Place predicted points on the ray of the tracked view that agrees with them best.

    Parameters
    ----------
    rig : CameraRig
        C cameras.
    predicted : (n, 3) float ndarray
        Predictions (NaN rows have none).
    observations : (C, n, 2) float ndarray
        Tracked positions (distorted pixels; NaN where a camera lost the point).
    max_px : float
        Largest distance between a prediction's projection and the view it keeps.

    Returns
    -------
    points : (n, 3) float64 ndarray
        On the kept view's ray, nearest the prediction (NaN where none agrees).
    camera : (n,) int64 ndarray
        The kept view's camera (-1 where none agrees).
    distance : (n,) float64 ndarray
        Pixels between the prediction's projection and the kept view.
    ok : (n,) bool ndarray
    """
    C = len(rig)
    Xp = check_array("predicted", predicted, (None, 3))
    n = len(Xp)
    obs = check_array("observations", observations, (C, n, 2))
    proj = rig.project(np.where(np.isfinite(Xp), Xp, 0.0))
    with np.errstate(invalid="ignore"):
        d = pixel_distance(proj.pixels, obs)  # (C, n), NaN where not tracked
    d = np.where(np.isfinite(d) & proj.in_image & np.isfinite(Xp).all(axis=1)[None], d, np.inf)
    cam = np.argmin(d, axis=0) if n else np.zeros(0, np.int64)
    best = d[cam, np.arange(n)] if n else np.zeros(0)
    ok = best <= max_px
    points = np.full((n, 3), np.nan)
    for c in np.unique(cam[ok]):
        sel = np.flatnonzero(ok & (cam == c))
        origin, direction = rig[int(c)].rays(obs[c, sel])  # (k, 3) each
        s = np.einsum("nk,nk->n", Xp[sel] - origin, direction)
        points[sel] = origin + s[:, None] * direction
    return points, np.where(ok, cam, -1).astype(np.int64), np.where(ok, best, np.nan), ok


def trim_one_view_tails(
    trajectories: Trajectories, visibility_threshold: float = 0.05, min_views: int = 2
) -> tuple[Trajectories, int]:
    """Drop the rows at the end of each trajectory that have fewer than ``min_views`` views.

    A trajectory carried on one view that never regained a second one ends with rows whose
    position only its neighbours' motion supports; they are kept only where they bridge to
    triangulated rows.

    Parameters
    ----------
    trajectories : Trajectories
    visibility_threshold : float
        A view counts where the visibility exceeds this.
    min_views : int

    Returns
    -------
    trajectories : Trajectories
        The same store when nothing is dropped; otherwise a new one with the same trajectory
        indices.
    dropped : int
        Rows dropped.
    """
    from ..trajectories import dequantize_visibility

    views = np.count_nonzero(
        dequantize_visibility(trajectories.visibility) > visibility_threshold, axis=1
    )
    good = views >= min_views  # (P,)
    offsets = trajectories.offsets
    M = trajectories.num_trajectories
    if M == 0 or good.all():
        return trajectories, 0
    # the last good row of each trajectory: the max good row index within [offsets[m], offsets[m+1])
    track = trajectories.row_track
    last = np.full(M, -1, np.int64)
    rows = np.flatnonzero(good)
    np.maximum.at(last, track[rows], rows)
    last = np.where(last >= 0, last, offsets[:-1])  # a trajectory without one keeps its first row
    lengths = last - offsets[:-1] + 1
    if np.array_equal(lengths, trajectories.lengths):
        return trajectories, 0
    out = trajectories.truncate(lengths)
    return out, int(trajectories.num_point_frames - out.num_point_frames)
