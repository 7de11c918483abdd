"""The reconstruction stage's parameters: :class:`ReconstructConfig` (table ``[reconstruct]``)."""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Literal

import numpy as np

from ..camera import CameraRig
from ..errors import ValidationError
from ..geometry import axis_angles
from ..scale import SceneLength
from .densify import DensifyConfig
from .matching import MatchingConfig
from .stitch import StitchConfig
from .survive import SurviveConfig
from .views import ViewsConfig

if TYPE_CHECKING:  # pragma: no cover
    from .triangulate import TriangulationConfig

__all__ = ["ReconstructConfig", "RigChoice", "rig_choices"]

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class ReconstructConfig:
    """Every parameter of the reconstruction stage (TOML table ``[reconstruct]``).

    Attributes
    ----------
    sigma_px : float
        sigma, the reprojection-error tolerance of the visibility
        ``V(X, c) = exp(-(e_c / sigma)^2)`` (paper Section 5, step 2).
    visibility_threshold : float
        eps_s: a point is tracked in camera c at the next frame only where ``V(X, c) > eps_s``.
        The default 0.05 keeps views with a reprojection error below ``sigma * sqrt(-ln 0.05)``,
        about 1.7 sigma.
    ransac_threshold_px : float
        Inlier threshold of the RANSAC triangulation.
    ransac_iterations : int
        Hypotheses per point of the RANSAC triangulation.
    max_mean_error_px : float
        A trajectory stops when its mean inlier reprojection error exceeds this (paper: 2 px).
    min_views : int
        A trajectory stops when fewer cameras see it (``V > eps_s``) (paper: 2).
    min_views_new : int
        Inlier views a newly matched point needs to start a trajectory; 3 rejects most false
        two-view matches (two views always agree with a wrong match along the epipolar line).
    lk_window : int or None
        Lucas-Kanade window size in pixels; None (the default) chooses it from the rig
        (:func:`lk_window_for`): the smallest odd size that covers :data:`LK_WINDOW_M` of the
        subject at the cameras' working distance, within 7-21 px. A window wider than the limb
        it tracks lags behind it, held back by the static background in it: on the demo's
        640x512 images (a limb 11-16 px across), 21 px let points slide 10 mm along their limb
        over 20 frames (``docs/reconstruction.md``, "The Lucas-Kanade window and the subject's
        size").
    lk_levels : int
        Lucas-Kanade pyramid levels above the full resolution.
    lk_start : {"projection", "observation"}
        Where the flow starts in each camera: the projection of ``X_{t-1}`` (the paper) or the
        previous tracked 2D position.
    fb_max_px : float
        Forward-backward flow check: a view is dropped when tracking forward then backward ends
        farther than this from the start.
    fb_skip_views : int
        Points tracked in at least this many cameras skip the backward flow and its check
        (half the flow's cost): their re-triangulation's RANSAC rejects a view that the flow
        lost, by its disagreement with the others. Points in fewer cameras, where a lost
        view can agree with the rest, keep the check. 0: every point is checked. Applied only
        where ``ransac_threshold_px`` is at most twice ``fb_max_px`` (a looser RANSAC keeps a
        drifted view; :func:`~pointtraj.reconstruct.track.effective_fb_skip`, logged).
    still_px : float
        Views whose window moves by at most this between frames take their flow from one
        Lucas-Kanade step at full resolution, read from box sums of the whole image
        (:func:`~pointtraj.reconstruct.flow.still_flow`), instead of the pyramidal flow and its
        check; the rest, and any whose residual after the step is above ``still_noise`` times
        the image's noise, get the pyramidal flow. On a capture with a static background most
        views are such (83 % on paper69, which saves about 10 % of a tracked frame's CPU at
        the same accuracy). Only cameras that track at least one view per 256 pixels take the
        step, where its whole-image sums cost less than the flow they save
        (:data:`~pointtraj.reconstruct.flow.STILL_VIEWS_PER_PIXEL`); ``docs/reconstruction.md``,
        "Still views". 0: every view gets the pyramidal flow.
    still_noise : float
        See ``still_px``: the largest residual per pixel, in units of the image's noise (the
        mean squared frame difference of its quietest quarter of windows). Textured windows
        keep more of the sensor noise through compression than the quietest quarter: on
        paper69 the static views that the step takes to within the flow's own agreement
        (0.005 px median, 0.035 px p99) have residuals up to 6 times that noise; from 8 times
        the agreement degrades (``docs/reconstruction.md``, "Still views").
    cover_px : float
        A new point is already covered when, in at least ``cover_views`` of its cameras, a live
        trajectory's observation lies within this many pixels of its own.
    cover_views : int
        See ``cover_px``.
    cover_visible : {"auto", "on", "off"}
        What covers the surface. "auto" (the default) turns it on where view discovery does
        not search every camera of every point every frame (rigs of 32 cameras and more,
        ``[reconstruct.views] retry_every``), and off elsewhere: on the demo's 8 cameras, where
        discovery searches every camera each frame, it only removed legitimate new points
        (graph cut 86.0 % against 88.8 %, 3D error p90 30.3 against 27.3 mm). When on, a live
        point covers the pixels around its
        projection in every camera where it is in the image, not occluded and on the side its
        observing cameras see (within 90 degrees of their mean direction), observed or not;
        otherwise only around its observations. It applies to matched points (``cover_px``)
        and to densification's candidate grid (within ``0.75 * densify.step_px`` of a
        covering pixel in the reference camera, before the sweep). A live point that view
        discovery has not found in a camera yet (view recall is about 0.5 on paper69) then
        no longer leaves a hole there that new points fill every frame: on paper69 the live
        points grew by about 30,000 a frame (50k, 80k, 108k in frames 0-2; 50k, 75k, 99k with
        it), and those on the actors were mostly duplicates of tracked surface
        (``docs/reconstruction.md``, "Bounded density and the back-off").
    match_skip_px : float or None
        Dense matching leaves out the features within this many pixels of a live
        trajectory's observation in their camera: such a feature is the tracked point
        detected again, and a point matched there is dropped as covered (``cover_px``).
        Features are detected on the whole image as before; only those are not matched.
        0 matches every feature. None (the default, the key left out): chosen from the rig
        by :meth:`for_rig`: :data:`MATCH_SKIP_COVER` times ``cover_px`` where
        ``cover_visible`` is on (rigs of 32 cameras and more), 0 elsewhere
        (``docs/reconstruction.md``, "Matching only where tracking has no point").
    occlusion_depth_m : float
        Depth tolerance of the occlusion test against the frame's own points (metres), and its
        upper bound when it comes from the points' uncertainty; 0 turns the test off.
    occlusion_sigmas : float
        The occlusion test's tolerance per point: each point is the depth interval of this many
        standard deviations of its depth on each side (from its triangulation angle,
        :func:`~.views.depth_uncertainty`), within ``[occlusion_min_m, occlusion_depth_m]``
        in all; a point is hidden only by a point whose interval lies wholly in front of its
        own. 0 (the default): the fixed ``occlusion_depth_m`` for every point. At 3, view
        precision rises from 0.964 to 0.977 on paper69 (frames 0-2) and from 0.794 to 0.807 on
        the demo (frames 0-29), and view recall falls from 0.491 to 0.439 and from 0.740 to
        0.732: precise points are then hidden by surfaces 1-2 cm in front, and some of those
        views were visible (``docs/reconstruction.md``).
    occlusion_min_m : float
        Lower bound of the per-point tolerance (a surface's thickness that no point resolves).
    occlusion_cell_px : float
        Z-buffer cell size of the occlusion test.
    max_angle_deg : float
        Camera pairs whose optical axes differ by more are not matched (connectivity graph).
    capture_volume : ((3,), (3,)) tuple of float, optional
        The capture volume ``[[xmin, ymin, zmin], [xmax, ymax, zmax]]`` in metres, where the
        camera pairs' shared view is measured. Left out (the default): the cameras' common
        view, from their frusta (:func:`~.connectivity.common_view`: the region that a third
        of the cameras, at least 2, see between 0.2 and 1.5 times their working distance);
        ``pointtraj rig info`` prints it.
    min_pair_overlap : float
        A camera pair within ``max_angle_deg`` is matched only when its shared view of the
        capture volume is at least this fraction of the rig's reference shared view (the
        median over cameras of each camera's best pair), so the cut-off follows the rig: it
        keeps the demo's, paper69's and caliscope's pairs as the earlier fixed 0.05 did, and 18
        of the 18 pairs within 90 degrees of the narrow-field ``narrow7`` preset (the fixed
        cut-off in the earlier volume: 0); ``docs/reconstruction.md``, "Rig-derived defaults".
    max_pairs_per_camera : int
        Keep only this many smallest-angle partners per camera (0: all within
        ``max_angle_deg``); bounds the matching cost of large rigs. Rigs of up to 13 cameras
        keep every pair; on the paper's 69 cameras 12 partners give the same points and
        errors as all 1266 pairs at 2.5 times less CPU (``benchmarks/bench_matching.py``).
    match_every : int or None
        Run dense matching (new trajectories) over the whole images every this many frames
        (1: every frame, the paper). None (the default, the key left out): chosen from the
        rig by :meth:`for_rig`, :data:`MATCH_EVERY_COVER` (2) where ``cover_visible`` is on
        (rigs of 32 cameras and more, whose live trajectories cover every camera where they
        are visible) and 1 elsewhere. In between, densification (``densify``) grows from the
        new matches and the fast-moving points only (``densify.between_motion_px``;
        ``docs/reconstruction.md``, "Matching every other frame").
    match_moving : bool
        On the frames between (``match_every`` above 1), match features only in the image
        regions where tracked points move (:func:`~.matching.moving_boxes`): the surfaces that
        move, and those they uncover, get new points every frame; still ones every
        ``match_every`` frames. False: no matching between.
    expand_views : bool
        View expansion by flow (off by default): after each frame, look for every point in the
        cameras that should see it by Lucas-Kanade flow from its nearest observing camera,
        started at the point's projection (:func:`~.flow.expand_views`); accepted views join a
        RANSAC re-triangulation. It only reaches cameras within ``expand_max_angle_deg``; view
        discovery (``views``) searches every baseline and replaces it: on paper69 (frames 0-2)
        discovery alone reaches a view recall of 0.49 at 1.1 times the CPU time of neither, and
        both together 0.53 at 1.6 times (``docs/reconstruction.md``).
    expand_max_angle_deg : float
        A camera is searched from an observing camera whose optical axis is at most this far
        from its own (the flow's patch must look alike in both).
    expand_px : float
        The flow's result must lie within this many pixels of the point's projection.
    seed : int
        Seed of the RANSAC sampling.
    chunk_frames : int
        Frames per temporal chunk (0: one chunk). A longer frame range is tracked in chunks of
        this many frames, each by its own tracker and as one task of the executor, so that
        tracking spreads over workers; trajectories are joined across the chunk boundaries
        (:mod:`pointtraj.reconstruct.chunks`). The chunks depend only on this, the overlap and
        the frame range, never on the executor: serial and cluster runs give the same output.
        A range of at most ``chunk_frames`` frames is one chunk, reconstructed as without
        chunking. The trajectories that the overlap does not join are carried on over the next
        chunk by their own tracker, in the same task, without new points. On the demo (frames
        0-29 in chunks of 10) view recall and precision stay within 0.02 of one chunk's, the
        median 3D errors within 0.3 mm, as many trajectories cross each boundary, and 35 %
        more CPU goes to the overlap (5 %: ``chunk_frames`` 100); ``docs/reconstruction.md``.
    chunk_overlap : int
        Frames that a chunk's tracker starts before its boundary, to warm up: the trajectories
        of both chunks over these frames are compared to join them, and the chunk's points there
        are then dropped (each frame's points come from one chunk). 0: no warm-up, and
        trajectories continue across a boundary only by stitching (``stitch``). Costs
        ``chunk_overlap / chunk_frames`` more tracking.
    chunk_tail_discovery : bool
        Whether view discovery (``views``) runs in a chunk's tail, the trajectories carried on
        over the next chunk. Off, a tail only tracks its points with their flow, the
        re-triangulation and the occlusion test (no search for more views, no grazing-view
        drop, no ``unconfirmed`` rule).
    chunk_join_m : float
        Two trajectories of consecutive chunks are the same point when they stay within this
        distance (metres) over every overlap frame where both exist, their projections agree
        within twice ``ransac_threshold_px`` in the cameras that see both at the boundary, and
        each is the other's nearest such candidate. 5 mm: on the demo the joined trajectories then
        step across the join as their ground-truth points move within 2.0 mm (median; 1.0-1.4
        for ordinary steps), against 5 mm at 1 cm, which joins twice as many, mostly
        neighbouring points.
    matching : MatchingConfig
        Feature detection and matching (table ``[reconstruct.matching]``). ``guided`` and
        ``gms_threshold``, when left out, are chosen from the rig (:meth:`for_rig`).
    densify : DensifyConfig
        Patch densification around the frame's points, for wide baselines where features and
        view expansion find little (table ``[reconstruct.densify]``; ``enabled``, when left
        out, is chosen from the rig: :meth:`for_rig`).
    views : ViewsConfig
        View discovery by a plane sweep, at any baseline: every point is searched in the
        cameras that should see it and that flow (``expand_views``) cannot reach (table
        ``[reconstruct.views]``; :mod:`pointtraj.reconstruct.views`).
    stitch : StitchConfig
        Joining a trajectory that ended to one born where it would have gone, across gaps of
        a frame or two (table ``[reconstruct.stitch]``; :mod:`pointtraj.reconstruct.stitch`).
    survive : SurviveConfig
        A point that drops to one view goes on for a few frames, carried by its neighbours'
        rigid motion where its remaining view agrees (table ``[reconstruct.survive]``;
        :mod:`pointtraj.reconstruct.survive`).
    cloud_visibility : {"full", "uint8", "sparse"}
        How ``clouds/<t>.ply`` hold the points' visibility
        (:data:`pointtraj.trajectories.CLOUD_VISIBILITY`): C float32 columns (the default, what
        Open3D users read), C uint8 columns (the store's quantised values: a third of the
        file on paper69), or only the observed views as a second PLY element (a fifth).
        ``load_cloud`` reads every form back to (N, C) float32. It does not change the
        trajectories; as one of the run's parameters, changing it restarts a run.
    """

    sigma_px: float = 1.0
    visibility_threshold: float = 0.05
    ransac_threshold_px: float = 2.0
    ransac_iterations: int = 50
    max_mean_error_px: float = 2.0
    min_views: int = 2
    min_views_new: int = 2
    lk_window: int | None = None
    lk_levels: int = 3
    lk_start: Literal["projection", "observation"] = "projection"
    fb_max_px: float = 1.0
    fb_skip_views: int = 4
    still_px: float = 0.1
    still_noise: float = 6.0
    cover_px: float = 3.0
    cover_views: int = 2
    cover_visible: str = "auto"
    match_skip_px: float | None = None
    occlusion_depth_m: float = SceneLength(0.05)
    occlusion_sigmas: float = 0.0
    occlusion_min_m: float = SceneLength(0.01)
    occlusion_cell_px: float = 8.0
    max_angle_deg: float = 90.0
    capture_volume: tuple[tuple[float, float, float], tuple[float, float, float]] | None = None
    min_pair_overlap: float = 0.2
    max_pairs_per_camera: int = 12
    match_every: int | None = None
    match_moving: bool = True
    expand_views: bool = False
    expand_max_angle_deg: float = 40.0
    expand_px: float = 2.0
    seed: int = 0
    chunk_frames: int = 100
    chunk_overlap: int = 5
    chunk_join_m: float = SceneLength(0.005)
    chunk_tail_discovery: bool = True
    matching: MatchingConfig = field(default_factory=MatchingConfig)
    densify: DensifyConfig = field(default_factory=DensifyConfig)
    views: ViewsConfig = field(default_factory=ViewsConfig)
    stitch: StitchConfig = field(default_factory=StitchConfig)
    survive: SurviveConfig = field(default_factory=SurviveConfig)
    cloud_visibility: Literal["full", "uint8", "sparse"] = "full"

    def __post_init__(self) -> None:
        checks = {
            "sigma_px": self.sigma_px > 0,
            "visibility_threshold": 0 <= self.visibility_threshold < 1,
            "ransac_threshold_px": self.ransac_threshold_px > 0,
            "ransac_iterations": self.ransac_iterations >= 1,
            "max_mean_error_px": self.max_mean_error_px > 0,
            "min_views": self.min_views >= 2,
            "min_views_new": self.min_views_new >= self.min_views,
            "lk_window": self.lk_window is None or self.lk_window >= 5,
            "lk_levels": self.lk_levels >= 0,
            "fb_max_px": self.fb_max_px > 0,
            "fb_skip_views": self.fb_skip_views == 0 or self.fb_skip_views >= 3,
            "still_px": 0 <= self.still_px <= 1,
            "still_noise": self.still_noise > 0,
            "cover_px": self.cover_px >= 0,
            "cover_views": self.cover_views >= 1,
            "cover_visible": self.cover_visible in ("auto", "on", "off"),
            "match_skip_px": self.match_skip_px is None or self.match_skip_px >= 0,
            "occlusion_depth_m": self.occlusion_depth_m >= 0,
            "occlusion_sigmas": self.occlusion_sigmas >= 0,
            "occlusion_min_m": 0 <= self.occlusion_min_m <= max(self.occlusion_depth_m, 0),
            "occlusion_cell_px": self.occlusion_cell_px > 0,
            "max_angle_deg": 0 < self.max_angle_deg <= 180,
            "capture_volume": self.capture_volume is None
            or (
                len(self.capture_volume) == 2
                and all(len(c) == 3 for c in self.capture_volume)
                and all(a <= b for a, b in zip(*self.capture_volume, strict=True))
            ),
            "min_pair_overlap": 0 <= self.min_pair_overlap <= 1,
            "max_pairs_per_camera": self.max_pairs_per_camera >= 0,
            "match_every": self.match_every is None or self.match_every >= 1,
            "expand_max_angle_deg": 0 < self.expand_max_angle_deg <= 180,
            "expand_px": self.expand_px > 0,
            "chunk_frames": self.chunk_frames >= 0,
            "chunk_overlap": self.chunk_overlap >= 0
            and (self.chunk_frames == 0 or self.chunk_overlap < self.chunk_frames),
            "chunk_join_m": self.chunk_join_m > 0,
        }
        bad = [k for k, ok in checks.items() if not ok]
        if bad:
            raise ValidationError(
                f"ReconstructConfig.{bad[0]} out of range: {getattr(self, bad[0])!r}"
            )
        if self.lk_start not in ("projection", "observation"):
            raise ValidationError(
                f"ReconstructConfig.lk_start must be 'projection' or 'observation', "
                f"got {self.lk_start!r}"
            )
        if self.cloud_visibility not in ("full", "uint8", "sparse"):
            raise ValidationError(
                "ReconstructConfig.cloud_visibility must be 'full', 'uint8' or 'sparse', "
                f"got {self.cloud_visibility!r}"
            )
        if not isinstance(self.matching, MatchingConfig):
            raise ValidationError("ReconstructConfig.matching must be a MatchingConfig")
        if not isinstance(self.densify, DensifyConfig):
            raise ValidationError("ReconstructConfig.densify must be a DensifyConfig")
        if not isinstance(self.views, ViewsConfig):
            raise ValidationError("ReconstructConfig.views must be a ViewsConfig")
        if not isinstance(self.stitch, StitchConfig):
            raise ValidationError("ReconstructConfig.stitch must be a StitchConfig")
        if not isinstance(self.survive, SurviveConfig):
            raise ValidationError("ReconstructConfig.survive must be a SurviveConfig")

    def triangulation(self) -> TriangulationConfig:
        """The matching :class:`TriangulationConfig`."""
        from .triangulate import TriangulationConfig

        return TriangulationConfig(
            threshold_px=self.ransac_threshold_px,
            sigma_px=self.sigma_px,
            iterations=self.ransac_iterations,
            min_views=self.min_views,
            seed=self.seed,
        )

    def for_rig(self, rig: CameraRig, *, log: bool = True) -> ReconstructConfig:
        """This config with the settings left out chosen from the rig, and the choice logged.

        Every length left at its default (:class:`~pointtraj.scale.SceneLength`: the depth
        ranges, occlusion tolerances, ``chunk_join_m``, the stitch and survive radii) follows
        the rig's scale (:func:`pointtraj.scale.scene_scale`: unchanged on human-sized rigs).
        ``matching.guided``, ``matching.gms_threshold``, ``densify.enabled``, ``densify.min_ncc``
        and ``densify.seeds`` left out (None)
        are chosen from the rig's baselines and resolution (:func:`rig_choices`),
        ``views.confirm_incidence_deg`` from its camera count, ``sigma_px`` and its cameras'
        nearest-partner angle (:func:`confirm_off_reasons`; off, with a warning, where it
        gives reasons),
        ``cover_visible = "auto"`` from its camera count, ``match_skip_px`` and
        ``match_every`` left out from ``cover_visible``, and ``lk_window`` left out from the
        subject's size in the images (:func:`lk_window_for`); set ones are kept. The choice is
        logged at INFO, with its reasons (:meth:`rig_notes` gives the same messages).

        Parameters
        ----------
        rig : CameraRig
        log : bool
            Log the choice (when something was left to choose).

        Returns
        -------
        ReconstructConfig
            With no setting left to the rig (unchanged when none was).
        """
        cfg, notes = self._choose_for_rig(rig, log=log)
        if log:
            for level, message in notes:
                logger.log(level, "%s", message)
        return cfg

    def rig_notes(self, rig: CameraRig) -> list[tuple[int, str]]:
        """What :meth:`for_rig` logs about its choice for this rig, without logging it.

        Parameters
        ----------
        rig : CameraRig

        Returns
        -------
        list of (int, str)
            ``(logging level, message)``: a WARNING for what the rig leaves off, then the
            INFO line of the choice and its reasons; empty when nothing is left to the rig.
        """
        return self._choose_for_rig(rig, log=False)[1]

    def _choose_for_rig(
        self, rig: CameraRig, *, log: bool
    ) -> tuple[ReconstructConfig, list[tuple[int, str]]]:
        """:meth:`for_rig`'s choice and the messages that give it (``log``: the scale's)."""
        from ..scale import scale_lengths, scene_scale

        cfg_scale = scene_scale(rig, self.capture_volume, log=log)
        cfg = scale_lengths(self, cfg_scale, "[reconstruct]", log=log)
        notes: list[tuple[int, str]] = []
        m, d = cfg.matching, cfg.densify
        if (
            m.guided is not None
            and m.gms_threshold is not None
            and d.enabled is not None
            and d.min_ncc is not None
            and d.seeds is not None
            and cfg.cover_visible != "auto"
            and cfg.match_skip_px is not None
            and cfg.match_every is not None
            and cfg.views.confirm_incidence_deg is not None
            and cfg.lk_window is not None
        ):
            return cfg, notes
        from .views import CONFIRM_INCIDENCE_DEG, retry_periods

        choice = rig_choices(rig)
        window, px_per_m = lk_window_for(rig, cfg_scale.factor)
        if cfg.lk_window is not None:
            window = cfg.lk_window
        guided = choice.guided if m.guided is None else m.guided
        gms = choice.gms_threshold if m.gms_threshold is None else m.gms_threshold
        densify = choice.densify if d.enabled is None else d.enabled
        ncc = choice.densify_ncc if d.min_ncc is None else d.min_ncc
        seeds = choice.densify_seeds if d.seeds is None else d.seeds
        every = retry_periods(cfg.views, len(rig))[0]
        cover = cfg.cover_visible
        if cover == "auto":
            cover = "on" if every > 1 else "off"
        skip = cfg.match_skip_px
        if skip is None:
            skip = MATCH_SKIP_COVER * cfg.cover_px if cover == "on" else 0.0
        match_every = cfg.match_every
        if match_every is None:
            match_every = MATCH_EVERY_COVER if cover == "on" else 1
        v = cfg.views
        confirm, unconfirmed = v.confirm_incidence_deg, []
        if confirm is None:
            unconfirmed = confirm_off_reasons(cfg, len(rig), choice.nearest_deg)
            confirm = 0.0 if unconfirmed else CONFIRM_INCIDENCE_DEG
        if unconfirmed and v.enabled and v.confirm_new:
            notes.append(
                (
                    logging.WARNING,
                    "new two-view points are not searched again facing their cameras "
                    "([reconstruct.views] confirm_incidence_deg, from the rig): "
                    + "; ".join(unconfirmed),
                )
            )

        def how(value: object, left: object) -> str:
            return f"{value} ({'from the rig' if left is None else 'set'})"

        densify_how = how("on" if densify else "off", d.enabled)
        if densify:
            densify_how += f" (min_ncc {how(f'{ncc:g}', d.min_ncc)}, seeds {how(seeds, d.seeds)})"
        confirm_how = how(
            f"within {confirm:g} deg" if confirm > 0 else "off", v.confirm_incidence_deg
        )
        notes.append(
            (
                logging.INFO,
                f"rig-derived settings: {choice.reason}; matching: guided "
                f"{how('on' if guided else 'off', m.guided)}, GMS threshold "
                f"{how(f'{gms:g}', m.gms_threshold)}; densification {densify_how}; cover_visible "
                f"{how(cover, None if cfg.cover_visible == 'auto' else cover)} (view discovery "
                f"searches each camera every {every} frame{'' if every == 1 else 's'}); "
                f"match_skip_px {how(f'{skip:g}', cfg.match_skip_px)}; match_every "
                f"{how(match_every, cfg.match_every)}{_between(match_every, densify, d)}; new "
                f"two-view points searched again facing their cameras {confirm_how}; "
                f"lk_window {how(window, cfg.lk_window)} ({px_per_m:.0f} px a metre at the "
                f"cameras' working distance, median: {LK_WINDOW_M * cfg_scale.factor * 100:.3g} "
                f"cm is {px_per_m * LK_WINDOW_M * cfg_scale.factor:.1f} px, within "
                f"{LK_WINDOW_RANGE[0]}-{LK_WINDOW_RANGE[1]})",
            )
        )
        cfg = replace(
            cfg,
            lk_window=window,
            cover_visible=cover,
            match_skip_px=skip,
            match_every=match_every,
            matching=replace(m, guided=guided, gms_threshold=gms),
            densify=replace(d, enabled=densify, min_ncc=ncc, seeds=seeds),
            views=replace(v, confirm_incidence_deg=confirm),
        )
        return cfg, notes


