"""3D point tracking by multi-view optical flow (paper Section 5, steps 2-3).

At every frame t the live points ``X_{t-1}`` are projected into the cameras where
``V(X_{t-1}, c) > eps_s``, tracked there to frame t with pyramidal Lucas-Kanade (one batched call
per camera, with a forward-backward check; :mod:`.flow`), re-triangulated with RANSAC from the
tracked 2D positions, and their visibility is updated from the reprojection errors (and an
occlusion test against the frame's own points). A trajectory stops when its mean reprojection
error exceeds ``max_mean_error_px`` or fewer than ``min_views`` cameras still see it. Dense
matching (:mod:`.matching`) then triangulates new points; those not already covered by a live
trajectory start new trajectories. Trajectories thus emerge and dissolve at different times.

This module holds the :class:`Tracker`, its state (:class:`TrackState`) and per-frame output
(:class:`FrameRecord`); :mod:`.stage` streams a capture through it.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ..camera import CameraRig, Projection
from ..errors import ValidationError, check_array
from ..geometry import axis_angles, finite_rows, pixel_distance
from ..trajectories import quantize_visibility
from .config import ReconstructConfig
from .flow import STILL_VIEWS_PER_PIXEL, expand_views, still_flow, to_grey, track_flow
from .matching import MultiViewTracks, match_frame, moving_boxes, near_pixels, resolve_ambiguous
from .reacquire import LostViews, cut_patches, search_patches
from .survive import carry_one_view, predict_rigid
from .views import (
    depth_uncertainty,
    discover_views,
    grazing_views,
    record_misses,
    refuted,
    retry_due,
    retry_periods,
)

if TYPE_CHECKING:  # pragma: no cover
    from .triangulate import Triangulation

__all__ = [
    "TrackState",
    "FrameRecord",
    "Tracker",
    "config_edges",
    "select_edges",
    "covered_by",
    "effective_fb_skip",
    "sample_colors",
]

logger = logging.getLogger(__name__)

#: Why a trajectory ends: its flow succeeded in fewer than ``min_views`` cameras (lost by
#: Lucas-Kanade or the forward-backward check, or out of the images); the RANSAC
#: re-triangulation failed or its error exceeded ``max_mean_error_px``; the occlusion test hid
#: views it had; or fewer than ``min_views`` of its re-triangulated views kept a visibility
#: above ``visibility_threshold``; or, on fewer than two views already (``[reconstruct.survive]``),
#: it lost its last one, its view and its neighbours' motion disagreed, or its frames ran out.
#: Or, left with two views, its search failed in ``[reconstruct.views] unconfirmed_fails`` cameras.
STOP_REASONS = ("flow", "triangulation", "occlusion", "visibility", "one-view", "unconfirmed")


@dataclass
class TrackState:
    """The live trajectories after a frame.

    Attributes
    ----------
    frame : int
        The frame these positions belong to.
    ids : (N,) int64 ndarray
        Trajectory id of each live point.
    xyz : (N, 3) float64 ndarray
    visibility : (N, C) float32 ndarray
    pixels : (C, N, 2) float32 ndarray
        Tracked (inlier) observations, NaN where the camera does not see the point.
    next_id : int
        The id the next new trajectory gets.
    lone : (N,) int64 ndarray, optional
        Frames each point has gone on with fewer than two views (0 where it has two or more;
        :mod:`~.survive`). Default: all 0.
    misses : (N, C) uint8 ndarray, optional
        View discovery's failed searches in a row per point and camera, the back-off of
        :func:`~.views.retry_due` (0: search the camera at the next frame). Default: all 0.
    densify_backlog : bool
        The frame's densification stopped at ``densify.max_points``: the next frame densifies
        as a matched frame does, also where it lies between whole-image matchings
        (``densify.between_motion_px``).
    lost : LostViews, optional
        The lost views that points on fewer than two views may get back
        (:mod:`~.reacquire`). Default: none.
    """

    frame: int
    ids: np.ndarray
    xyz: np.ndarray
    visibility: np.ndarray
    pixels: np.ndarray
    next_id: int
    lone: np.ndarray | None = None
    misses: np.ndarray | None = None
    densify_backlog: bool = False
    lost: LostViews | None = None

    def __post_init__(self) -> None:
        if self.lost is None:
            self.lost = LostViews.empty()
        if self.lone is None:
            self.lone = np.zeros(len(self.ids), np.int64)
        if self.misses is None:
            self.misses = np.zeros((len(self.ids), self.visibility.shape[1]), np.uint8)

    @classmethod
    def empty(cls, num_cameras: int, frame: int = -1) -> TrackState:
        """No live trajectories."""
        return cls(
            frame,
            np.zeros(0, np.int64),
            np.zeros((0, 3)),
            np.zeros((0, num_cameras), np.float32),
            np.zeros((num_cameras, 0, 2), np.float32),
            0,
        )

    def __len__(self) -> int:
        return int(self.ids.shape[0])


@dataclass(frozen=True)
class FrameRecord:
    """The point-frames of one frame, as they go into the trajectory store.

    Attributes
    ----------
    frame : int
    ids : (N,) int64 ndarray
    xyz : (N, 3) float32 ndarray
    visibility : (N, C) uint8 ndarray
        Quantised ``round(255 V)``.
    error : (N,) float32 ndarray
        Mean inlier reprojection error (pixels).
    color : (N, 3) uint8 ndarray
    num_new : int
        How many of the points started a trajectory at this frame.
    """

    frame: int
    ids: np.ndarray
    xyz: np.ndarray
    visibility: np.ndarray
    error: np.ndarray
    color: np.ndarray
    num_new: int = 0

    def __len__(self) -> int:
        return int(self.ids.shape[0])


# -- building blocks --------------------------------------------------------------------------


def select_edges(
    rig: CameraRig,
    max_angle_deg: float = 90.0,
    max_pairs_per_camera: int = 0,
    *,
    min_overlap: float = 0.2,
    volume: np.ndarray | None = None,
) -> np.ndarray:
    """Camera pairs to match: the connectivity graph, optionally thinned per camera.

    Parameters
    ----------
    rig : CameraRig
    max_angle_deg : float
        Pairs whose viewing directions differ by more are unlikely to match (paper Section 5).
    max_pairs_per_camera : int
        If positive, each camera keeps only its this-many smallest-angle partners (a pair is kept
        when either camera keeps it); the pairs left out are logged as a warning.
    min_overlap : float
        Shared-view cut-off relative to the rig's (:func:`~.connectivity.build_connectivity`).
    volume : (2, 3) float ndarray, optional
        The capture volume (default: the cameras' common view).

    Returns
    -------
    (E, 2) int64 ndarray
        Pairs ``a < b``.
    """
    from .connectivity import build_connectivity

    graph = build_connectivity(rig, max_angle_deg, min_overlap, volume=volume)
    edges = np.sort(np.asarray(graph.edges, dtype=np.int64).reshape(-1, 2), axis=1)
    angles = np.asarray(graph.angles_deg, dtype=float).reshape(-1)
    if max_pairs_per_camera <= 0 or edges.size == 0:
        return edges
    keep = np.zeros(len(edges), bool)
    # per camera, rank its incident edges by angle (vectorised over the 2E incidences)
    cam = np.concatenate([edges[:, 0], edges[:, 1]])
    eid = np.concatenate([np.arange(len(edges))] * 2)
    order = np.lexsort((angles[eid], cam))
    sorted_cam = cam[order]
    rank = np.arange(order.size) - np.searchsorted(sorted_cam, sorted_cam, side="left")
    keep[eid[order[rank < max_pairs_per_camera]]] = True
    if not keep.all():
        logger.warning(
            "connectivity: %d of %d camera pairs not matched: beyond both cameras' "
            "max_pairs_per_camera = %d smallest-angle partners (it bounds the matching cost)",
            int((~keep).sum()),
            len(edges),
            max_pairs_per_camera,
        )
    return edges[keep]


def config_edges(rig: CameraRig, config: ReconstructConfig) -> np.ndarray:
    """:func:`select_edges` with a config's settings (``max_angle_deg``,
    ``max_pairs_per_camera``, ``min_pair_overlap``, ``capture_volume``).

    Returns
    -------
    (E, 2) int64 ndarray
    """
    return select_edges(
        rig,
        config.max_angle_deg,
        config.max_pairs_per_camera,
        min_overlap=config.min_pair_overlap,
        volume=None if config.capture_volume is None else np.array(config.capture_volume),
    )


def covered_by(
    live_pixels: np.ndarray, new_pixels: np.ndarray, radius_px: float, min_views: int
) -> np.ndarray:
    """Which new points a live trajectory already covers (:func:`~.matching.near_pixels` per
    camera).

    Parameters
    ----------
    live_pixels : (C, N, 2) float ndarray
        Live trajectories' observations at this frame (NaN where absent).
    new_pixels : (C, Q, 2) float ndarray
        New points' observations (NaN where absent).
    radius_px : float
    min_views : int

    Returns
    -------
    (Q,) bool ndarray
        True where, in at least ``min_views`` cameras, some live observation lies within
        ``radius_px`` of the new point's observation.
    """
    live = check_array("live_pixels", live_pixels, (None, None, 2))
    new = check_array("new_pixels", new_pixels, (live.shape[0], None, 2))
    hits = np.zeros(new.shape[1], np.int64)
    for c in range(live.shape[0]):  # one vectorised query per camera
        hits += near_pixels(live[c], new[c], radius_px)
    return hits >= min_views


def sample_colors(
    images: Sequence[np.ndarray], pixels: np.ndarray, visibility: np.ndarray
) -> np.ndarray:
    """RGB colour of each point in its most visible camera.

    Parameters
    ----------
    images : list of C (H, W, 3) uint8 RGB ndarrays
    pixels : (C, N, 2) float ndarray
        Observations (NaN where absent).
    visibility : (N, C) float ndarray

    Returns
    -------
    (N, 3) uint8 ndarray
        Grey 128 where no camera observes the point.
    """
    pix = check_array("pixels", pixels, (len(images), None, 2))
    N = pix.shape[1]
    vis = np.where(finite_rows(pix).T, visibility, -1.0)  # (N, C)
    best = np.argmax(vis, axis=1) if N else np.zeros(0, np.int64)
    out = np.full((N, 3), 128, np.uint8)
    has = vis[np.arange(N), best] >= 0 if N else np.zeros(0, bool)
    for c, img in enumerate(images):
        sel = np.flatnonzero(has & (best == c))
        if sel.size == 0:
            continue
        h, w = img.shape[:2]
        x = np.clip(np.rint(pix[c, sel, 0]).astype(np.int64), 0, w - 1)
        y = np.clip(np.rint(pix[c, sel, 1]).astype(np.int64), 0, h - 1)
        out[sel] = img[y, x]
    return out


def occlusion_tolerance(
    config: ReconstructConfig, rig: CameraRig, xyz: np.ndarray, observed: np.ndarray
) -> float | np.ndarray:
    """The occlusion test's depth tolerance for each of a frame's points.

    Parameters
    ----------
    config : ReconstructConfig
        ``occlusion_sigmas``, ``occlusion_min_m``, ``occlusion_depth_m`` and ``sigma_px``.
    rig : CameraRig
        C cameras.
    xyz : (N, 3) float ndarray
    observed : (C, N) bool ndarray
        The cameras observing each point.

    Returns
    -------
    float or (N,) float64 ndarray
        Metres: ``2 * occlusion_sigmas`` standard deviations of each point's depth
        (:func:`~.views.depth_uncertainty`) within ``[occlusion_min_m, occlusion_depth_m]``
        (the upper bound for a point on one view); ``occlusion_depth_m`` for every point when
        ``occlusion_sigmas`` is 0.
    """
    if config.occlusion_sigmas <= 0:
        return config.occlusion_depth_m
    sigma = depth_uncertainty(rig, xyz, observed, config.sigma_px)
    return np.clip(
        2 * config.occlusion_sigmas * sigma, config.occlusion_min_m, config.occlusion_depth_m
    )


# -- the tracker ------------------------------------------------------------------------------


def effective_fb_skip(cfg: ReconstructConfig, *, log: bool = False) -> int:
    """The camera count from which tracked points skip the backward flow check (0: none skip).

    ``cfg.fb_skip_views`` where the re-triangulation can stand in for the check: its RANSAC
    drops a view that the flow lost only when the view lands farther than
    ``ransac_threshold_px`` from where the other views put the point, so the skip applies
    where that tolerance is at most twice ``fb_max_px``. On a rig calibrated to several
    pixels (Pose2Sim's pipeline: 12 px) RANSAC would keep a view that drifted by up to 12 px,
    which the backward check drops at 1 px: there every point keeps the check.

    Parameters
    ----------
    cfg : ReconstructConfig
    log : bool
        Log, at INFO, when the configured skip is turned off.

    Returns
    -------
    int
    """
    if not cfg.fb_skip_views or cfg.ransac_threshold_px <= 2 * cfg.fb_max_px:
        return cfg.fb_skip_views
    if log:
        logger.info(
            "every tracked point keeps the forward-backward flow check (fb_skip_views = %d "
            "not applied): ransac_threshold_px = %g is above twice fb_max_px = %g, so the "
            "re-triangulation would keep a view that the flow lost",
            cfg.fb_skip_views,
            cfg.ransac_threshold_px,
            cfg.fb_max_px,
        )
    return 0


class Tracker:
    """Frame-by-frame trajectory reconstruction (tracking -> triangulation -> visibility).

    Parameters
    ----------
    rig : CameraRig
        C cameras.
    config : ReconstructConfig, optional
    edges : (E, 2) int ndarray, optional
        Camera pairs to match (default :func:`select_edges` with the config's settings).
    state : TrackState, optional
        Resume from this state (its frame must precede the next :meth:`step`).
    first_frame : int, optional
        Phase of ``config.match_every``: matching runs at frames ``first_frame + k * match_every``
        (default: the first frame stepped), and whenever tracking restarts.
    """

    def __init__(
        self,
        rig: CameraRig,
        config: ReconstructConfig | None = None,
        edges: np.ndarray | None = None,
        state: TrackState | None = None,
        first_frame: int | None = None,
    ) -> None:
        self.rig = rig
        self.config = (config or ReconstructConfig()).for_rig(rig)
        self.tri_config = self.config.triangulation()
        if edges is None:
            edges = config_edges(rig, self.config)
        self.edges = check_array("edges", edges, (None, 2), dtype=np.int64)
        self.state = state if state is not None else TrackState.empty(len(rig))
        # view expansion by flow can only find something where two cameras are close enough
        angles = axis_angles(rig)
        np.fill_diagonal(angles, np.inf)
        near = angles <= self.config.expand_max_angle_deg
        self._expand_views = self.config.expand_views and bool(near.any())
        # coverage by visible projections: where discovery leaves cameras unsearched for frames
        self._cover_visible = {"on": True, "off": False}.get(
            self.config.cover_visible, retry_periods(self.config.views, len(rig))[0] > 1
        )
        if self.config.expand_views and not self._expand_views and len(rig) > 1:
            logger.warning(
                "view expansion by flow is off on this rig: no two cameras' optical axes are "
                "within expand_max_angle_deg = %.0f degrees (the nearest pair: %.1f); %s",
                self.config.expand_max_angle_deg,
                float(angles.min()),
                "view discovery by plane sweep ([reconstruct.views]) searches every baseline"
                if self.config.views.enabled
                else "points will mostly keep the two views they were matched in",
            )
        alone = ~(angles <= self.config.densify.max_angle_deg).any(axis=1)  # (C,)
        if self.config.densify.enabled and alone.any() and len(rig) > 1:
            logger.warning(
                "densification does not start from cameras %s: no other camera's optical axis "
                "is within [reconstruct.densify] max_angle_deg = %.0f degrees of theirs",
                ", ".join(rig.names[c] for c in np.flatnonzero(alone)),
                self.config.densify.max_angle_deg,
            )
        self._fb_skip = effective_fb_skip(self.config, log=True)
        lonely = [rig.names[c] for c in range(len(rig)) if not np.isin(c, self.edges).any()]
        if lonely and len(rig) > 1:
            logger.warning(
                "cameras %s are matched with no other camera (max_angle_deg = %.0f, "
                "max_pairs_per_camera = %d): they add views to points but start none",
                ", ".join(lonely),
                self.config.max_angle_deg,
                self.config.max_pairs_per_camera,
            )
        self._prev_grey: list[np.ndarray] | None = None
        # the live points' projection (C, N, 2) at the end of a step, with the state it
        # belongs to: the next step's flow starts there (``lk_start = "projection"``)
        self._projected: tuple[TrackState, np.ndarray] | None = None
        self._first_frame = first_frame
        #: Why trajectories ended, counted over the frames stepped (:data:`STOP_REASONS`).
        self.stops: dict[str, int] = dict.fromkeys(STOP_REASONS, 0)
        #: Tracked views over the frames stepped: ``"still"`` took their flow from one
        #: Lucas-Kanade step (``still_px``), ``"pyramidal"`` from the pyramidal flow.
        self.flows: dict[str, int] = {"still": 0, "pyramidal": 0}

    def set_previous_images(self, images: Sequence[np.ndarray]) -> None:
        """Give the images of ``state.frame`` (needed to resume tracking)."""
        self._prev_grey = [to_grey(im) for im in images]

    # -- one frame -----------------------------------------------------------------------------
    def step(self, t: int, images: Sequence[np.ndarray]) -> FrameRecord:
        """Advance to frame ``t``.

        Parameters
        ----------
        t : int
            The frame index (``state.frame + 1`` to continue trajectories; any other frame
            starts afresh).
        images : list of C (H, W, 3) uint8 RGB ndarrays
            The frame's images in rig order.

        Returns
        -------
        FrameRecord
            The points alive at frame t.
        """
        from .triangulate import triangulate_ransac

        cfg = self.config
        rig = self.rig
        C = len(rig)
        if len(images) != C:
            raise ValidationError(f"images: expected {C} images, got {len(images)}")
        grey = [to_grey(im) for im in images]
        st = self.state
        restart = st.frame != t - 1 or self._prev_grey is None
        if restart:
            if len(st):
                logger.info("frame %d does not follow %d: live trajectories end", t, st.frame)
            st = TrackState(t - 1, *_empty_live(C), next_id=st.next_id)
        if self._first_frame is None:
            self._first_frame = t

        # 1. tracking: LK flow of the live points in their visible cameras
        obs = np.full((C, len(st), 2), np.nan)
        still = flowed = 0  # views tracked by one step, and by the pyramidal flow
        if len(st):
            if cfg.lk_start == "projection":
                if self._projected is not None and self._projected[0] is st:
                    start = self._projected[1]  # (C, N, 2), kept by the last step
                else:
                    start = rig.project(st.xyz).pixels
            else:
                start = st.pixels.astype(np.float64)
            seen_in = st.visibility > cfg.visibility_threshold  # (N, C)
            check = None  # points in fb_skip_views cameras or more: RANSAC checks their flow
            if self._fb_skip:
                check = np.count_nonzero(seen_in, axis=1) < self._fb_skip
            for c in range(C):
                sel = np.flatnonzero(seen_in[:, c])
                dense = sel.size >= STILL_VIEWS_PER_PIXEL * grey[c].size  # the step pays
                if dense and cfg.still_px > 0:  # windows that barely move: one LK step
                    obs[c, sel] = still_flow(
                        self._prev_grey[c],
                        grey[c],
                        start[c, sel],
                        window=cfg.lk_window,
                        max_px=cfg.still_px,
                        noise_ratio=cfg.still_noise,
                    )
                    taken = np.isfinite(obs[c, sel, 0])
                    still += int(taken.sum())
                    sel = sel[~taken]
                if sel.size:
                    flowed += sel.size
                    obs[c, sel] = track_flow(
                        self._prev_grey[c],
                        grey[c],
                        start[c, sel],
                        window=cfg.lk_window,
                        levels=cfg.lk_levels,
                        fb_max_px=cfg.fb_max_px,
                        check=None if check is None else check[sel],
                    )
        self.flows["still"] += still
        self.flows["pyramidal"] += flowed
        tri_old = triangulate_ransac(rig, obs, self.tri_config)
        triangulated = self._alive(tri_old)
        keep_old = triangulated
        lost, regained = LostViews.empty(), 0  # views that carried points may get back
        if cfg.survive.frames > 0 and len(st):
            tri_old, carried, back, lost = self._carry(st, grey, obs, tri_old, triangulated)
            triangulated = triangulated | back
            keep_old = triangulated | carried
            regained = int(back.sum())

        # 2. dense matching: new points where no live trajectory is, every match_every frames;
        # in between (match_moving) only around the moving points. Densification grows from
        # the new matches and the tracked points that moved; in between from the fast ones.
        new_tri, new_obs = None, np.zeros((C, 0, 2))
        live_proj, cover = None, np.zeros((C, 0, 2))
        matching = restart or (t - self._first_frame) % cfg.match_every == 0
        in_between = not matching and cfg.match_moving  # match around the moving points
        dcfg = cfg.densify
        whole = matching or st.densify_backlog  # densify as on a matched frame
        densifying = dcfg.enabled and (whole or np.isfinite(dcfg.between_seed_px))
        moved = seeding = None  # (N,) tracked points whose image moved, that seed densify
        if in_between or (densifying and (not whole or dcfg.seeds == "moving")):
            motion = _image_motion(obs, st.pixels)
            moved = motion > dcfg.seed_motion_px
            if not whole:
                seeding = motion > dcfg.between_seed_px
            elif dcfg.seeds == "moving":
                seeding = moved
        boxes = None  # per camera, where to match on a frame between matched ones
        if matching or in_between or densifying:
            # where the live trajectories are followed
            observed = np.where(tri_old.inliers[:, keep_old, None], obs[:, keep_old], np.nan)
            if in_between and keep_old.any():
                boxes = moving_boxes(observed, moved[keep_old], rig.sizes)
                if not any(len(b) for b in boxes):
                    boxes = None
        if matching or boxes is not None or densifying:
            cover = observed
            if self._cover_visible and keep_old.any():
                live_proj, cover = self._cover_pixels(
                    tri_old.points[keep_old],
                    tri_old.visibility[keep_old],
                    cover,
                    st.misses[keep_old],
                )
        if matching or boxes is not None:
            skip = observed if cfg.match_skip_px > 0 and observed.shape[1] else None
            tracks = match_frame(
                rig,
                images,
                self.edges,
                cfg.matching,
                skip=skip,
                skip_px=cfg.match_skip_px,
                boxes=boxes,
            )
            new_tri, new_obs = self._triangulate_tracks(tracks)
            keep_new = self._alive(new_tri) & (
                np.count_nonzero(new_tri.inliers, axis=0) >= cfg.min_views_new
            )
            new_pix = np.where(new_tri.inliers[..., None], new_obs, np.nan)
            covered = covered_by(cover, new_pix, cfg.cover_px, cfg.cover_views)
            keep_new &= ~covered
            logger.debug("frame %d: %d new points, %d covered", t, keep_new.sum(), covered.sum())

        # 3. union, more views, occlusion, visibility, stopping rule
        prepared = None
        if cfg.densify.enabled or cfg.views.enabled:
            from .densify import prepare_images

            prepared = prepare_images(rig, grey)
        parts = [(tri_old, obs, keep_old)]
        if new_tri is not None:
            parts.append((new_tri, new_obs, keep_new))
        backlog = False  # densification stopped at its max_points
        if densifying:  # the tracked points that moved seed it too
            parts.append(self._densify(grey, prepared, parts, cover, seeding))
            backlog = parts[-1][1].shape[1] >= cfg.densify.max_points
        xyz, vis, err, pix = _union(parts)
        n_old = int(keep_old.sum())
        old_ids = st.ids[keep_old]
        misses = np.zeros((len(xyz), C), np.uint8)
        misses[:n_old] = st.misses[keep_old]
        proj = _extend_projection(rig, live_proj, xyz) if len(xyz) else None
        if self._expand_views and len(xyz):
            xyz, vis, err, pix = self._expand(grey, xyz, vis, err, pix)
            proj = None
        if cfg.views.enabled and len(xyz):
            xyz, vis, err, pix, keep, misses, proj = self._discover(
                t, prepared, xyz, vis, err, pix, old_ids, misses, proj
            )
            xyz, vis, err, pix = xyz[keep], vis[keep], err[keep], pix[:, keep]
            misses, proj = misses[keep], _take_projection(proj, keep)
            if cfg.views.drop_grazing and len(xyz):
                drop = grazing_views(rig, xyz, (vis > cfg.visibility_threshold).T, cfg.views)
                vis = np.where(drop.T, np.float32(0), vis)
                pix = np.where(drop[..., None], np.nan, pix)
                logger.debug("frame %d: %d grazing views dropped", t, int(drop.sum()))
        found = np.count_nonzero(vis > cfg.visibility_threshold, axis=1)  # (N,)
        enough = found >= cfg.min_views
        unconfirmed = np.zeros(n_old, bool)
        if cfg.views.enabled and cfg.views.unconfirmed_fails > 0 and n_old:
            fails = np.count_nonzero(misses[:n_old] >= cfg.views.unconfirmed_frames, axis=1)
            unconfirmed = (found[:n_old] == 2) & (fails >= cfg.views.unconfirmed_fails)
        if len(xyz):
            vis = np.where(self._occluded(xyz, vis, proj, misses), np.float32(0), vis)
        views = np.count_nonzero(vis > cfg.visibility_threshold, axis=1)
        seen = views >= cfg.min_views
        lone = np.zeros(len(xyz), np.int64)  # frames on fewer than two views, after this one
        lone[:n_old] = np.where(seen[:n_old], 0, st.lone[keep_old] + 1)
        if cfg.survive.frames > 0:  # tracked points left with one view go on for a while
            seen[:n_old] |= (views[:n_old] >= 1) & (lone[:n_old] <= cfg.survive.frames)
        seen[:n_old] &= ~unconfirmed
        self._count_stops(
            obs, triangulated, keep_old, enough[:n_old], seen[:n_old], st.lone > 0, unconfirmed
        )
        n_new = int(seen[n_old:].sum())
        ids = np.concatenate([old_ids[seen[:n_old]], st.next_id + np.arange(n_new)])
        xyz, vis, err, pix = xyz[seen], vis[seen], err[seen], pix[:, seen]
        pix = np.where((vis.T > cfg.visibility_threshold)[..., None], pix, np.nan)
        lone = lone[seen]
        self.state = TrackState(
            t,
            ids,
            xyz,
            vis,
            pix.astype(np.float32),
            st.next_id + n_new,
            lone,
            misses[seen],
            densify_backlog=backlog,
            lost=lost.kept(ids[lone > 0]),
        )
        self._prev_grey = grey
        self._projected = None
        if proj is not None and cfg.lk_start == "projection":
            self._projected = (self.state, proj.pixels[:, seen])
        logger.info(
            "frame %d: %d tracked of %d (%.0f %% of their views still, %d lost views back), "
            "%d new, %d live",
            t,
            int(seen[:n_old].sum()),
            len(st),
            100.0 * still / max(still + flowed, 1),
            regained,
            n_new,
            len(ids),
        )
        return FrameRecord(
            frame=t,
            ids=ids,
            xyz=xyz.astype(np.float32),
            visibility=quantize_visibility(vis),
            error=err.astype(np.float32),
            color=sample_colors(images, pix, vis),
            num_new=n_new,
        )

    def _carry(
        self,
        st: TrackState,
        grey: list[np.ndarray],
        obs: np.ndarray,
        tri: Triangulation,
        triangulated: np.ndarray,
    ) -> tuple[Triangulation, np.ndarray, np.ndarray, LostViews]:
        """One-view survival (:mod:`~.survive`) of live points the re-triangulation lost.

        Points carried on one view first search the camera that lost them
        (:meth:`_reacquire`); those found there are triangulated again from their views.
        Returns the triangulation with the carried and the re-acquired points' rows replaced
        (a carried point: one inlier view, visibility 1 there, the prediction's distance to it
        as the error), which points are carried, which re-acquired a view (``obs`` gets it),
        and the lost views of the carried points (:class:`~.reacquire.LostViews`).
        """
        from .triangulate import Triangulation

        cfg = self.config
        carried = np.zeros(len(st), bool)
        back = np.zeros(len(st), bool)
        cand = np.flatnonzero(
            ~triangulated & (st.lone < cfg.survive.frames) & finite_rows(obs).any(axis=0)
        )
        if cand.size == 0:  # (too few neighbours: predict_rigid predicts nothing)
            return tri, carried, back, LostViews.empty()
        pred, _ = predict_rigid(
            st.xyz[triangulated], tri.points[triangulated], st.xyz[cand], cfg.survive
        )
        max_px = cfg.survive.max_px or 2 * cfg.ransac_threshold_px
        X, cam, dist, ok = carry_one_view(self.rig, pred, obs[:, cand], max_px)
        idx, cam, dist, X = cand[ok], cam[ok], dist[ok], X[ok]
        if idx.size == 0:
            return tri, carried, back, LostViews.empty()
        points, inliers, errors = tri.points.copy(), tri.inliers.copy(), tri.errors.copy()
        visibility, mean_error = tri.visibility.copy(), tri.mean_error.copy()
        lost = LostViews.empty()
        if cfg.survive.reacquire:
            lost, found, sub = self._reacquire(st, grey, obs, idx, X, max_px)
            rows = idx[found]
            points[rows] = sub.points
            inliers[:, rows] = sub.inliers
            errors[:, rows] = sub.errors
            visibility[rows] = sub.visibility
            mean_error[rows] = sub.mean_error
            back[rows] = True
            keep = np.ones(idx.size, bool)
            keep[found] = False
            idx, cam, dist, X = idx[keep], cam[keep], dist[keep], X[keep]
        points[idx] = X
        inliers[:, idx] = False
        inliers[cam, idx] = True
        errors[:, idx] = np.nan
        errors[cam, idx] = dist
        visibility[idx] = 0
        visibility[idx, cam] = 1
        mean_error[idx] = dist
        carried[idx] = True
        logger.debug(
            "one-view survival: %d of %d points carried, %d got a lost view back",
            idx.size,
            cand.size,
            int(back.sum()),
        )
        return Triangulation(points, inliers, errors, visibility, mean_error), carried, back, lost

    def _reacquire(
        self,
        st: TrackState,
        grey: list[np.ndarray],
        obs: np.ndarray,
        idx: np.ndarray,
        X: np.ndarray,
        radius: float,
    ) -> tuple[LostViews, np.ndarray, Triangulation]:
        """Search the cameras that lost carried points for them (:mod:`~.reacquire`).

        ``idx`` (n,) are the carried points (rows of ``st``) and ``X`` (n, 3) their carried
        positions. A point carried since an earlier frame searches the camera its lost view
        was kept for; one that lost its views now keeps the view of the camera that saw it
        best at the last frame, cut from that camera's previous image. Returns the lost
        views of the n points (those with one), which of the n (indices) got a view back,
        found and kept by RANSAC with at least two views, and their triangulation from their
        views with the found one added (``obs`` gets their inlier views).
        """
        from .triangulate import Triangulation, triangulate_ransac

        cfg = self.config
        spacing = cfg.views.spacing_px
        entry = st.lost.lookup(st.ids[idx])  # (n,) -1: lost now
        # views lost now: seen at the last frame, not followed by the flow
        fresh = np.flatnonzero(entry < 0)
        parts = [st.lost.take(entry[entry >= 0])]
        order = [np.flatnonzero(entry >= 0)]
        if fresh.size:
            rows = idx[fresh]
            was = np.where(
                (st.visibility[rows] > cfg.visibility_threshold) & ~finite_rows(obs[:, rows]).T,
                st.visibility[rows],
                -1.0,
            )  # (f, C)
            lost_cam = np.argmax(was, axis=1)
            has = was[np.arange(rows.size), lost_cam] > 0
            # camera by camera: projecting into every camera is C times the work
            for c in np.unique(lost_cam[has]):
                sel = np.flatnonzero(has & (lost_cam == c))
                last = st.pixels[c, rows[sel]].astype(np.float64)
                patch, frac, ok = cut_patches(self._prev_grey[c], last, spacing)
                sel, patch, frac, last = sel[ok], patch[ok], frac[ok], last[ok]
                centre = last - frac
                parts.append(
                    LostViews(
                        st.ids[rows[sel]],
                        np.full(sel.size, c, np.int64),
                        (centre - self.rig[int(c)].project(st.xyz[rows[sel]])[0]).astype(
                            np.float32
                        ),
                        frac,
                        patch,
                    )
                )
                order.append(fresh[sel])
        lost = LostViews.concat(parts)
        where = np.concatenate(order)  # (L,) the rows of idx the entries belong to
        found_px = np.full((len(lost), 2), np.nan)
        if len(lost):
            for c in np.unique(lost.camera):
                sel = np.flatnonzero(lost.camera == c)
                centre = self.rig[int(c)].project(X[where[sel]])[0] + lost.offset[sel]
                px, _ = search_patches(
                    grey[c],
                    lost.patch[sel],
                    centre,
                    spacing,
                    radius,
                    cfg.survive.reacquire_ncc,
                    cfg.survive.reacquire_margin,
                )
                found_px[sel] = px + lost.frac[sel]
        hit = np.flatnonzero(np.isfinite(found_px).all(axis=1))
        rows = where[hit]  # (h,) rows of idx with a found view (one entry per point)
        sub_obs = obs[:, idx[rows]].copy()
        sub_obs[lost.camera[hit], np.arange(hit.size)] = found_px[hit]
        sub = triangulate_ransac(self.rig, sub_obs, self.tri_config)
        good = sub.inliers[lost.camera[hit], np.arange(hit.size)] & self._alive(sub)
        sub = Triangulation(
            sub.points[good],
            sub.inliers[:, good],
            sub.errors[:, good],
            sub.visibility[good],
            sub.mean_error[good],
        )
        rows = rows[good]
        obs[:, idx[rows]] = np.where(sub.inliers[..., None], sub_obs[:, good], np.nan)
        return lost, rows, sub

    def _expand(
        self,
        grey: list[np.ndarray],
        xyz: np.ndarray,
        vis: np.ndarray,
        err: np.ndarray,
        pix: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """View expansion (:func:`~.flow.expand_views`); re-triangulation of the points it grew."""
        cfg = self.config
        proj = self.rig.project(xyz)
        cand = proj.in_image & ~self._occluded(xyz, vis, proj).T
        grown = expand_views(
            self.rig,
            grey,
            xyz,
            pix,
            cand,
            max_angle_deg=cfg.expand_max_angle_deg,
            max_px=cfg.expand_px,
            window=cfg.lk_window,
            fb_max_px=cfg.fb_max_px,
            projection=proj,
        )
        return self._retriangulate(xyz, vis, err, pix, grown)

    def _discover(
        self,
        t: int,
        images: Sequence[np.ndarray],
        xyz: np.ndarray,
        vis: np.ndarray,
        err: np.ndarray,
        pix: np.ndarray,
        old_ids: np.ndarray,
        misses: np.ndarray,
        proj: Projection | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, Projection]:
        """View discovery (:func:`~.views.discover_views`) and re-triangulation.

        The first ``len(old_ids)`` points are tracked ones: a camera where the search failed
        is searched again after a back-off (:func:`~.views.retry_due`, from ``misses`` (N, C)
        uint8), staggered by id and camera; new points, points on one view and cameras that
        newly see a point are searched at once. ``proj`` is ``rig.project(xyz)`` when the
        caller has it. Returns the points, which to keep (new two-view points that a searched
        third camera did not confirm are not), the updated failure counts and the points'
        projection.
        """
        cfg = self.config
        C, N, n_old = len(self.rig), len(xyz), len(old_ids)
        if proj is None:
            proj = self.rig.project(xyz)
        cand = proj.in_image & ~self._occluded(xyz, vis, proj, misses).T
        due = np.ones((C, N), bool)
        if n_old:
            every, max_every = retry_periods(cfg.views, C)
            due[:, :n_old] = retry_due(misses[:n_old], old_ids, t, every, max_every)
            one_view = finite_rows(pix[:, :n_old]).sum(axis=0) < 2
            due[:, :n_old] |= one_view[None, :]
        # new two-view points that no camera could be searched for are searched again
        confirm = np.arange(N) >= n_old if cfg.views.confirm_new else None
        grown, searched = discover_views(
            self.rig,
            images,
            xyz,
            pix,
            cand & due,
            cfg.views,
            sigma_px=cfg.sigma_px,
            confirm=confirm,
        )
        before = xyz
        xyz, vis, err, pix = self._retriangulate(xyz, vis, err, pix, grown)
        misses = record_misses(misses, cand, due, finite_rows(pix))
        moved = np.flatnonzero(np.any(xyz != before, axis=1))
        if moved.size:
            proj = _update_projection(self.rig, proj, xyz, moved)
        keep = np.ones(N, bool)
        if cfg.views.confirm_new:
            views = np.count_nonzero(vis > cfg.visibility_threshold, axis=1)  # (N,)
            unconfirmed = (views < 3) & searched.any(axis=0)
            keep[n_old:] = ~unconfirmed[n_old:]
        return xyz, vis, err, pix, keep, misses, proj

    def _retriangulate(
        self,
        xyz: np.ndarray,
        vis: np.ndarray,
        err: np.ndarray,
        pix: np.ndarray,
        grown: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """RANSAC re-triangulation of the points that ``grown`` (C, N, 2) gives more views;
        a view stays only where the RANSAC keeps it as an inlier."""
        from .triangulate import triangulate_ransac

        views_before = finite_rows(pix)  # (C, N)
        more = np.flatnonzero(finite_rows(grown).sum(axis=0) > views_before.sum(axis=0))
        if more.size == 0:
            return xyz, vis, err, pix
        tri = triangulate_ransac(self.rig, grown[:, more], self.tri_config)
        ok = self._alive(tri)
        idx = more[ok]
        xyz, vis, err, pix = xyz.copy(), vis.copy(), err.copy(), pix.copy()
        xyz[idx] = tri.points[ok]
        vis[idx] = tri.visibility[ok]
        err[idx] = tri.mean_error[ok]
        pix[:, idx] = np.where(tri.inliers[:, ok, None], grown[:, idx], np.nan)
        if logger.isEnabledFor(logging.DEBUG):  # counting the views costs a pass over pix
            logger.debug(
                "view expansion: %d points gained views (%.2f views per point, was %.2f)",
                idx.size,
                finite_rows(pix).sum() / max(len(xyz), 1),
                views_before.sum() / max(len(xyz), 1),
            )
        return xyz, vis, err, pix

    def _densify(
        self,
        grey: list[np.ndarray],
        prepared: Sequence[np.ndarray],
        parts: list[tuple[Triangulation, np.ndarray, np.ndarray]],
        cover: np.ndarray,
        seeding: np.ndarray | None,
    ) -> tuple[Triangulation, np.ndarray, np.ndarray]:
        """Patch densification (:func:`~.densify.densify`) into pixels that no point of
        ``parts`` takes, grown from the frame's new matches (``parts[1:]``) and the tracked
        points (``parts[0]``) where ``seeding`` (N,) is set (None: every one, with ``seeds =
        "all"`` on a matched frame); none of the tracked ones with ``seeds = "new"``.
        ``cover`` (C, n, 2) are more pixels that count as taken (:meth:`_cover_pixels`)."""
        from .densify import densify
        from .triangulate import triangulate_ransac

        cfg = self.config
        xyz, _, _, pix = _union(parts)
        taken = np.concatenate([pix, cover], axis=1) if cover.shape[1] else pix
        if cfg.densify.seeds == "new" or seeding is not None:
            tri, obs, keep = parts[0]
            tracked = [] if cfg.densify.seeds == "new" else [(tri, obs, keep & seeding)]
            xyz, _, _, pix = _union(tracked + parts[1:])
        dense = densify(self.rig, prepared, xyz, pix, taken, cfg.densify)
        for c in range(len(self.rig)):  # keep the views that Lucas-Kanade can follow: a flow
            # from the image to itself fails where its minimum-eigenvalue test will
            dense[c] = track_flow(
                grey[c],
                grey[c],
                dense[c],
                window=cfg.lk_window,
                levels=cfg.lk_levels,
                fb_max_px=cfg.fb_max_px,
            )
        tri = triangulate_ransac(self.rig, dense, self.tri_config)
        keep = self._alive(tri) & (np.count_nonzero(tri.inliers, axis=0) >= cfg.min_views_new)
        logger.debug("densify: %d of %d new points kept", int(keep.sum()), dense.shape[1])
        return tri, dense, keep

    def _count_stops(
        self,
        obs: np.ndarray,
        triangulated: np.ndarray,
        kept: np.ndarray,
        enough: np.ndarray,
        seen: np.ndarray,
        was_lone: np.ndarray,
        unconfirmed: np.ndarray,
    ) -> dict[str, np.ndarray]:
        """Count why the live trajectories that ended at this frame ended.

        ``obs`` (C, N, 2): their flow results; ``triangulated`` (N,): alive after
        re-triangulation; ``kept`` (N,): that or carried on one view (:meth:`_carry`);
        ``enough`` and ``seen`` (kept points): enough views before and after the occlusion
        test, and still live; ``was_lone`` (N,): on fewer than two views before this frame;
        ``unconfirmed`` (kept points): ended on two views that the search did not confirm.
        Returns, per reason of :data:`STOP_REASONS`, which of the N ended for it (added to
        ``self.stops``).
        """
        ended = ~kept
        ended[kept] = ~seen
        reasons = {"unconfirmed": np.zeros(len(kept), bool)}
        reasons["unconfirmed"][kept] = unconfirmed
        ended &= ~reasons["unconfirmed"]
        reasons["one-view"] = ended & was_lone
        ended &= ~was_lone
        flows = np.count_nonzero(finite_rows(obs), axis=0)  # (N,)
        reasons["flow"] = ended & ~kept & (flows < self.config.min_views)
        reasons["triangulation"] = ended & ~kept & ~reasons["flow"]
        after = np.zeros(len(kept), bool)
        after[kept] = enough
        reasons["occlusion"] = ended & kept & after
        reasons["visibility"] = ended & kept & ~after
        for name, mask in reasons.items():
            self.stops[name] += int(mask.sum())
        return reasons

    def _cover_pixels(
        self, xyz: np.ndarray, vis: np.ndarray, pix: np.ndarray, misses: np.ndarray | None = None
    ) -> tuple[Projection, np.ndarray]:
        """Where the live points cover the images (``cover_visible``).

        Parameters
        ----------
        xyz : (N, 3) float ndarray
        vis : (N, C) float ndarray
        pix : (C, N, 2) float ndarray
            Their observations (NaN where absent).
        misses : (N, C) uint8 ndarray, optional
            View discovery's failure counts (refuted points hide nothing).

        Returns
        -------
        projection : Projection
            ``rig.project(xyz)``.
        cover : (C, N, 2) float64 ndarray
            The observations, and the projections in the cameras where a point is in the
            image, not occluded and on the side its observing cameras see (within 90 degrees
            of their mean direction: the far side of a limb or a ball is within the occlusion
            test's tolerance of the near side and must not cover it), but not observed (NaN
            elsewhere).
        """
        from .views import _directions, _facing

        proj = self.rig.project(xyz)
        seen = finite_rows(pix)
        to_cams = _directions(self.rig, xyz, np.float32)  # (C, N, 3)
        front = np.einsum("cnk,nk->cn", to_cams, _facing(seen, to_cams)) > 0
        visible = proj.in_image & front & ~self._occluded(xyz, vis, proj, misses).T  # (C, N)
        cover = np.where(seen[..., None], pix, np.where(visible[..., None], proj.pixels, np.nan))
        return proj, cover

    def _occluded(
        self,
        xyz: np.ndarray,
        vis: np.ndarray,
        projection: Projection | None = None,
        misses: np.ndarray | None = None,
    ) -> np.ndarray:
        """(N, C) views of the frame's points hidden behind its own surface (all False when
        the test is off): :func:`~.occlusion.occlusion_test`. With view discovery's failure
        counts ``misses`` (N, C), the points they refute (:func:`~.views.refuted`) hide
        nothing."""
        from .occlusion import occlusion_test

        cfg = self.config
        if cfg.occlusion_depth_m <= 0 or len(xyz) == 0:
            return np.zeros((len(xyz), len(self.rig)), bool)
        observed = (vis > cfg.visibility_threshold).T  # (C, N)
        tol = occlusion_tolerance(cfg, self.rig, xyz, observed)
        occluders = None
        if misses is not None and cfg.views.enabled:
            occluders = ~refuted(misses, observed.sum(axis=0), cfg.views)
            logger.debug("occlusion test: %d refuted points hide nothing", (~occluders).sum())
        return occlusion_test(
            self.rig,
            xyz,
            tol,
            cell_px=cfg.occlusion_cell_px,
            projection=projection,
            occluders=occluders,
        )

    def _alive(self, tri: Triangulation) -> np.ndarray:
        cfg = self.config
        with np.errstate(invalid="ignore"):
            return (
                tri.valid
                & (tri.mean_error <= cfg.max_mean_error_px)
                & (np.count_nonzero(tri.inliers, axis=0) >= cfg.min_views)
            )

    def _triangulate_tracks(self, tracks: MultiViewTracks) -> tuple[Triangulation, np.ndarray]:
        """RANSAC-triangulate matched tracks; ambiguous ones keep their closest keypoints."""
        from .triangulate import Triangulation, triangulate_ransac

        tri = triangulate_ransac(self.rig, tracks.observations, self.tri_config)
        obs = tracks.observations
        amb = np.flatnonzero(tracks.ambiguous)
        if amb.size:
            obs = resolve_ambiguous(self.rig, tracks, tri.points)
            sub = triangulate_ransac(self.rig, obs[:, amb], self.tri_config)
            fields = {}
            for name in ("points", "inliers", "errors", "visibility", "mean_error"):
                whole = getattr(tri, name).copy()
                part = getattr(sub, name)
                if whole.ndim == 2 and name in ("inliers", "errors"):
                    whole[:, amb] = part
                else:
                    whole[amb] = part
                fields[name] = whole
            tri = Triangulation(**fields)
        return tri, obs


def _image_motion(obs: np.ndarray, previous: np.ndarray) -> np.ndarray:
    """How far each tracked point's image moved since the previous frame.

    The median over the cameras that follow the point: on a still floor the largest
    displacement over 12 cameras exceeds 1 px for half of the points (tracking jitter), the
    median for 4 % (paper69, frame 1).

    Parameters
    ----------
    obs : (C, N, 2) float ndarray
        This frame's flow results (NaN where a camera does not follow the point).
    previous : (C, N, 2) float ndarray
        The previous frame's pixels.

    Returns
    -------
    (N,) float64 ndarray
        The median displacement in pixels over the cameras with both; 0 where there is none.
    """
    step = pixel_distance(obs, previous)  # (C, N)
    count = np.count_nonzero(~np.isnan(step), axis=0)  # (N,) values, infinite ones too
    has = np.flatnonzero(np.isfinite(step).any(axis=0))
    motion = np.zeros(step.shape[1])
    if has.size:
        # nanmedian's values at a fraction of its cost: sorted (NaN last), the mean of the
        # middle two finite values (the middle one twice for an odd count)
        srt = np.sort(step[:, has], axis=0)
        k = count[has]
        lo = srt[(k - 1) // 2, np.arange(has.size)]
        hi = srt[k // 2, np.arange(has.size)]
        motion[has] = (lo + hi) / 2.0
    return motion


def _union(
    parts: list[tuple[Triangulation, np.ndarray, np.ndarray]],
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The kept points of several triangulations, in order.

    Parameters
    ----------
    parts : list of (Triangulation, (C, n, 2) observations, (n,) bool keep)

    Returns
    -------
    xyz : (N, 3) float ndarray
    visibility : (N, C) float ndarray
    error : (N,) float ndarray
        Mean inlier reprojection error.
    pixels : (C, N, 2) float ndarray
        The inlier observations (NaN elsewhere).
    """
    xyz = np.concatenate([tri.points[keep] for tri, _, keep in parts])
    vis = np.concatenate([tri.visibility[keep] for tri, _, keep in parts])
    err = np.concatenate([tri.mean_error[keep] for tri, _, keep in parts])
    pix = np.concatenate(
        [np.where(tri.inliers[:, keep, None], obs[:, keep], np.nan) for tri, obs, keep in parts],
        axis=1,
    )
    return xyz, vis, err, pix


def _extend_projection(rig: CameraRig, head: Projection | None, xyz: np.ndarray) -> Projection:
    """``rig.project(xyz)`` (N points), reusing ``head``, the projection of its first rows."""
    n = 0 if head is None else head.depth.shape[1]
    if n == 0:
        return rig.project(xyz)
    tail = rig.project(xyz[n:])
    return Projection(
        np.concatenate([head.pixels, tail.pixels], axis=1),
        np.concatenate([head.depth, tail.depth], axis=1),
        np.concatenate([head.in_image, tail.in_image], axis=1),
    )


def _update_projection(
    rig: CameraRig, proj: Projection, xyz: np.ndarray, rows: np.ndarray
) -> Projection:
    """``proj`` with the points ``rows`` (indices into ``xyz`` (N, 3)) projected anew."""
    part = rig.project(xyz[rows])
    pixels, depth, in_image = proj.pixels.copy(), proj.depth.copy(), proj.in_image.copy()
    pixels[:, rows], depth[:, rows], in_image[:, rows] = part.pixels, part.depth, part.in_image
    return Projection(pixels, depth, in_image)


def _take_projection(proj: Projection, keep: np.ndarray) -> Projection:
    """The projection of the points selected by ``keep`` ((N,) bool)."""
    return Projection(proj.pixels[:, keep], proj.depth[:, keep], proj.in_image[:, keep])


def _empty_live(C: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    return (
        np.zeros(0, np.int64),
        np.zeros((0, 3)),
        np.zeros((0, C), np.float32),
        np.zeros((C, 0, 2), np.float32),
    )
