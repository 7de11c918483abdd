"""View discovery: find each point in every camera that should see it, at any baseline.

Matching chains into mostly two-view tracks, and Lucas-Kanade flow between two cameras only
finds a point where their images look alike (optical axes within about 40 degrees). View
discovery uses the calibration instead, as the plane sweep of :mod:`.densify` does:

1. **Candidates.** Each (camera c, point n) where n projects inside c's image, is not occluded,
   is not observed yet, and faces c: the angle between the point's surface normal (fitted to
   its neighbours with Open3D) and the direction to c is below ``max_incidence_deg``.
2. **Sweep.** The observing camera r whose direction to the point is nearest c's gives the
   patch: ``patch_size`` x ``patch_size`` samples around the point's observation in r, on the
   plane through the point with its normal. Depths along r's ray through the observation are
   swept over the point's uncertainty (``depth_sigmas`` standard deviations of its depth,
   from the triangulation angle; within ``[min_depth_range_m, max_depth_range_m]``), the
   plane warped into c at each (a plane homography), and scored by normalised
   cross-correlation (NCC) with r's patch.
3. **Acceptance.** The best NCC must reach ``min_ncc``, inside the swept range, with no rival
   peak within ``min_margin`` of it, on a textured patch (``min_std``). The new observation is
   the point at the best depth projected into c. The tracker then re-triangulates with RANSAC,
   which keeps the view only where it agrees with the others.

A point's unobserved cameras are searched when it is new and when a camera newly sees it;
a camera where the search failed is searched again after ``retry_every`` frames, then after
twice as many at each further failure up to ``max_retry_every`` (staggered by point and camera),
so that a tracked point does not pay for the same fruitless search every frame
(:func:`retry_due`). A point carried on one view (:mod:`.survive`) is searched every frame,
over the widest depth range (one view gives no triangulation angle).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from ..camera import CameraRig
from ..errors import ValidationError, check_array
from ..geometry import finite_rows, observed_first, squared_norm
from ..scale import SceneLength
from .densify import _ncc_warped, _rays, _sample, _warp, _zscore
from .texture import PATCH_SPACINGS

__all__ = [
    "ViewsConfig",
    "discover_views",
    "grazing_views",
    "refuted",
    "point_normals",
    "depth_uncertainty",
    "retry_due",
    "retry_periods",
    "record_misses",
]

logger = logging.getLogger(__name__)

_CHUNK = 4096  # points per vectorised block (bounds the (n, C, C) work arrays)


@dataclass(frozen=True)
class ViewsConfig:
    """Parameters of view discovery (TOML table ``[reconstruct.views]``).

    Attributes
    ----------
    enabled : bool
        Search every point in the cameras that should see it (on by default).
    min_ncc : float
        NCC the warped patch needs at its best depth.
    min_margin : float
        The best NCC must exceed every score more than ``peak_width`` depth steps away by this.
    peak_width : int
        Depth steps on each side of the best one that belong to its peak.
    min_std : float
        Grey-level standard deviation (0-255) the reference patch needs.
    patch_size : int
        Samples per side of the patch.
    patch_spacing_px : float or None
        Spacing of the patch's samples in the reference image. None (the default, the key left
        out): chosen by the reconstruction from the first frame's texture, as densification's
        (:func:`~.texture.texture_patch_spacing`): 2 px on rendered texture, 4-6 px on real
        video. On the Pose2Sim demo 5 px made the labelled trajectories last 9 frames at the
        median against 7 at 2 px (``docs/real_captures.md``, "Densification's patch from the
        images' texture"). Functions given this config directly read None as 2 px
        (:attr:`spacing_px`).
    depth_steps : int
        Depth hypotheses swept (odd keeps the point's own depth).
    depth_sigmas : float
        The sweep covers this many standard deviations of the point's depth on each side.
    min_depth_range_m, max_depth_range_m : float
        Bounds of the half-range swept.
    max_incidence_deg : float
        A camera that sees the point's surface at a more grazing angle (or from behind) is not
        searched, and with ``drop_grazing`` a view observed at such an angle is dropped.
    normal_neighbors : int
        Neighbours of a point that its surface normal is fitted to.
    retry_every : int
        A camera where a tracked point was searched and not found is searched again after
        this many frames, staggered by point and camera; 0 derives it from the rig,
        ``max(1, C // 16)`` for C cameras, so that a point costs about as much a frame on a
        69-camera dome (every 4th frame) as on an 8-camera ring (every frame). New points, and
        cameras that newly see a point (it was occluded, outside the image or observed the
        frame before), are searched at once.
    max_retry_every : int
        Back-off: after each further failed search of a (point, camera) the period doubles,
        up to this many frames (the tracker keeps a failure count per point and camera,
        ``TrackState.misses``); 0 derives it from ``retry_every``: four times it where that
        is above 1 (16 frames on a 69-camera dome), and no back-off where it is 1 (rigs of up
        to 31 cameras, where searching every frame costs little: on the demo's 8 cameras a
        back-off to 4 frames lowered view recall from 0.733 to 0.710 over frames 0-29);
        ``retry_every`` or less turns the back-off off.
    normal : {"neighbors", "bisector"}
        The swept plane's normal: fitted to the point's neighbours, or the bisector of the
        directions to the reference and the searched camera (with the cameras observing the
        point deciding which cameras face it).
    search_sigmas : float
        Calibration error moves a point off its epipolar line: the warped patch is also tried
        shifted across the line, within this many ``sigma_px`` (the tracker's image tolerance)
        on each side, in steps of ``max(sigma_px / 2, patch_spacing_px)``, where that reaches
        beyond the patch spacing (rigs calibrated to a few pixels). Off (0) by default: on
        three synthetic cameras with one principal point 8 px off it finds 57 % of the points
        in that camera against 13 %, but on the Pose2Sim demo (``sigma_px`` 6, 2) it left the
        labelled body points with three views unchanged (3.9 %) and lowered the share on the
        body from 86.6 to 85.4 % and predictive validity from 0.69 to 0.66
        (``docs/reconstruction.md``).
    confirm_new : bool
        A new point left with two views is dropped when another camera was searched for it
        with a usable patch and did not confirm it (two views always agree with a wrong match
        along the epipolar line; a third decides).
    confirm_incidence_deg : float or None
        A new two-view point that no camera could be searched for with its fitted normal (all
        beyond ``max_incidence_deg``, or no usable patch) is searched once more for
        ``confirm_new``, with the plane facing the bisector of the reference and the searched
        camera, in the cameras within this angle of its observing cameras' mean direction.
        The fitted normals are poor on sparse clouds (27 degrees off at the median on the
        demo), and on the demo half of the new points were such two-view points, 12 mm off
        the surface at the median (46 % more than 15 mm) against 5 mm for three views: the
        points that no third camera checks carry the 3D error's tail
        (``docs/reconstruction.md``, "New two-view points that no camera could check").
        None (the default) lets the rig choose (``ReconstructConfig.for_rig``,
        :func:`~pointtraj.reconstruct.config.confirm_off_reasons`): 89 degrees on rigs of
        :data:`CONFIRM_MIN_CAMERAS` cameras or more whose image tolerance ``sigma_px`` is at
        most ``patch_spacing_px`` (or ``search_sigmas`` at least 1), and whose neighbours are
        close enough that a third camera sees a pair's surface within ``max_incidence_deg``
        (:data:`CONFIRM_THIRD_FACTOR` times the median nearest-partner angle); off, said in a
        warning, elsewhere. On 4 cameras the other cameras of a two-view point see it at a
        grazing angle, where the search misses right points (the caliscope board's torso lost
        37 % of its trajectories), on six cameras 60 degrees apart it adds grazing views, and a
        rig calibrated to a few pixels puts a right point off its epipolar line (the Pose2Sim
        demo). 0 turns it off; a number is used as set.
    drop_grazing : bool
        After the search, a tracked or new point drops the views it observes beyond
        ``max_incidence_deg`` to its fitted normal, where it keeps at least 3 views
        (:func:`grazing_views`): tracking carries a view on while the surface turns away, and
        such views are the wrong ones (on paper69, observed views at 80-90 degrees to the true
        surface are right in 71 % of cases, from behind in 18 %, below 70 degrees in 99 %).
    refute_min_fails, refute_fail_ratio : int, float
        A tracked point is *refuted* (:func:`refuted`) when the cameras where it is in the
        image and not occluded, but where it is still unobserved after a search, number at
        least ``refute_min_fails`` and at least ``refute_fail_ratio`` times its observing
        cameras. A refuted point stays a trajectory but hides nothing in the occlusion test:
        it floats off the surface (a track that slid off a limb), and the views behind it
        are visible. On paper69 at frame 29, 764 points 3-16 cm off the surface caused 60 %
        of the test's false occlusions, and the share of true views lost to the test grew
        from 8.5 % at frame 0 to 21.7 % (``docs/reconstruction.md``, "Points that float
        hide nothing"). ``refute_fail_ratio`` 0 turns it off; the count of 8 keeps it off on
        rigs of up to 8 cameras.
    unconfirmed_fails, unconfirmed_frames : int
        A tracked point left with two views ends when its searches failed at least
        ``unconfirmed_frames`` times in a row in at least ``unconfirmed_fails`` cameras that
        should see it (in the image, not occluded): what ``confirm_new`` asks of a new point,
        asked again when a point falls back to two views (two views always agree). Such
        points lie off the surface: on the demo, two-view points that 3-4 searched cameras
        did not find were 17-18 mm off at the median, against 4-8 mm with 1-2. On the demo
        the default 4 lowered the 3D error from 6.1 / 25.9 to 5.2 / 19.7 mm (median / p90)
        and raised view recall and precision, for trajectories half as long (median 15
        frames instead of 30); on paper69 it changed the live points by 1.5 %
        (``docs/reconstruction.md``, "Two-view points that the other cameras do not
        confirm"). It needs 2 + 4 cameras, so rigs of up to 5 never use it; 0 turns it off.
    """

    enabled: bool = True
    min_ncc: float = 0.7
    min_margin: float = 0.05
    peak_width: int = 2
    min_std: float = 3.0
    patch_size: int = 5
    patch_spacing_px: float | None = None
    depth_steps: int = 9
    depth_sigmas: float = 3.0
    min_depth_range_m: float = SceneLength(0.01)
    max_depth_range_m: float = SceneLength(0.08)
    max_incidence_deg: float = 80.0
    normal_neighbors: int = 12
    retry_every: int = 0
    max_retry_every: int = 0
    search_sigmas: float = 0.0
    confirm_new: bool = True
    confirm_incidence_deg: float | None = None
    drop_grazing: bool = True
    refute_min_fails: int = 8
    refute_fail_ratio: float = 4.0
    unconfirmed_fails: int = 4
    unconfirmed_frames: int = 1
    normal: str = "neighbors"

    def __post_init__(self) -> None:
        checks = {
            "min_ncc": -1 <= self.min_ncc <= 1,
            "min_margin": self.min_margin >= 0,
            "peak_width": 1 <= self.peak_width < self.depth_steps // 2,
            "min_std": self.min_std >= 0,
            "patch_size": self.patch_size >= 3,
            "patch_spacing_px": self.patch_spacing_px is None or self.patch_spacing_px > 0,
            "depth_steps": self.depth_steps >= 5,
            "depth_sigmas": self.depth_sigmas > 0,
            "min_depth_range_m": self.min_depth_range_m > 0,
            "max_depth_range_m": self.max_depth_range_m >= self.min_depth_range_m,
            "max_incidence_deg": 0 < self.max_incidence_deg <= 90,
            "confirm_incidence_deg": self.confirm_incidence_deg is None
            or 0 <= self.confirm_incidence_deg <= 90,
            "normal_neighbors": self.normal_neighbors >= 3,
            "retry_every": self.retry_every >= 0,
            "max_retry_every": self.max_retry_every >= 0,
            "search_sigmas": self.search_sigmas >= 0,
            "refute_min_fails": self.refute_min_fails >= 1,
            "refute_fail_ratio": self.refute_fail_ratio >= 0,
            "unconfirmed_fails": self.unconfirmed_fails >= 0,
            "unconfirmed_frames": 1 <= self.unconfirmed_frames <= MAX_MISSES,
            "normal": self.normal in ("neighbors", "bisector"),
        }
        bad = [k for k, ok in checks.items() if not ok]
        if bad:
            raise ValidationError(f"ViewsConfig.{bad[0]} out of range: {getattr(self, bad[0])!r}")

    @property
    def spacing_px(self) -> float:
        """``patch_spacing_px``, or :data:`~.texture.PATCH_SPACINGS`' first (2 px) where it is
        left to the images and they were not measured."""
        return PATCH_SPACINGS[0] if self.patch_spacing_px is None else self.patch_spacing_px


def point_normals(
    rig: CameraRig,
    xyz: np.ndarray,
    observed: np.ndarray,
    neighbors: int = 12,
    directions: np.ndarray | None = None,
) -> np.ndarray:
    """Unit surface normals of a frame's points, facing the cameras that observe them.

    Parameters
    ----------
    rig : CameraRig
        C cameras.
    xyz : (N, 3) float ndarray
    observed : (C, N) bool ndarray
        The cameras observing each point.
    neighbors : int
        Nearest neighbours the local plane is fitted to (Open3D ``estimate_normals``).
    directions : (C, N, 3) float ndarray, optional
        The unit directions from the points to the cameras, where the caller has them.

    Returns
    -------
    (N, 3) float64 ndarray
        Normals; where a point has too few neighbours for a plane, the mean direction to its
        observing cameras.
    """
    import open3d as o3d

    X = check_array("xyz", xyz, (None, 3))
    N = len(X)
    facing = (
        _observed_facing(rig, X, observed) if directions is None else _facing(observed, directions)
    )
    if N < 3:
        return facing
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(X))
    pcd.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(min(neighbors, N)))
    normals = np.asarray(pcd.normals)
    flip = np.einsum("nk,nk->n", normals, facing) < 0
    normals[flip] *= -1
    bad = ~finite_rows(normals) | (np.linalg.norm(normals, axis=1) < 0.5)
    normals[bad] = facing[bad]
    return normals


#: ``ViewsConfig.confirm_incidence_deg`` where the rig chooses it: the cameras within this
#: angle of a new two-view point's observing cameras' mean direction are searched again.
CONFIRM_INCIDENCE_DEG = 89.0

#: The fewest cameras on which new two-view points are searched again facing their cameras,
#: where ``confirm_incidence_deg`` is left to the rig (``ReconstructConfig.for_rig``): on 4
#: cameras the other cameras of a two-view point see it at a grazing angle, where the search
#: misses right points.
CONFIRM_MIN_CAMERAS = 6

#: Where ``confirm_incidence_deg`` is left to the rig, the search runs only where a third camera
#: can see a pair's surface within ``max_incidence_deg``: on a ring whose neighbours are ``a``
#: degrees apart (the median nearest partner), a pair's mean direction is ``a / 2`` from each of
#: its cameras and the next camera lies ``1.5 a`` from it. On six cameras 60 degrees apart
#: (89.6 > 80) the search added grazing views: view precision 0.754 -> 0.722, three-view points'
#: 3D error p90 17.4 -> 22.0 mm (``docs/reconstruction.md``, "New two-view points that no
#: camera could check", the rigs that no rule was tuned on).
CONFIRM_THIRD_FACTOR = 1.5

#: Failed searches in a row counted per (point, camera) at most (the back-off stops doubling).
MAX_MISSES = 8


def retry_periods(config: ViewsConfig, num_cameras: int) -> tuple[int, int]:
    """``(retry_every, max_retry_every)`` for a rig of ``num_cameras`` cameras, with the
    config's 0s derived (see :class:`ViewsConfig`)."""
    every = config.retry_every or max(1, num_cameras // 16)
    derived = 4 * every if every > 1 else 1
    return every, max(config.max_retry_every or derived, every)


def retry_due(
    misses: np.ndarray, ids: np.ndarray, t: int, every: int, max_every: int
) -> np.ndarray:
    """Which views of tracked points are due for a search at frame ``t``.

    Parameters
    ----------
    misses : (N, C) uint8 ndarray
        Failed searches in a row per point and camera (0: never searched, or the camera
        newly sees the point).
    ids : (N,) int ndarray
        The points' trajectory ids (they stagger the searches).
    t : int
        The frame.
    every, max_every : int
        The period after one failure, and the longest period (:func:`retry_periods`).

    Returns
    -------
    (C, N) bool ndarray
        True where ``misses`` is 0, and once every ``min(every * 2^(misses - 1), max_every)``
        frames otherwise, on frames ``t`` with ``(id + c + t)`` a multiple of that period.
    """
    m = np.asarray(misses, np.int64).T  # (C, N)
    C, N = m.shape
    if np.shape(ids) != (N,):
        raise ValidationError(f"retry_due: expected {N} ids, got shape {np.shape(ids)}")
    period = np.minimum(every * (1 << np.clip(m - 1, 0, MAX_MISSES)), max_every)
    phase = np.asarray(ids, np.int64)[None, :] + np.arange(C)[:, None] + t
    return (m == 0) | (phase % np.maximum(period, 1) == 0)


def grazing_views(
    rig: CameraRig, xyz: np.ndarray, observed: np.ndarray, config: ViewsConfig
) -> np.ndarray:
    """The observed views to drop: beyond ``max_incidence_deg`` to the point's fitted normal,
    on points that keep at least 3 views without them.

    Parameters
    ----------
    rig : CameraRig
        The C cameras.
    xyz : (N, 3) float ndarray
        The frame's points.
    observed : (C, N) bool ndarray
        Their views (after the search).
    config : ViewsConfig
        ``max_incidence_deg`` and ``normal_neighbors``.

    Returns
    -------
    (C, N) bool ndarray
        True for the views to drop (a subset of ``observed``).
    """
    X = check_array("xyz", xyz, (None, 3))
    obs = check_array("observed", observed, (len(rig), len(X)), dtype=bool)
    normals = point_normals(rig, X, obs, config.normal_neighbors)
    cams, pts = np.nonzero(obs)  # only the observed views: (C, N, 3) directions are large
    d = rig.C[cams] - X[pts]
    cos = np.einsum("kj,kj->k", d, normals[pts]) / np.linalg.norm(d, axis=1)
    grazing = np.zeros_like(obs)
    grazing[cams, pts] = cos < np.cos(np.radians(config.max_incidence_deg))
    keeps = (obs & ~grazing).sum(axis=0) >= 3
    return grazing & keeps[None, :]


def refuted(misses: np.ndarray, observed: np.ndarray, config: ViewsConfig) -> np.ndarray:
    """The points that the cameras which should see them do not confirm.

    Parameters
    ----------
    misses : (N, C) uint8 ndarray
        View discovery's failure counts (:func:`record_misses`): non-zero where the point is
        in the image and not occluded, was searched, and is still unobserved.
    observed : (N,) int ndarray
        The number of cameras observing each point.
    config : ViewsConfig
        ``refute_min_fails`` and ``refute_fail_ratio``.

    Returns
    -------
    (N,) bool ndarray
        True where the failed cameras number at least ``refute_min_fails`` and at least
        ``refute_fail_ratio`` times ``observed`` (all False when the ratio is 0).
    """
    fails = np.count_nonzero(np.asarray(misses), axis=1)
    if config.refute_fail_ratio <= 0:
        return np.zeros(len(fails), bool)
    return (fails >= config.refute_min_fails) & (
        fails >= config.refute_fail_ratio * np.asarray(observed)
    )


def record_misses(
    misses: np.ndarray, candidates: np.ndarray, due: np.ndarray, observed: np.ndarray
) -> np.ndarray:
    """The failure counts after a frame's search.

    Parameters
    ----------
    misses : (N, C) uint8 ndarray
        The counts before (see :func:`retry_due`).
    candidates : (C, N) bool ndarray
        The views that should see the points (in the image, not occluded).
    due : (C, N) bool ndarray
        The candidate views searched this frame.
    observed : (C, N) bool ndarray
        The views observed after the search (and the re-triangulation).

    Returns
    -------
    (N, C) uint8 ndarray
        One more (up to :data:`MAX_MISSES`) where a searched candidate is still unobserved;
        0 where the view is observed or not a candidate (so that a camera that newly sees the
        point is searched at once); unchanged elsewhere.
    """
    m = np.asarray(misses, np.uint8).T  # (C, N)
    failed = candidates & due & ~observed
    out = np.where(failed, np.minimum(m, MAX_MISSES - 1) + 1, m)
    out = np.where(observed | ~candidates, 0, out)
    return np.ascontiguousarray(out.T.astype(np.uint8))


def _directions(rig: CameraRig, X: np.ndarray, dtype: type = np.float64) -> np.ndarray:
    """(C, N, 3) unit directions from the points X (N, 3) to the camera centres, as ``dtype``.

    Computed in float64 one camera at a time (a (N, 3) block stays in cache; the whole (C, N,
    3) float64 array is 124 MB on paper69) and cast: the values of the whole-array form.
    """
    out = np.empty((len(rig), len(X), 3), dtype)
    for c, centre in enumerate(rig.C):
        d = centre - X
        out[c] = d / np.sqrt(squared_norm(d))[:, None]  # linalg.norm's values, at half its cost
    return out


def _observed_facing(rig: CameraRig, X: np.ndarray, observed: np.ndarray) -> np.ndarray:
    """:func:`_facing` from the observed views' directions alone (observed (C, N)), without
    the (C, N, 3) directions of every camera: a few views a point of 69 cameras."""
    cams, pts = np.nonzero(observed)  # camera by camera
    d = rig.C[cams] - X[pts]
    d = d / np.sqrt(squared_norm(d))[:, None]  # the values of _directions
    f = np.zeros((len(X), 3))
    bounds = np.searchsorted(cams, np.arange(len(observed) + 1))
    for a, b in zip(bounds[:-1], bounds[1:], strict=True):  # in camera order, as _facing sums
        f[pts[a:b]] += d[a:b]
    return f / np.maximum(np.linalg.norm(f, axis=1, keepdims=True), 1e-12)


def _facing(observed: np.ndarray, to_cams: np.ndarray) -> np.ndarray:
    """(N, 3) unit mean direction to the cameras observing each point (observed (C, N))."""
    f = np.einsum("cn,cnk->nk", observed.astype(to_cams.dtype), to_cams)
    return f / np.maximum(np.linalg.norm(f, axis=1, keepdims=True), 1e-12)


def depth_uncertainty(
    rig: CameraRig, xyz: np.ndarray, observed: np.ndarray, sigma_px: float = 1.0
) -> np.ndarray:
    """Standard deviation of each point's position along its worst-constrained direction.

    For a point seen from directions whose largest mutual angle is theta, by cameras at a
    distance where a pixel spans s metres, an image error of ``sigma_px`` moves it about
    ``sigma_px * s / sin(theta)`` along the rays.

    Parameters
    ----------
    rig : CameraRig
    xyz : (N, 3) float ndarray
    observed : (C, N) bool ndarray
    sigma_px : float

    Returns
    -------
    (N,) float64 ndarray
        Metres; infinite for a point observed by fewer than two cameras.
    """
    X = check_array("xyz", xyz, (None, 3))
    obs_all = check_array("observed", observed, (len(rig), len(X)), dtype=bool)
    centres = rig.C  # (C, 3)
    f = rig.K[:, 0, 0]  # (C,)
    out = np.full(len(X), np.inf)
    counts = obs_all.sum(axis=0)  # (N,)
    by_count = np.argsort(counts, kind="stable")  # chunks of points with alike view counts
    for a in range(0, len(X), _CHUNK):
        # only the observing cameras matter: gather them first (K of C per point)
        pts = by_count[a : a + _CHUNK]
        obs = obs_all[:, pts]
        K = int(counts[pts].max(initial=0))
        if K < 2:
            continue
        cams = observed_first(obs, K)  # (K, n) observing cameras first
        valid = np.arange(K)[:, None] < counts[None, pts]  # (K, n)
        d = centres[cams] - X[None, pts]  # (K, n, 3)
        dist = np.linalg.norm(d, axis=2)  # (K, n)
        u = (d / np.maximum(dist[..., None], 1e-12)).astype(np.float32)
        cos = np.einsum("cnk,dnk->ncd", u, u)  # (n, K, K)
        both = valid.T[:, :, None] & valid.T[:, None, :]
        min_cos = np.where(both, cos, 1.0).min(axis=(1, 2)).astype(np.float64)
        sin = np.sqrt(np.clip(1 - min_cos**2, 0.0, 1.0))
        scale = np.where(valid, dist / f[cams], 0.0).max(axis=0)  # metres per pixel
        with np.errstate(divide="ignore", invalid="ignore"):
            out[pts] = np.where(sin > 1e-6, sigma_px * scale / sin, np.inf)
    return out


def _references(
    to_cams: np.ndarray, observed: np.ndarray, cs: np.ndarray, ns: np.ndarray
) -> np.ndarray:
    """For candidate views (cs, ns), the observing camera whose direction to the point is
    nearest the candidate camera's (to_cams: (C, N, 3) unit directions; the lowest index
    among equals)."""
    out = np.empty(len(cs), np.int64)
    counts = observed.sum(axis=0)  # (N,)
    K = max(int(counts.max(initial=0)), 1)
    # each point's observing cameras, in index order, padded with unobserved ones: (N, K)
    cams = observed_first(observed, K).T
    valid = np.arange(K)[None, :] < counts[:, None]  # (N, K)
    by_count = np.argsort(counts[ns], kind="stable")  # chunks of points with alike view counts
    for a in range(0, len(cs), _CHUNK):
        idx = by_count[a : a + _CHUNK]
        c, n = cs[idx], ns[idx]
        k = max(int(counts[n].max(initial=0)), 1)
        kc = cams[n, :k]  # (m, k)
        cos = np.einsum("mk,mjk->mj", to_cams[c, n], to_cams[kc, n[:, None]])  # (m, k)
        best = np.argmax(np.where(valid[n, :k], cos, -2.0), axis=1)
        out[idx] = kc[np.arange(len(n)), best]
    return out


def discover_views(
    rig: CameraRig,
    images: Sequence[np.ndarray],
    xyz: np.ndarray,
    pixels: np.ndarray,
    candidates: np.ndarray,
    config: ViewsConfig | None = None,
    *,
    sigma_px: float = 1.0,
    confirm: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Find points in more cameras by a plane sweep from an observing camera.

    Parameters
    ----------
    rig : CameraRig
        C cameras.
    images : sequence of C (H, W) float32 ndarrays
        Undistorted grey images (:func:`pointtraj.reconstruct.densify.prepare_images`).
    xyz : (N, 3) float ndarray
    pixels : (C, N, 2) float ndarray
        Observations so far, distorted pixels (NaN where a camera does not observe the point).
    candidates : (C, N) bool ndarray
        Where to search (in the image, not occluded); observed views are skipped.
    config : ViewsConfig, optional
    sigma_px : float
        Image noise (px) that the depth range is derived from.
    confirm : (N,) bool ndarray, optional
        Points to confirm (the tracker's new ones): those observed in two cameras that no
        camera could be searched for are searched once more facing their cameras
        (within ``config.confirm_incidence_deg``, :data:`CONFIRM_INCIDENCE_DEG` where that is
        None), so that ``confirm_new`` can judge them.

    Returns
    -------
    pixels : (C, N, 2) float64 ndarray
        ``pixels`` with the new observations filled in.
    searched : (C, N) bool ndarray
        The views that were searched with a usable (textured) patch, found or not.
    """
    cfg = config or ViewsConfig()
    C = len(rig)
    if len(images) != C:
        raise ValidationError(f"discover_views: expected {C} images, got {len(images)}")
    X = check_array("xyz", xyz, (None, 3))
    N = len(X)
    pix = check_array("pixels", pixels, (C, N, 2)).astype(np.float64)
    cand = check_array("candidates", candidates, (C, N), dtype=bool)
    out, searched = _search(rig, images, X, pix, cand, cfg, sigma_px)
    facing_deg = cfg.confirm_incidence_deg
    facing_deg = CONFIRM_INCIDENCE_DEG if facing_deg is None else facing_deg
    if confirm is None or facing_deg <= 0:
        return out, searched
    observed = finite_rows(pix)  # (C, N)
    again = (
        check_array("confirm", confirm, (N,), dtype=bool)
        & (observed.sum(axis=0) == 2)
        & ~searched.any(axis=0)
        & (cand & ~observed).any(axis=0)
    )
    if again.any():
        idx = np.flatnonzero(again)
        facing = replace(cfg, normal="bisector", max_incidence_deg=facing_deg)
        out[:, idx], searched[:, idx] = _search(
            rig, images, X[idx], pix[:, idx], cand[:, idx], facing, sigma_px
        )
        logger.debug(
            "view discovery: %d two-view points searched again facing their cameras, %d of "
            "them with a usable patch",
            idx.size,
            int(searched[:, idx].any(axis=0).sum()),
        )
    return out, searched


def _search(
    rig: CameraRig,
    images: Sequence[np.ndarray],
    X: np.ndarray,
    pix: np.ndarray,
    cand: np.ndarray,
    cfg: ViewsConfig,
    sigma_px: float,
) -> tuple[np.ndarray, np.ndarray]:
    """The plane sweep of :func:`discover_views` (checked inputs; ``pix`` float64)."""
    C, N = len(rig), len(X)
    out = pix.copy()
    searched = np.zeros((C, N), bool)
    observed = finite_rows(pix)  # (C, N)
    cand = cand & ~observed & (observed.sum(axis=0) >= 1)[None, :]
    if not cand.any():
        return out, searched
    to_cams = _directions(rig, X, np.float32)  # (C, N, 3)
    if cfg.normal == "neighbors":
        normals = point_normals(rig, X, observed, cfg.normal_neighbors)
    else:
        normals = _facing(observed, to_cams)
    incidence = np.einsum("cnk,nk->cn", to_cams, normals)  # cos of the incidence angle
    cand &= incidence >= np.cos(np.radians(cfg.max_incidence_deg))
    if not cand.any():
        return out, searched
    cs, ns = np.nonzero(cand)
    rs = _references(to_cams, observed, cs, ns)
    sigma = np.full(N, np.inf)
    some = np.unique(ns)  # only the points with a candidate
    sigma[some] = depth_uncertainty(rig, X[some], observed[:, some], sigma_px)
    half = np.clip(cfg.depth_sigmas * sigma, cfg.min_depth_range_m, cfg.max_depth_range_m)
    ideal = rig.undistort_pixels(np.where(observed[..., None], pix, np.nan))
    h = (cfg.patch_size - 1) / 2
    off = (np.arange(cfg.patch_size) - h) * cfg.spacing_px
    offsets = np.stack(np.meshgrid(off, off), axis=-1).reshape(-1, 2)  # (P, 2)
    steps = np.linspace(-1.0, 1.0, cfg.depth_steps)  # (D,) in units of the half-range
    across = _across_offsets(cfg, sigma_px)  # (S,) pixels across the epipolar line
    found = 0
    # Two passes, so that each camera's prepared image is needed in one stretch (the prepared
    # images are kept within a memory budget): reference patches camera by camera, then the
    # sweeps camera by searched camera.
    K = len(cs)
    ref = np.zeros((K, len(offsets)), np.float32)
    textured = np.zeros(K, bool)
    by_ref = np.argsort(rs, kind="stable")
    for group in np.split(by_ref, np.flatnonzero(np.diff(rs[by_ref])) + 1):
        r = int(rs[group[0]])
        patch = ideal[r, ns[group]][:, None, :] + offsets[None]  # (k, P, 2)
        z, std = _zscore(_sample(images[r], patch[..., 0], patch[..., 1]))
        ok = np.isfinite(std) & (std >= cfg.min_std) & np.all(np.isfinite(z), axis=1)
        ref[group] = np.where(ok[:, None], z, 0.0)
        textured[group] = ok
    # The sweeps camera by searched camera c: the patches of all of c's reference cameras
    # are set up, scored in one NCC call (each row with its reference camera's warp) and
    # accepted together, then projected into c at once (camera c alone: projecting into every
    # camera is C times the work). Rows are grouped by reference camera within c.
    pair = cs * C + rs
    order = np.argsort(pair, kind="stable")
    cut = np.flatnonzero(np.diff(pair[order])) + 1
    starts = np.concatenate([[0], cut, [len(order)]])  # (G + 1,) group bounds in ``order``
    group_cam = cs[order[starts[:-1]]]
    chunks = np.concatenate([[0], np.flatnonzero(np.diff(group_cam)) + 1, [len(group_cam)]])
    for g0, g1 in zip(chunks[:-1], chunks[1:], strict=True):
        rows = order[starts[g0] : starts[g1]]
        c = int(cs[rows[0]])
        n, r = ns[rows], rs[rows]
        st = _sweep_setup(
            rig, c, r, starts[g0 : g1 + 1] - starts[g0], X[n],
            _plane_normals(cfg, normals[n], to_cams[r, n], to_cams[c, n]),
            ideal[r, n], half[n], offsets, steps, textured[rows], across,
        )  # fmt: skip
        searched[c, n] = st.usable
        if not st.u.size:
            continue
        scores, which = _sweep_scores(images[c], rig, c, st, ref[rows[st.u]])
        ok, Xb, shift = _sweep_finish(rig, st, scores, which, half[n], steps, cfg)
        if ok.any():
            p = CameraRig([rig[c]]).project(Xb[ok])
            inside = p.in_image[0]
            sel = n[ok][inside]
            out[c, sel] = p.pixels[0][inside] + shift[ok][inside]
            found += sel.size
    logger.debug("view discovery: %d of %d candidate views found", found, len(cs))
    return out, searched


def _across_offsets(cfg: ViewsConfig, sigma_px: float) -> np.ndarray:
    """(S,) offsets (pixels) across the epipolar line tried by the sweep (only 0 where the
    search does not reach beyond the patch spacing)."""
    half = cfg.search_sigmas * sigma_px
    step = max(sigma_px / 2, cfg.spacing_px)
    if half <= cfg.spacing_px:
        return np.zeros(1)
    k = int(np.floor(half / step + 1e-9))
    return np.arange(-k, k + 1) * step


def _plane_normals(
    cfg: ViewsConfig, normals: np.ndarray, to_r: np.ndarray, to_c: np.ndarray
) -> np.ndarray:
    """The normals of the planes swept: the points' own, or the bisector of the directions to
    the reference and the searched camera."""
    if cfg.normal != "bisector":
        return normals
    b = to_r.astype(np.float64) + to_c
    return b / np.maximum(np.linalg.norm(b, axis=1, keepdims=True), 1e-12)


@dataclass
class _SweepSetup:
    """The candidate views of one searched camera c, ready to score: n rows, grouped by
    reference camera.

    Attributes
    ----------
    r : (n,) int ndarray
        Each row's reference camera.
    bounds : (G + 1,) int ndarray
        The groups' row bounds: rows ``bounds[i]:bounds[i + 1]`` share one reference camera.
    usable : (n,) bool ndarray
        Whose patch can be compared (textured, plane not grazing in r).
    u : (m,) int ndarray
        ``flatnonzero(usable)``.
    rays : (n, P, 3) float ndarray
        The patches' sample rays in r's frame, scaled to the plane (depth 1 at the centre;
        meaningful where usable).
    z : (n, D) float ndarray
        Depth hypotheses in r.
    centre_ray : (n, 3) float ndarray
        The rays through the observations in r.
    shifts : (m, S, 2) float ndarray or None
        Offsets across the epipolar line in c (None without ``across``).
    """

    r: np.ndarray
    bounds: np.ndarray
    usable: np.ndarray
    u: np.ndarray
    rays: np.ndarray
    z: np.ndarray
    centre_ray: np.ndarray
    shifts: np.ndarray | None

    def groups(self) -> list[tuple[int, int, int]]:
        """(reference camera, first row, end row) of each group."""
        return _groups(self.r, self.bounds)


def _sweep_setup(
    rig: CameraRig,
    c: int,
    r: np.ndarray,
    bounds: np.ndarray,
    X: np.ndarray,
    normals: np.ndarray,
    ideal_r: np.ndarray,
    half: np.ndarray,
    offsets: np.ndarray,
    steps: np.ndarray,
    textured: np.ndarray,
    across: np.ndarray,
) -> _SweepSetup:
    """The plane sweep of points X (n, 3) seen in reference cameras r (n,), grouped by
    reference camera (``bounds``, see :class:`_SweepSetup`), for camera c: the patches' rays
    on each point's plane (``normals`` (n, 3)), through its observation ``ideal_r`` (n, 2),
    and the depths swept (``half`` (n,) times ``steps`` (D,)). ``textured`` (n,) are the
    usable reference patches, ``across`` (S,) the offsets (pixels) across the epipolar line
    tried at every depth.

    Every value is computed row by row as for one reference camera at a time: the products
    with a camera's rotation stay one matrix product per group, the rest is element-wise.
    """
    K = rig.K[r]  # (n, 3, 3)
    patch = ideal_r[:, None, :] + offsets[None]  # (n, P, 2)
    rays = _rays(K, patch)  # (n, P, 3), camera frame, z = 1
    centre_ray = _rays(K, ideal_r)  # (n, 3)
    groups = _groups(r, bounds)
    nr = np.empty_like(normals)  # normals in r's frame
    z0 = np.empty(len(X))  # the points' depths in r
    for ref, a, b in groups:
        cam = rig[ref]
        nr[a:b] = normals[a:b] @ cam.R.T
        z0[a:b] = ((X[a:b] - cam.C) @ cam.R.T)[:, 2]
    with np.errstate(invalid="ignore", divide="ignore"):
        w = np.einsum("nk,nk->n", nr, centre_ray)[:, None] / np.einsum("npk,nk->np", rays, nr)
    w = np.where(np.isfinite(w) & (w > 0.2) & (w < 5.0), w, np.nan)  # (n, P): plane depth ratio
    usable = textured & np.all(np.isfinite(w), axis=1)
    rays *= w[..., None]
    # depth of the ray through the observation where it passes the point (the observation
    # may sit a little off the point's projection)
    z = z0[:, None] + half[:, None] * steps[None, :]  # (n, D)
    u = np.flatnonzero(usable)
    shifts = None
    if len(across) > 1:
        normal = np.zeros((len(X), 2))  # (n, 2)
        for ref, a, b in groups:
            v = a + np.flatnonzero(usable[a:b])
            if v.size:
                normal[v] = _epipolar_normals(rig[c], rig[ref], X[v], half[v])
        shifts = across[None, :, None] * normal[u, None, :]  # (m, S, 2)
    return _SweepSetup(r, bounds, usable, u, rays, z, centre_ray, shifts)


def _groups(r: np.ndarray, bounds: np.ndarray) -> list[tuple[int, int, int]]:
    """(reference camera, first row, end row) of each group of rows ``bounds`` (G + 1,) that
    share a reference camera (r (n,) per row)."""
    return [(int(r[i]), int(i), int(j)) for i, j in zip(bounds[:-1], bounds[1:], strict=True)]


def _sweep_scores(
    image: np.ndarray, rig: CameraRig, c: int, st: _SweepSetup, ref: np.ndarray
) -> tuple[np.ndarray, np.ndarray | None]:
    """NCC scores of the sweeps of :func:`_sweep_setup` into camera c (its prepared
    ``image``), in one call (:func:`~.densify._ncc_warped`); ``ref`` (m, P) are the usable
    rows' reference patches. Returns the (n, D) scores (-1 where not usable) and, with
    shifts, the (m, D) index of the best shift."""
    m = st.u.size
    B = np.empty((m, st.rays.shape[1], 3), np.float32)
    k = np.empty((m, 3), np.float32)
    lo = np.searchsorted(st.u, st.bounds)  # the usable rows' group bounds
    for (ref_cam, _, _), a, b in zip(st.groups(), lo[:-1], lo[1:], strict=True):
        if a == b:
            continue
        M, kk = _warp(rig[c], rig[ref_cam])
        B[a:b] = st.rays[st.u[a:b]].astype(np.float32) @ M.T  # (m, P, 3)
        k[a:b] = kk
    ncc = _ncc_warped(image, B, k, st.z[st.u], ref, st.shifts)
    scores = np.full(st.z.shape, -1.0)
    scores[st.u] = ncc[0] if st.shifts is not None else ncc
    return scores, ncc[1] if st.shifts is not None else None


def _sweep_finish(
    rig: CameraRig,
    st: _SweepSetup,
    scores: np.ndarray,
    which: np.ndarray | None,
    half: np.ndarray,
    steps: np.ndarray,
    cfg: ViewsConfig,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Acceptance of a sweep (:func:`_sweep_setup`, scores (n, D) from :func:`_sweep_scores`).

    Returns
    -------
    accepted : (n,) bool ndarray
    best : (n, 3) float ndarray
        The points at their best depth along r's rays through their observations.
    shift : (n, 2) float ndarray
        Where c sees them relative to the best point's projection (pixels, across the
        epipolar line; 0 without shifts).
    """
    n, D = scores.shape
    best = np.argmax(scores, axis=1)
    top = scores[np.arange(n), best]
    far = np.abs(np.arange(D)[None, :] - best[:, None]) > cfg.peak_width
    rival = np.where(far, scores, -np.inf).max(axis=1)
    interior = (best > 0) & (best < D - 1)
    accept = st.usable & interior & (top >= cfg.min_ncc) & (top - rival >= cfg.min_margin)
    b = np.clip(best, 1, D - 2)
    y0, y1, y2 = (scores[np.arange(n), b + k] for k in (-1, 0, 1))
    with np.errstate(invalid="ignore", divide="ignore"):
        delta = np.clip(0.5 * (y0 - y2) / (y0 - 2 * y1 + y2), -0.5, 0.5)
    delta = np.where(np.isfinite(delta), delta, 0.0)
    z_best = st.z[np.arange(n), b] + delta * half * (steps[1] - steps[0])
    Xb = np.empty((n, 3))
    for ref, a, e in st.groups():
        cam = rig[ref]
        Xb[a:e] = cam.C + (z_best[a:e, None] * st.centre_ray[a:e]) @ cam.R  # world
    shift = np.zeros((n, 2))
    if which is not None:
        j = which[np.arange(st.u.size), best[st.u]]
        shift[st.u] = st.shifts[np.arange(st.u.size), j]
    return accept, Xb, shift


def _epipolar_normals(other, cam, X: np.ndarray, half: np.ndarray) -> np.ndarray:
    """(n, 2) unit image directions in ``other`` across the epipolar lines of the points X
    (n, 3) seen by ``cam``: perpendicular to the image of each point's ray segment of +-half."""
    d = X - cam.C
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    ends = [X - half[:, None] * d, X + half[:, None] * d]
    pix = [other.project(e)[0] for e in ends]  # (n, 2) each
    along = pix[1] - pix[0]
    along = along / np.maximum(np.linalg.norm(along, axis=1, keepdims=True), 1e-12)
    return np.stack([-along[:, 1], along[:, 0]], axis=1)