def confirm_off_reasons(cfg: ReconstructConfig, num_cameras: int, nearest_deg: float) -> list[str]:
    """Why the rig leaves the search of new two-view points facing their cameras off
    (``[reconstruct.views] confirm_incidence_deg`` left out; empty: it is on).

    ``nearest_deg`` is the rig's median angle between a camera's axis and its nearest
    partner's (:attr:`RigChoice.nearest_deg`).

    - On fewer than :data:`~.views.CONFIRM_MIN_CAMERAS` cameras the other cameras of a
      two-view point see it at a grazing angle, where the search misses right points: on the
      caliscope board (4 webcams) it took the torso's labelled trajectories from 447 to 283
      and the head's from 49 to 13.
    - The search finds a view only within about the patch spacing of its epipolar line;
      where the images' tolerance ``sigma_px`` is larger (a rig calibrated to a few pixels)
      and the search does not reach across the line (``search_sigmas`` under 1), it misses
      right points as often as wrong ones: on the Pose2Sim demo (``sigma_px`` 6) it lowered
      the labelled body points with three views from 4.1 to 3.4 % and the nearest-part
      agreement from 81.2 to 79.7 %.
    - Where a third camera sees a pair's surface beyond ``max_incidence_deg``
      (:data:`~.views.CONFIRM_THIRD_FACTOR` times ``nearest_deg``), the search finds grazing
      views: on six cameras 60 degrees apart it lowered view precision from 0.754 to 0.722.

    ``docs/reconstruction.md``, "New two-view points that no camera could check".
    """
    from .views import CONFIRM_MIN_CAMERAS, CONFIRM_THIRD_FACTOR

    v = cfg.views
    why = []
    if num_cameras < CONFIRM_MIN_CAMERAS:
        why.append(f"the rig has {num_cameras} cameras (fewer than {CONFIRM_MIN_CAMERAS})")
    if cfg.sigma_px > v.spacing_px and v.search_sigmas < 1:
        why.append(
            f"sigma_px = {cfg.sigma_px:.3g} is above the patch spacing of view discovery "
            f"({v.spacing_px:.3g} px) and the search does not reach across the epipolar "
            f"line (search_sigmas = {v.search_sigmas:.3g})"
        )
    third = CONFIRM_THIRD_FACTOR * nearest_deg
    if third > v.max_incidence_deg:
        why.append(
            f"the cameras' nearest partners are {nearest_deg:.0f} deg apart (median), so a third "
            f"camera sees a pair's surface at about {third:.0f} deg, beyond max_incidence_deg = "
            f"{v.max_incidence_deg:.0f}"
        )
    return why


def _between(match_every: int, densify: bool, d: DensifyConfig) -> str:
    """What densification does on the frames between whole-image matchings, for the log."""
    if match_every == 1 or not densify:
        return ""
    if not np.isfinite(d.between_seed_px):
        return " (no densification between)"
    return f" (densification between from points moving over {d.between_seed_px:g} px)"


#: ``match_skip_px`` left to the rig, where live trajectories cover every camera where they
#: are visible (``cover_visible``): this fraction of ``cover_px``. On paper69 frames 0-9, half
#: of ``cover_px`` (1.5 px) left out 42 % of the features at frame 3 and kept the mean coverage
#: of the parts; all of it (3 px, around every visible projection too) left out 86 % and lowered
#: the ball's coverage from 0.83 to 0.81 (``docs/reconstruction.md``).
MATCH_SKIP_COVER = 0.5
#: ``match_every`` left to the rig where ``cover_visible`` is on: the whole images are matched
#: every other frame, and in between only the regions where tracked points move
#: (``match_moving``). On paper69 frames 0-9 it took 11 % off the CPU; the parts' mean
#: coverage fell by 0.1 points (the ball's by 0.9), and recall, precision and the 3D error held
#: (``docs/reconstruction.md``, "Matching every other frame").
MATCH_EVERY_COVER = 2
#: Megapixels (median image) from which a rig's images are large: the default 12,000
#: features then lie fewer than 20,000 to the megapixel, too sparse to cover the surfaces, and
#: guided matching and densification fill the image (paper69's 1280x1024: 1.31 MP, 9,155
#: features per MP; caliscope's webcams 0.92; the demo's 640x512: 0.33 MP, 36,621 per MP;
#: tiny4's 320x256: 0.08). It does not follow ``num_features``, so that a smaller budget set
#: for speed does not switch the matching mode.
LARGE_IMAGE_MP = 0.6
#: Megapixels (median image) from which images below :data:`LARGE_IMAGE_MP` are densified
#: where the cameras are close enough (:data:`DENSIFY_PARTNER_DEG`): the demo's 640x512 (0.33 MP)
#: and ring12's 800x640 (0.51). Below it (tiny4's and paper69q's 320x256, 0.08 MP) a 7 x 7
#: patch 2 px apart spans a limb, and densification at :data:`DENSIFY_NCC` added wrong
#: points on tiny4 (3D error 28 to 43 mm median; ``docs/reconstruction.md``, "Densification on
#: medium images").
MEDIUM_IMAGE_MP = 0.25
#: Median angle (degrees) to the nearest partner's axis up to which medium images are densified
#: (ring8: 43.8, ring12: 34.7; tiny4's 87.1 is where it was measured to hurt). Placed between
#: the rigs measured, not measured at the threshold.
DENSIFY_PARTNER_DEG = 60.0
#: Densification's ``min_ncc`` on a dense rig (:data:`DENSE_RIG_CAMERAS` cameras, nearest
#: partners within :data:`CLOSE_PARTNER_DEG`), where a patch looks alike from cameras 10
#: degrees apart (paper69), and on a rig whose cameras have fewer than
#: :data:`CHECKING_PARTNERS` partners within 90 degrees, where no other camera can reject a
#: wrong point of a pair: on the Pose2Sim demo (two pairs facing each other) 0.8 lowered the
#: labelled points on the body from 86.0 to 85.0 % and with the nearest part from 81.2 to
#: 78.9 %, and on its synthetic twin view precision from 0.897 to 0.867.
STRICT_DENSIFY_NCC = 0.9
#: Densification's ``min_ncc`` elsewhere: seen from cameras 35-60 degrees apart, or at the
#: demo's resolution, a right match peaks lower. At 0.9 densification added 10 % to the
#: demo's points, at 0.8 50 %, with a lower 3D error and a higher view precision. On large
#: images from moving points (frames 0-9), 0.8 gave 1.6 times the actor point-frames of 0.9
#: on 8 cameras 44 degrees apart at 1280x1024 (view precision 0.945 against 0.931) and 1.4
#: times on lab4 (0.938 both) (``docs/reconstruction.md``, "Densification on rigs that are
#: not dense").
DENSIFY_NCC = 0.8
#: Partners within :data:`CHECKING_PARTNER_DEG` (the median camera's) from which a rig's
#: densified points have other cameras to check them, and densification runs at
#: :data:`DENSIFY_NCC` (lab4: 2.5, ring8: 4; Pose2Sim's two facing pairs: 1).
CHECKING_PARTNERS = 2
#: Angle (degrees) between two cameras' axes within which one counts as the other's partner
#: for :data:`CHECKING_PARTNERS` (densification's own ``max_angle_deg`` default).
CHECKING_PARTNER_DEG = 90.0
#: Median angle (degrees) between each camera's axis and its nearest partner's at or below
#: which a rig of at least :data:`DENSE_RIG_CAMERAS` cameras is dense: other close views then
#: reject guided matching's wrong matches (paper69: 10.3; the demo's ring: 43.8).
CLOSE_PARTNER_DEG = 25.0
#: Cameras a dense rig has at least (a dome; paper69: 69).
DENSE_RIG_CAMERAS = 16
#: Rigs of at most this many cameras with large images get a lenient GMS threshold
#: (:data:`LENIENT_GMS`): each point has few pairs to be found in (Pose2Sim's 4 cameras).
FEW_CAMERAS = 8
#: The lenient GMS threshold (``pipelines/pose2sim_demo.toml`` measures 2 against 6).
LENIENT_GMS = 2.0


#: The length of the subject (m, at human scale; scaled with the rig by
#: :func:`pointtraj.scale.scene_scale`) that the Lucas-Kanade window spans at the cameras'
#: working distance: half a limb's width, so that the window moves with the limb rather than
#: with the background behind it: 7 px on the demo's 640x512 ring, 15 on paper69 (1280x1024 at
#: 1.6 m). Rounded up, so that real video's noise keeps as many pixels as the span allows: on
#: Pose2Sim's 1920x1080 at 3.5 m the span is 19.4 px, and 19 px there lowered every body-part
#: figure against 21 (``docs/reconstruction.md``, "The Lucas-Kanade window and the subject's
#: size").
LK_WINDOW_M = 0.04
#: The odd window sizes (px) :func:`lk_window_for` chooses between: below 7 the flow's
#: aperture loses texture, 21 is OpenCV's and the paper's usual window.
LK_WINDOW_RANGE = (7, 21)


def lk_window_for(rig: CameraRig, factor: float = 1.0) -> tuple[int, float]:
    """The Lucas-Kanade window that spans :data:`LK_WINDOW_M` of the subject.

    Parameters
    ----------
    rig : CameraRig
    factor : float
        The rig's length scale (:class:`pointtraj.scale.SceneScale` ``factor``).

    Returns
    -------
    window : int
        The smallest odd size that covers the span, within :data:`LK_WINDOW_RANGE`.
    px_per_m : float
        Pixels a metre at the cameras' working distance (median over cameras of the focal
        length over :func:`~.connectivity.working_depths`).
    """
    from .connectivity import working_depths

    focal = np.array([0.5 * (cam.K[0, 0] + cam.K[1, 1]) for cam in rig], float)
    depth = working_depths(rig)
    ok = np.isfinite(depth) & (depth > 0)
    if not ok.any():
        return LK_WINDOW_RANGE[1], float("nan")
    px_per_m = float(np.median(focal[ok] / depth[ok]))
    span = px_per_m * LK_WINDOW_M * factor
    lo, hi = LK_WINDOW_RANGE
    window = int(2 * np.ceil((span - 1) / 2) + 1) if np.isfinite(span) else hi
    return int(min(max(window, lo), hi)), px_per_m


@dataclass(frozen=True)
class RigChoice:
    """Matching and densification settings chosen from a rig (:func:`rig_choices`).

    Attributes
    ----------
    guided : bool
    gms_threshold : float
    densify : bool
    densify_ncc : float
        Densification's ``min_ncc`` where it is left out.
    densify_seeds : str
        Densification's ``seeds`` where it is left out.
    megapixels : float
        Of the median image.
    nearest_deg : float
        Median over cameras of the angle to the nearest partner's axis (degrees).
    reason : str
        One line: the rig's figures behind the choice.
    """

    guided: bool
    gms_threshold: float
    densify: bool
    densify_ncc: float
    densify_seeds: str
    megapixels: float
    nearest_deg: float
    reason: str


def rig_choices(rig: CameraRig) -> RigChoice:
    """Matching and densification settings from the rig's baselines and resolution.

    - Large images (the median image at least :data:`LARGE_IMAGE_MP` megapixels, where the
      default 12,000 features are sparse): guided matching and densification on. On paper69
      (1280x1024) they give 2.8 times the points on the actors at a lower error; on Pose2Sim's
      and caliscope's webcams the defaults found 0-152 matches a frame. Densification grows
      from the new matches and moving points (``seeds = "moving"``), at NCC
      :data:`DENSIFY_NCC`, or :data:`STRICT_DENSIFY_NCC` on a dense rig and where the
      cameras have fewer than :data:`CHECKING_PARTNERS` partners within
      :data:`CHECKING_PARTNER_DEG`.
    - A dense rig (at least :data:`DENSE_RIG_CAMERAS` cameras, each camera's nearest axis
      within :data:`CLOSE_PARTNER_DEG`, median): guided matching on (paper69: more points,
      lower errors than brute force; it is what ``paper69q``'s small images get).
    - Medium images (:data:`MEDIUM_IMAGE_MP` to :data:`LARGE_IMAGE_MP`) on a rig whose
      cameras' nearest partners lie within :data:`DENSIFY_PARTNER_DEG` (the demo's 8 cameras
      44 degrees apart at 640x512, ring12): densification on, at NCC :data:`DENSIFY_NCC`
      and growing from every point (``seeds = "all"``; the image bounds what it can add). On
      the demo it gave 50 % more points, a lower 3D error and a higher view precision.
    - Guided matching stays off elsewhere (the demo), where it lets wrong matches on repeated
      texture through; densification stays off on smaller images and wider baselines.
    - GMS: :data:`LENIENT_GMS` on rigs of at most :data:`FEW_CAMERAS` cameras with large
      images, :data:`~.matching.GMS_THRESHOLD` elsewhere.

    Parameters
    ----------
    rig : CameraRig
        C cameras.

    Returns
    -------
    RigChoice
    """
    from .matching import GMS_THRESHOLD

    C = len(rig)
    mp = float(np.median(rig.sizes.prod(axis=1))) / 1e6
    angles = axis_angles(rig)
    np.fill_diagonal(angles, np.inf)
    nearest = float(np.median(angles.min(axis=1))) if C > 1 else 180.0
    sparse = mp >= LARGE_IMAGE_MP
    medium = not sparse and mp >= MEDIUM_IMAGE_MP and nearest <= DENSIFY_PARTNER_DEG
    close = nearest <= CLOSE_PARTNER_DEG and C >= DENSE_RIG_CAMERAS
    partners = float(np.median((angles <= CHECKING_PARTNER_DEG).sum(axis=1))) if C > 1 else 0.0
    strict = close or partners < CHECKING_PARTNERS
    few = C <= FEW_CAMERAS
    size = (
        f"large: >= {LARGE_IMAGE_MP:g}"
        if sparse
        else f"medium: >= {MEDIUM_IMAGE_MP:g}"
        if mp >= MEDIUM_IMAGE_MP
        else f"small: < {MEDIUM_IMAGE_MP:g}"
    )
    reason = (
        f"{C} cameras, {mp:.2f} MP images ({size}), nearest partner {nearest:.1f} deg, "
        f"{partners:g} within {CHECKING_PARTNER_DEG:.0f} deg (medians; a dense rig: <= "
        f"{CLOSE_PARTNER_DEG:.0f} on >= {DENSE_RIG_CAMERAS} cameras; medium images densified "
        f"up to {DENSIFY_PARTNER_DEG:.0f}; densification at NCC {DENSIFY_NCC:g} with >= "
        f"{CHECKING_PARTNERS} within {CHECKING_PARTNER_DEG:.0f})"
    )
    return RigChoice(
        guided=sparse or close,
        gms_threshold=LENIENT_GMS if (sparse and few) else GMS_THRESHOLD,
        densify=sparse or medium,
        densify_ncc=STRICT_DENSIFY_NCC if strict else DENSIFY_NCC,
        densify_seeds="all" if medium else "moving",
        megapixels=mp,
        nearest_deg=nearest,
        reason=reason,
    )
