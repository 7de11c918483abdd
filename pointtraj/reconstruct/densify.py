"""Densification by patch plane sweep: grow new points around reconstructed ones.

Feature matching leaves surfaces with little texture for ORB (skin, plain clothing) nearly
empty on rigs whose cameras are far apart, and view expansion's flow between views needs close
cameras. Densification works at any baseline because it uses the calibration instead of image
similarity alone, in the manner of match propagation and patch-based multi-view stereo
(Lhuillier & Quan 2002; Furukawa & Ponce 2010, "expansion"):

1. In each reference camera r, the pixels of a regular grid (``step_px``) that lie within
   ``radius_px`` of a reconstructed point's projection, and that no point observes yet, are
   candidates. Each takes its nearest seed's depth ``z0`` in r and the seed's other cameras.
2. Depth hypotheses ``z0 +- depth_range_m`` (``depth_steps`` of them) are swept along the
   candidate's ray. A ``patch_size`` x ``patch_size`` patch, fronto-parallel in r, is warped into
   each partner camera at each depth, and scored by normalised cross-correlation (NCC) with r's
   patch.
3. A candidate is kept when the mean NCC over its partners peaks at ``min_ncc`` or more, with
   no rival peak within ``min_margin`` of it away from the best depth (repeated or flat texture),
   and its patch is textured (grey-level standard deviation ``min_std`` or more). The depth is
   refined by a parabola through the peak. It is observed in r and in every partner whose own
   NCC at that depth reaches ``min_ncc``.
   Two tests then remove wrong points. The patch's 3 x 3 centre must match as well
   (``inner_ncc``): a patch across an occluding edge matches on the nearer surface's texture
   while its centre lies on the farther one ("edge fattening" of window stereo). And the
   other cameras that should see the point must not mostly disagree (``veto_ncc``).
4. Accepted points seed the next of ``rounds`` rounds, so a frame's points spread outwards.

The result is a set of multi-view observations that the tracker triangulates with RANSAC and
follows by optical flow like matched points. Everything is vectorised per (reference, partner)
camera pair and chunk of candidates.
"""

from __future__ import annotations

import dataclasses
import logging
from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass
from typing import overload

import numpy as np

from ..camera import CameraRig
from ..errors import ValidationError, check_array
from ..geometry import axis_angles, finite_rows
from ..scale import SceneLength
from .texture import PATCH_SPACINGS

logger = logging.getLogger(__name__)

_REMAP_ROWS = 32000  # cv2.remap's maps must have fewer than 2^15 rows
_NCC_BOUND = 1.0 + 1e-4  # an NCC's upper bound, float32 rounding included
_NCC_BLOCK = 1 << 17  # samples per block of the NCC work arrays (0.5 MB each: they stay in cache)


@dataclass(frozen=True)
class DensifyConfig:
    """Parameters of patch densification (TOML table ``[reconstruct.densify]``).

    Attributes
    ----------
    enabled : bool or None
        Run densification whenever matching runs. None (the default, the key left out): chosen
        from the rig by the reconstruction (:meth:`~.config.ReconstructConfig.for_rig`): on
        where the images are large (0.6 megapixels and more, where the default features are
        sparse), off elsewhere; functions given this config directly read None as off.
    step_px : float
        Grid spacing of candidate pixels in each reference camera.
    radius_px : float
        Candidates lie within this many pixels of a seed's projection (how far one round grows).
    depth_range_m : float
        Depths from ``z0 - depth_range_m`` to ``z0 + depth_range_m`` around the seed's depth.
    depth_steps : int
        Depth hypotheses in that range (odd keeps ``z0`` itself).
    patch_size : int
        Samples per side of the square patch.
    patch_spacing_px : float or None
        Spacing of the patch's samples in the reference image. None (the default, the key left
        out): chosen by the reconstruction from the first frame's texture
        (:func:`~.texture.texture_patch_spacing`): the smallest of 2-6 px whose patch holds 0.7
        of the contrast of a patch twice as wide. That is 2 px (a 7 x 7 patch 12 px across) on
        rendered texture, fine-grained to the pixel, and 4-6 px on real video, whose contrast
        keeps growing with scale: on the Pose2Sim demo (2.5 cm of the person in 12 px) 5 px
        gave better points than 2 (``docs/real_captures.md``, "Densification's patch on real
        video"), and on a rendered twin of that rig 2 px gave better ones than 4 or 5.
        Functions given this config directly read None as 2 px (:attr:`spacing_px`).
    min_ncc : float or None
        Mean NCC a candidate needs at its best depth; also what a partner view needs to observe
        the new point. None (the default, the key left out): chosen from the rig
        (:func:`~.config.rig_choices`): 0.9 on a dense rig (16 cameras or more, nearest
        partners within 25 degrees), whose patches look alike from one camera to the next,
        and where cameras have fewer than 2 others within 90 degrees (nothing checks a pair's
        points); 0.8 elsewhere, where a right match peaks lower.
    min_margin : float
        The best mean NCC must exceed every score more than ``peak_width`` steps from the best
        depth by this much.
    peak_width : int
        Depth steps on each side of the best one that belong to its peak.
    min_std : float
        Grey-level standard deviation (0-255) the reference patch needs.
    veto_ncc : float
        A new point is dropped when more of the other cameras within ``veto_angle_deg`` that it
        projects into score below this NCC than cameras observe it (a wrong match floats in
        free space and the other cameras see something else there); -1 turns the test off.
    veto_angle_deg : float
        See ``veto_ncc``.
    inner_ncc : float
        NCC that the 3 x 3 centre of the patch (spacing :attr:`spacing_px` / 2) needs in every
        observing partner at the chosen depth. A patch across an occluding edge matches on the
        nearer surface's texture while its centre lies on the farther surface ("edge
        fattening"); -1 turns the test off.
    max_angle_deg : float
        Partner cameras' optical axes are at most this far from the reference camera's.
    rounds : int
        Growth rounds per frame; each grows from the previous round's points.
    max_partners : int
        A candidate is swept in at most this many of its seed's cameras, those whose optical
        axes are nearest the reference camera's, and vetoed by at most this many other cameras
        (0: all). Bounds the cost on dense rigs.
    max_points : int
        At most this many new points per frame (bounds the cost).
    seeds : {"moving", "new", "all"} or None
        Which of the frame's points densification grows from; None (the default, the key left
        out): chosen from the rig (:func:`~.config.rig_choices`): ``"all"`` on medium images, where
        the image bounds what it can add, ``"moving"`` elsewhere. ``"new"``: the points that
        matching found at this frame (at a capture's first frame, all of them), so that it fills
        around matched texture and stops there. ``"moving"``: those and the tracked points whose
        image moved by more than ``seed_motion_px`` since the previous frame in the cameras
        that follow them, so that surface a moving limb newly shows is filled too, while
        static, already covered surface (a floor) stops growing. ``"all"``: every point of the
        frame, so that the covered area grows by ``rounds * radius_px`` every frame, over static
        surfaces too, until ``max_points`` caps it (about 20,000 new points a frame on paper69).
        On the frames between whole-image matchings, ``between_motion_px`` picks the tracked
        points that seed, whatever this is (``"new"``: none).
    seed_motion_px : float
        With ``seeds = "moving"``: the image motion (pixels, the median over the cameras that
        follow the point) above which a tracked point seeds densification.
    between_motion_px : float
        On the frames between two whole-image matchings (``[reconstruct] match_every`` above
        1, chosen on rigs of 32 cameras and more), densification grows from the frame's new
        matches and from the tracked points whose image moved by more than this (and
        ``seed_motion_px``): fast motion shows the most new surface in a frame, slow motion
        waits for the next whole-image matching. ``inf``: no densification between, except on
        the frame after one where it stopped at ``max_points`` (the rest of that frame's work:
        a capture's first frame on paper69), which densifies as a matched frame does. On
        paper69 (``docs/reconstruction.md``, "Densification between matched frames from fast
        motion") the frames between cost 7-8 CPU-s of sweeps from every moving point, for
        about 800 new points.
    """

    enabled: bool | None = None
    step_px: float = 6.0
    radius_px: float = 24.0
    depth_range_m: float = SceneLength(0.08)
    depth_steps: int = 33
    patch_size: int = 7
    patch_spacing_px: float | None = None
    min_ncc: float | None = None
    min_margin: float = 0.1
    peak_width: int = 3
    min_std: float = 4.0
    veto_ncc: float = 0.3
    inner_ncc: float = 0.7
    veto_angle_deg: float = 120.0
    max_angle_deg: float = 90.0
    rounds: int = 2
    max_partners: int = 3
    max_points: int = 20000
    seeds: str | None = None
    seed_motion_px: float = 1.0
    between_motion_px: float = 4.0

    def __post_init__(self) -> None:
        checks = {
            "step_px": self.step_px >= 1,
            "radius_px": self.radius_px > 0,
            "depth_range_m": self.depth_range_m > 0,
            "depth_steps": self.depth_steps >= 3,
            "patch_size": self.patch_size >= 3,
            "patch_spacing_px": self.patch_spacing_px is None or self.patch_spacing_px > 0,
            "min_ncc": self.min_ncc is None or -1 <= self.min_ncc <= 1,
            "min_margin": self.min_margin >= 0,
            "peak_width": 1 <= self.peak_width < self.depth_steps // 2,
            "min_std": self.min_std >= 0,
            "veto_ncc": -1 <= self.veto_ncc <= 1,
            "veto_angle_deg": 0 < self.veto_angle_deg <= 180,
            "inner_ncc": -1 <= self.inner_ncc <= 1,
            "max_angle_deg": 0 < self.max_angle_deg <= 180,
            "rounds": self.rounds >= 1,
            "max_partners": self.max_partners >= 0,
            "max_points": self.max_points >= 1,
            "seed_motion_px": self.seed_motion_px >= 0,
            "between_motion_px": self.between_motion_px >= 0,
        }
        bad = [k for k, ok in checks.items() if not ok]
        if bad:
            raise ValidationError(f"DensifyConfig.{bad[0]} out of range: {getattr(self, bad[0])!r}")
        if self.seeds not in (None, "moving", "new", "all"):
            raise ValidationError(
                f'DensifyConfig.seeds must be "moving", "new" or "all", not {self.seeds!r}'
            )

    @property
    def spacing_px(self) -> float:
        """``patch_spacing_px``, or :data:`~.texture.PATCH_SPACINGS`' first (2 px) where it is
        left to the images and they were not measured."""
        return PATCH_SPACINGS[0] if self.patch_spacing_px is None else self.patch_spacing_px

    @property
    def between_seed_px(self) -> float:
        """The image motion (pixels) above which a tracked point seeds densification on a
        frame between whole-image matchings; ``inf`` where nothing does there (``seeds =
        "new"`` or ``between_motion_px = inf``)."""
        if self.seeds == "new":
            return float("inf")
        return max(self.between_motion_px, self.seed_motion_px)


#: Default memory budget (MB) of the prepared images that :class:`PreparedImages` keeps.
PREPARED_BUDGET_MB = 256.0


class PreparedImages(Sequence[np.ndarray]):
    """Undistorted float32 grey images, made on first use and kept within a memory budget.

    Item ``c`` is camera c's image undistorted to its own K (NaN where an undistorted pixel
    falls outside the original image) and blurred by a Gaussian of sigma 1 px, so that sparse
    patch samples do not alias. The sweep then maps patches between cameras by a plane
    homography, without lens distortion in its inner loop.

    An image is prepared when it is first asked for and kept while the kept images fit
    ``budget_mb``; beyond it the least recently used one is dropped and prepared again when it
    is needed (for a 1280x1024 image about 3 ms, or 12 ms with lens distortion, where the
    undistortion map dominates). Memory so stays bounded whatever the rig:
    all the prepared images of a frame take 360 MB on 69 cameras at 1280x1024 and 3.5 GB on a
    hundred 4K cameras. On the former, a budget of 128 MB prepares 287 images instead of 69 at
    the same CPU time, and halves densification's peak memory
    (``benchmarks/bench_densify_memory.py``).

    Parameters
    ----------
    rig : CameraRig
        C cameras.
    grey : sequence of C (H, W) uint8 ndarrays
        The frame's grey images, in the rig's order.
    budget_mb : float
        Memory for kept images, in MB (at least one image is always kept).

    Raises
    ------
    ValidationError
        If the number of images is not the number of cameras, or an image's size is not its
        camera's.
    """

    def __init__(
        self, rig: CameraRig, grey: Sequence[np.ndarray], budget_mb: float = PREPARED_BUDGET_MB
    ) -> None:
        if len(grey) != len(rig):
            raise ValidationError(f"prepare_images: expected {len(rig)} images, got {len(grey)}")
        for cam, g in zip(rig, grey, strict=True):
            if np.shape(g)[:2] != (cam.height, cam.width):
                raise ValidationError(
                    f"prepare_images: camera {cam.name!r} is {cam.width}x{cam.height}, its "
                    f"image has shape {np.shape(g)}"
                )
        self.rig = rig
        self.grey = grey
        self.budget_bytes = max(float(budget_mb), 0.0) * 1e6
        self._kept: OrderedDict[int, np.ndarray] = OrderedDict()
        self.prepared = 0  # images prepared so far (more than C: the budget made it re-prepare)

    def __len__(self) -> int:
        return len(self.rig)

    @overload
    def __getitem__(self, c: int) -> np.ndarray: ...
    @overload
    def __getitem__(self, c: slice) -> list[np.ndarray]: ...
    def __getitem__(self, c: int | slice) -> np.ndarray | list[np.ndarray]:
        if isinstance(c, slice):
            return [self[i] for i in range(len(self))[c]]
        c = range(len(self))[c]  # IndexError outside, negative indices allowed
        image = self._kept.get(c)
        if image is not None:
            self._kept.move_to_end(c)
            return image
        image = self._prepare(c)
        self._kept[c] = image
        while len(self._kept) > 1 and self.nbytes > self.budget_bytes:
            self._kept.popitem(last=False)
        return image

    @property
    def nbytes(self) -> int:
        """Bytes of the images kept now."""
        return sum(im.nbytes for im in self._kept.values())

    def _prepare(self, c: int) -> np.ndarray:
        import cv2

        cam = self.rig[c]
        im = np.asarray(self.grey[c], np.float32)
        if cam.has_distortion:
            mx, my = cv2.initUndistortRectifyMap(
                cam.K, cam.dist, None, cam.K, cam.size, cv2.CV_32FC1
            )
            im = cv2.remap(
                im, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan
            )
        self.prepared += 1
        return cv2.GaussianBlur(im, (0, 0), 1.0)


def prepare_images(
    rig: CameraRig, grey: Sequence[np.ndarray], budget_mb: float = PREPARED_BUDGET_MB
) -> PreparedImages:
    """The frame's images as :func:`densify` wants them (:class:`PreparedImages`).

    Parameters
    ----------
    rig : CameraRig
        C cameras.
    grey : sequence of C (H, W) uint8 ndarrays
    budget_mb : float
        Memory for the prepared images kept at once (MB).

    Returns
    -------
    PreparedImages
        A sequence of C (H, W) float32 images, each prepared on first use.
    """
    return PreparedImages(rig, grey, budget_mb)


def _sample(image: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Bilinear samples of ``image`` at (u, v) of shape (..., P); NaN outside the image."""
    import cv2

    shape = u.shape
    P = shape[-1]
    mu = np.ascontiguousarray(u.reshape(-1, P), dtype=np.float32)
    mv = np.ascontiguousarray(v.reshape(-1, P), dtype=np.float32)
    out = np.empty(mu.shape, np.float32)
    for a in range(0, mu.shape[0], _REMAP_ROWS):
        b = a + _REMAP_ROWS
        cv2.remap(
            image,
            mu[a:b],
            mv[a:b],
            cv2.INTER_LINEAR,
            dst=out[a:b],
            borderMode=cv2.BORDER_CONSTANT,
            borderValue=float("nan"),
        )
    return out.reshape(shape)


def _zscore(patches: np.ndarray, overwrite: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Patches over the last axis, centred and scaled to unit RMS; and their std.

    Parameters
    ----------
    patches : (..., P) float ndarray
    overwrite : bool
        Centre and scale ``patches`` in place (the caller's own temporary; the same values,
        fewer passes over memory).

    Returns
    -------
    zscores : (..., P) float ndarray
    std : (...) float ndarray
    """
    mean = patches.mean(axis=-1, keepdims=True)
    if overwrite:
        centred = patches
        centred -= mean
    else:
        centred = patches - mean
    std = np.sqrt(np.mean(np.square(centred), axis=-1, keepdims=True))
    with np.errstate(invalid="ignore", divide="ignore"):
        if overwrite:
            centred /= std
            return centred, std[..., 0]
        return centred / std, std[..., 0]


def _grid_axes(width: int, height: int, step: float, margin: float) -> tuple[np.ndarray, ...]:
    """The candidate grid's columns ``us`` and rows ``vs`` (pixels)."""
    return np.arange(margin, width - margin, step), np.arange(margin, height - margin, step)


def _grid(width: int, height: int, step: float, margin: float) -> np.ndarray:
    """(G, 2) candidate pixels, row by row: point ``iv * len(us) + iu`` is ``(us[iu], vs[iv])``
    (:func:`_grid_axes`)."""
    us, vs = _grid_axes(width, height, step, margin)
    uu, vv = np.meshgrid(us, vs)
    return np.stack([uu.ravel(), vv.ravel()], axis=1)  # (G, 2)


def _near_grid(points: np.ndarray, us: np.ndarray, vs: np.ndarray, radius: float) -> np.ndarray:
    """(G,) bool: the grid points of :func:`_grid` (columns ``us``, rows ``vs``, spaced by
    ``step``) closer than ``radius`` to one of ``points`` (Q, 2) finite.

    The same test as a k-d tree query with ``distance_upper_bound=radius`` (squared
    distances summed over u then v, compared strictly), at O(Q): with ``radius`` below the
    spacing only the column and the row on each side of a point can be that close (rounding
    moves a point's cell by 1e-12 of a spacing, far less than the spacing less the radius),
    and the four grid points around it are tested.
    """
    near = np.zeros(len(us) * len(vs), bool)
    if len(points) == 0 or len(us) == 0 or len(vs) == 0:
        return near
    step_u = us[1] - us[0] if len(us) > 1 else np.inf
    step_v = vs[1] - vs[0] if len(vs) > 1 else np.inf
    iu0 = np.floor((points[:, 0] - us[0]) / step_u) if len(us) > 1 else np.zeros(len(points))
    iv0 = np.floor((points[:, 1] - vs[0]) / step_v) if len(vs) > 1 else np.zeros(len(points))
    if radius >= min(step_u, step_v) * (1 - 1e-9):  # more than two columns or rows in reach
        from scipy.spatial import cKDTree

        grid = np.stack([g.ravel() for g in np.meshgrid(us, vs)], axis=1)
        d, _ = cKDTree(points).query(grid, k=1, distance_upper_bound=radius)
        return np.isfinite(d)
    r2 = radius * radius
    for du in (0, 1):
        iu = iu0 + du
        ok_u = (iu >= 0) & (iu < len(us))
        iu = np.where(ok_u, iu, 0).astype(np.int64)
        d_u = points[:, 0] - us[iu]
        for dv in (0, 1):
            iv = iv0 + dv
            ok = ok_u & (iv >= 0) & (iv < len(vs))
            iv = np.where(ok, iv, 0).astype(np.int64)
            d_v = points[:, 1] - vs[iv]
            hit = ok & (d_u * d_u + d_v * d_v < r2)
            near[iv[hit] * len(us) + iu[hit]] = True
    return near


def _in_box(points: np.ndarray, around: np.ndarray, reach: float) -> np.ndarray:
    """Indices of ``points`` (n, 2) inside the bounding box of ``around`` (m, 2, m > 0) grown
    by ``reach`` on every side: the only ones that can lie within ``reach`` of one of them."""
    lo = around.min(axis=0) - reach
    hi = around.max(axis=0) + reach
    x, y = points[:, 0], points[:, 1]
    return np.flatnonzero((x >= lo[0]) & (x <= hi[0]) & (y >= lo[1]) & (y <= hi[1]))


def densify(
    rig: CameraRig,
    images: Sequence[np.ndarray],
    seeds_xyz: np.ndarray,
    seeds_pixels: np.ndarray,
    taken_pixels: np.ndarray,
    config: DensifyConfig | None = None,
) -> np.ndarray:
    """New multi-view observations around reconstructed points (see the module docstring).

    Parameters
    ----------
    rig : CameraRig
        C cameras.
    images : sequence of C (H, W) float32 ndarrays
        Undistorted grey images from :func:`prepare_images`.
    seeds_xyz : (N, 3) float ndarray
        Reconstructed points of this frame.
    seeds_pixels : (C, N, 2) float ndarray
        Their observations, distorted pixels (NaN in the cameras that do not observe them).
    taken_pixels : (C, Q, 2) float ndarray
        Every observation already made at this frame (distorted pixels, NaN where absent); no
        candidate is placed within ``0.75 * step_px`` of one.
    config : DensifyConfig, optional
        ``min_ncc`` left out (None) is chosen from ``rig`` (:func:`~.config.rig_choices`).

    Returns
    -------
    (C, M, 2) float ndarray
        Observations (distorted pixels) of M new points, each in its reference camera and one
        or more partners (NaN elsewhere).
    """
    cfg = config or DensifyConfig()
    if cfg.min_ncc is None:
        from .config import rig_choices

        cfg = dataclasses.replace(cfg, min_ncc=rig_choices(rig).densify_ncc)
    C = len(rig)
    if len(images) != C:
        raise ValidationError(f"densify: expected {C} images, got {len(images)}")
    seeds_xyz = check_array("seeds_xyz", seeds_xyz, (None, 3))
    seeds_pixels = check_array("seeds_pixels", seeds_pixels, (C, len(seeds_xyz), 2))
    taken_pixels = check_array("taken_pixels", taken_pixels, (C, None, 2))
    ideal_rig = CameraRig([dataclasses.replace(cam, dist=np.zeros(8)) for cam in rig])
    ideal = rig.undistort_pixels(seeds_pixels)  # NaN stays NaN
    cams, _, ideal_taken = rig.undistort_observed(taken_pixels)  # camera by camera
    good = finite_rows(ideal_taken)  # (a lens model can fail far outside the image)
    cams, ideal_taken = cams[good], ideal_taken[good]
    taken = np.split(ideal_taken, np.cumsum(np.bincount(cams, minlength=C))[:-1])
    angles = axis_angles(rig)
    np.fill_diagonal(angles, np.inf)
    half = (cfg.patch_size - 1) / 2
    off = (np.arange(cfg.patch_size) - half) * cfg.spacing_px
    offsets = np.stack(np.meshgrid(off, off), axis=-1).reshape(-1, 2)  # (P, 2)
    margin = half * cfg.spacing_px + 1
    dz = np.linspace(-cfg.depth_range_m, cfg.depth_range_m, cfg.depth_steps)  # (D,)
    found: list[np.ndarray] = []
    subsets: dict[int, tuple[np.ndarray, CameraRig]] = {}
    total = 0
    xyz, pix = seeds_xyz, ideal
    for _ in range(cfg.rounds):
        round_X, round_seen, round_pix = [], [], []
        # the seeds' observing cameras (C, N), once a round rather than once a reference camera
        observed = finite_rows(pix) & finite_rows(xyz)
        for r in range(C):
            if total >= cfg.max_points:
                break
            X, seen = _densify_camera(
                rig, images, r, xyz, pix, observed, taken, angles[r], offsets, margin, dz, cfg,
                subsets,
            )  # fmt: skip
            X, seen = X[: cfg.max_points - total], seen[:, : cfg.max_points - total]
            if len(X) == 0:
                continue
            total += len(X)
            got = np.where(seen[..., None], ideal_rig.project(X).pixels, np.nan)
            round_X.append(X)
            round_seen.append(seen)
            round_pix.append(got)
            for c in np.flatnonzero(seen.any(axis=1)):  # later cameras and rounds leave
                taken[c] = np.concatenate([taken[c], got[c][seen[c]]])  # these pixels alone
        if not round_X:
            break
        xyz = np.concatenate(round_X)
        seen = np.concatenate(round_seen, axis=1)
        pix = np.concatenate(round_pix, axis=1)  # the next round's seeds, ideal pixels
        found.append(np.where(seen[..., None], rig.project(xyz).pixels, np.nan))
    out = np.concatenate(found, axis=1) if found else np.zeros((C, 0, 2))
    logger.debug("densify: %d new points in %d rounds", out.shape[1], len(found))
    return out


def _warp(other, cam) -> tuple[np.ndarray, np.ndarray]:
    """The plane-sweep warp from reference camera ``cam`` into ``other``: ``M = K' R_rs``
    (3, 3) and ``k = K' R' (C - C')`` (3,), float32 (see :func:`_ncc`)."""
    R_rs = other.R @ cam.R.T
    M = (other.K @ R_rs).astype(np.float32)
    k = (other.K @ (other.R @ (cam.C - other.C))).astype(np.float32)
    return M, k


def _ncc(
    image: np.ndarray,
    other,
    cam,
    rays: np.ndarray,
    z: np.ndarray,
    ref: np.ndarray,
    shifts: np.ndarray | None = None,
) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """NCC of reference patches with their warps into another camera, per depth hypothesis.

    A patch sample on ray ``x`` of the reference camera at depth ``z`` projects into the other
    camera's undistorted image at ``z * (K' R_rs x) + K' t_rs`` (homogeneous): a plane homography
    per depth, applied to all samples at once. With ``shifts``, each warped patch is also
    compared shifted by each of them in the other image (a calibration error moves a point
    off its epipolar line) and the best shift's score is kept.

    Parameters
    ----------
    image : (H, W) float32 ndarray
        The other camera's undistorted image (:func:`prepare_images`).
    other, cam : Camera
        The other camera and the reference camera.
    rays : (n, P, 3) float ndarray
        The patch samples' rays in the reference camera's frame (``z = 1``).
    z : (n, D) float ndarray
        Depth hypotheses along the reference camera's optical axis.
    ref : (n, P) float ndarray
        The reference patches from :func:`_zscore`.
    shifts : (n, S, 2) float ndarray, optional
        Pixel offsets in the other image tried at every depth.

    Returns
    -------
    scores : (n, D) float ndarray
        NCC in [-1, 1]; -1 where the warped patch leaves the image or is flat.
    best_shift : (n, D) int ndarray
        Only with ``shifts``: the index of the best shift at each depth.
    """
    M, k = _warp(other, cam)
    B = rays.astype(np.float32, copy=False) @ M.T  # (n, P, 3)
    return _ncc_warped(image, B, np.broadcast_to(k, (len(B), 3)), z, ref, shifts)


def _ncc_warped(
    image: np.ndarray,
    B: np.ndarray,
    k: np.ndarray,
    z: np.ndarray,
    ref: np.ndarray,
    shifts: np.ndarray | None = None,
) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """:func:`_ncc` of patches whose warps are given per row, so that one call scores the
    patches of several reference cameras in one other camera (view discovery).

    Parameters
    ----------
    image : (H, W) float32 ndarray
        The other camera's undistorted image.
    B : (n, P, 3) float32 ndarray
        ``rays @ M.T`` with each row's reference camera's ``M`` (:func:`_warp`).
    k : (n, 3) float32 ndarray
        Each row's ``k`` (:func:`_warp`).
    z, ref, shifts
        As for :func:`_ncc`.

    Returns
    -------
    As :func:`_ncc`.
    """
    n, D = z.shape
    P = ref.shape[1]
    S = 1 if shifts is None else shifts.shape[1]
    scores = np.full((n, D, S), -1.0)
    rows = max(1, min(_REMAP_ROWS // D, _NCC_BLOCK // (D * P * S)))
    for a in range(0, n, rows):
        Bx, By, Bw = (np.ascontiguousarray(B[a : a + rows, :, i]) for i in range(3))  # (m, P)
        kx, ky, kw = (k[a : a + rows, i, None, None] for i in range(3))  # (m, 1, 1)
        zz = z[a : a + rows].astype(np.float32)  # (m, D)
        # w = z B_w + k_w, u = (z B_x + k_x) / w, v = (z B_y + k_y) / w: the same float32
        # operations as written out; the outer products by einsum (one rounded product each,
        # 3 times faster than a broadcast multiply over the short last axis), the rest in place
        w = np.einsum("md,mp->mdp", zz, Bw)  # (m, D, P)
        w += kw
        np.copyto(w, np.float32(np.nan), where=w <= 1e-6)  # behind the camera: NaN
        u = np.einsum("md,mp->mdp", zz, Bx)
        u += kx
        v = np.einsum("md,mp->mdp", zz, By)
        v += ky
        with np.errstate(invalid="ignore", divide="ignore"):
            u /= w
            v /= w
        r = ref[a : a + rows].astype(np.float32)
        for j in range(S):  # the warp is computed once, each shift only moves the samples
            uj, vj = u, v
            if shifts is not None:
                off = shifts[a : a + rows, j].astype(np.float32)  # (m, 2)
                uj, vj = u + off[:, None, None, 0], v + off[:, None, None, 1]
            cmp, _ = _zscore(_sample(image, uj, vj), overwrite=True)  # (m, D, P)
            ncc = np.einsum("mdp,mp->md", cmp, r)
            ncc /= P
            scores[a : a + rows, :, j] = np.where(np.isfinite(ncc), ncc, -1.0)
    if shifts is None:
        return scores[..., 0]
    best = np.argmax(scores, axis=2)
    return np.take_along_axis(scores, best[..., None], axis=2)[..., 0], best


def _rays(K: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    """(n, ..., 3) rays ``K^-1 (u, v, 1)`` of ideal pixels (n, ..., 2), in the camera frame.

    ``K`` is one camera's (3, 3) intrinsics, or (n, 3, 3): each row's own camera's (the same
    arithmetic, element by element).
    """
    K = np.asarray(K)
    shape = K.shape[:-2] + (1,) * (pixels.ndim - 1 - (K.ndim - 2))

    def k(i: int, j: int) -> np.ndarray:
        return K[..., i, j].reshape(shape)

    y = (pixels[..., 1] - k(1, 2)) / k(1, 1)
    x = (pixels[..., 0] - k(0, 2) - k(0, 1) * y) / k(0, 0)
    return np.stack([x, y, np.ones_like(x)], axis=-1)


def _nearest(mask: np.ndarray, angles: np.ndarray, k: int) -> np.ndarray:
    """Keep, per column of a (C, n) camera mask, the ``k`` cameras nearest in ``angles`` (C,)."""
    if k <= 0 or mask.shape[1] == 0 or int(mask.sum(axis=0).max()) <= k:
        return mask
    key = np.where(mask, angles[:, None], np.inf)
    # the first k of each column's stable order (one sort; ranks below k, as before)
    first = np.argsort(key, axis=0, kind="stable")[:k]  # (k, n)
    near = np.zeros(mask.shape, bool)
    np.put_along_axis(near, first, True, axis=0)
    return mask & near


def _densify_camera(
    rig: CameraRig,
    images: Sequence[np.ndarray],
    r: int,
    seeds_xyz: np.ndarray,
    seeds_pixels: np.ndarray,
    seeds_observed: np.ndarray,
    taken: list[np.ndarray],
    angles: np.ndarray,
    offsets: np.ndarray,
    margin: float,
    dz: np.ndarray,
    cfg: DensifyConfig,
    subsets: dict[int, tuple[np.ndarray, CameraRig]],
) -> tuple[np.ndarray, np.ndarray]:
    """One reference camera's accepted candidates.

    ``seeds_pixels`` and ``taken`` are ideal (undistorted) pixels; ``seeds_observed`` (C, N)
    where a seed's pixels and position are finite; ``subsets`` caches, per reference camera,
    the cameras whose images the new points are tested against (and their rig). Returns the new points (M, 3) and the
    cameras observing them (C, M) bool.
    """
    from scipy.spatial import cKDTree

    C = len(rig)
    empty = (np.zeros((0, 3)), np.zeros((C, 0), bool))
    seen = seeds_observed[r]
    if not seen.any():
        return empty
    cam = rig[r]
    q = seeds_pixels[r, seen]
    z_seed = ((seeds_xyz[seen] - cam.C) @ cam.R.T)[:, 2]
    partners_ok = angles <= cfg.max_angle_deg  # (C,)
    partner_mask = _nearest(
        seeds_observed[:, seen] & partners_ok[:, None],
        angles,
        cfg.max_partners,
    )  # (C, S): each seed's observing cameras nearest to r
    us, vs = _grid_axes(cam.width, cam.height, cfg.step_px, margin)
    grid = _grid(cam.width, cam.height, cfg.step_px, margin)
    # only grid points within the seeds' box, grown by the radius, can be near a seed: the
    # tree is asked about those alone (the seeds of a moving limb cover a small part of it)
    near = _in_box(grid, q, cfg.radius_px)
    keep = np.zeros(len(grid), bool)
    j = np.zeros(len(grid), np.int64)
    d, j[near] = cKDTree(q).query(grid[near], k=1, distance_upper_bound=cfg.radius_px)
    keep[near] = np.isfinite(d)
    if len(taken[r]) and keep.any():
        # no candidate near a taken pixel (a k-d tree of every taken pixel, built for each
        # reference camera, cost more than the test of the grid points around each of them);
        # only the taken pixels within reach of a candidate can take one
        reach = 0.75 * cfg.step_px
        t = taken[r][_in_box(taken[r], grid[keep], reach)]
        keep &= ~_near_grid(t, us, vs, reach)
    cand, j = grid[keep], j[keep]
    ok = partner_mask[:, j].any(axis=0) & (z_seed[j] > 0)
    cand, j = cand[ok], j[ok]
    if len(cand) == 0:
        return empty

    # reference patches; flat ones cannot be matched
    n_cand = len(cand)
    patch = cand[:, None, :] + offsets[None]  # (n, P, 2)
    ref, ref_std = _zscore(_sample(images[r], patch[..., 0], patch[..., 1]))
    ok = ref_std >= cfg.min_std
    cand, j, ref, patch = cand[ok], j[ok], ref[ok], patch[ok]
    n, P = ref.shape
    if n == 0:
        return empty
    rays = _rays(cam.K, patch).astype(np.float32)  # (n, P, 3), as _ncc uses them
    z = z_seed[j][:, None] + dz[None, :]  # (n, D)
    D = len(dz)

    score_sum = np.zeros((n, D))
    count = partner_mask[:, j].sum(axis=0).astype(np.float64)  # (n,) partners per candidate
    swept = np.zeros(n)  # partners swept so far
    # A candidate needs a mean NCC of min_ncc over its partners at one depth, and an NCC is
    # at most 1: one whose partial sum cannot reach that with the partners left is rejected
    # now, not swept in them (the others' sums, and so every accepted point, are unchanged).
    hopeless = np.zeros(n, bool)
    per_partner: list[tuple[int, np.ndarray, np.ndarray]] = []
    for s in np.flatnonzero(partners_ok):
        sel = np.flatnonzero(partner_mask[s, j] & ~hopeless)
        if sel.size == 0:
            continue
        scores = _ncc(images[s], rig[s], cam, rays[sel], z[sel], ref[sel])
        score_sum[sel] += scores
        swept[sel] += 1
        per_partner.append((int(s), sel, scores))
        reach = score_sum[sel].max(axis=1) + (count[sel] - swept[sel]) * _NCC_BOUND
        hopeless[sel] = reach < cfg.min_ncc * count[sel] - 1e-9

    with np.errstate(invalid="ignore", divide="ignore"):
        mean = score_sum / count[:, None]
    best = np.argmax(mean, axis=1)
    top = mean[np.arange(n), best]
    far = np.abs(np.arange(D)[None, :] - best[:, None]) > cfg.peak_width
    rival = np.where(far, mean, -np.inf).max(axis=1)
    interior = (best > 0) & (best < D - 1)
    accept = (count > 0) & interior & (top >= cfg.min_ncc) & (top - rival >= cfg.min_margin)
    accept &= ~hopeless
    if not accept.any():
        return empty
    # parabola through the peak and its neighbours
    b = np.clip(best, 1, D - 2)
    y0, y1, y2 = (mean[np.arange(n), b + k] for k in (-1, 0, 1))
    with np.errstate(invalid="ignore", divide="ignore"):
        delta = np.clip(0.5 * (y0 - y2) / (y0 - 2 * y1 + y2), -0.5, 0.5)
    delta = np.where(np.isfinite(delta), delta, 0.0)
    z_best = z[np.arange(n), b] + delta * (dz[1] - dz[0])
    X = cam.C + (z_best[:, None] * _rays(cam.K, cand)) @ cam.R  # (n, 3) world
    # in the image of r, its partners and the cameras the veto may ask; only those cameras are
    # projected into (each camera's projection is its own: the same values as the whole rig's)
    if r not in subsets:
        need = partners_ok | (angles <= cfg.veto_angle_deg if cfg.veto_ncc > -1 else False)
        need[r] = True
        subsets[r] = (np.flatnonzero(need), rig.subset(np.flatnonzero(need).tolist()))
    cams, sub = subsets[r]
    in_image = np.zeros((C, n), bool)
    in_image[cams] = sub.project(X).in_image
    views = np.zeros((C, n), bool)
    views[r] = in_image[r]
    for s, sel, scores in per_partner:
        good = (scores[np.arange(sel.size), best[sel]] >= cfg.min_ncc) & in_image[s, sel]
        views[s, sel[good]] = True
    accept &= views[r] & (views.sum(axis=0) >= 2)
    if cfg.inner_ncc > -1 and accept.any():
        # the centre of the patch must match too: a patch across an occluding edge matches on
        # the nearer surface's texture while its centre lies on the farther one
        k = np.arange(-1, 2) * max(cfg.spacing_px / 2, 1.0)
        inner = np.stack(np.meshgrid(k, k), axis=-1).reshape(-1, 2)
        idx = np.flatnonzero(accept)
        ipatch = cand[idx, None, :] + inner[None]
        iref, _ = _zscore(_sample(images[r], ipatch[..., 0], ipatch[..., 1]))
        irays = _rays(cam.K, ipatch)
        worst = np.full(idx.size, np.inf)
        for s in np.flatnonzero(partners_ok):
            sub = np.flatnonzero(views[s, idx])
            if sub.size == 0:
                continue
            ncc = _ncc(images[s], rig[s], cam, irays[sub], z_best[idx[sub], None], iref[sub])
            worst[sub] = np.minimum(worst[sub], ncc[:, 0])
        accept[idx[worst < cfg.inner_ncc]] = False
    if cfg.veto_ncc > -1 and accept.any():
        # the other cameras that should see the point: a wrong match floats in free space, so
        # most of them see something else there (an occluded view disagrees too, so only a
        # majority of disagreeing views rejects)
        disagree = np.zeros(n, np.int64)
        asked = _nearest(
            (angles <= cfg.veto_angle_deg)[:, None] & in_image & ~views & accept[None],
            angles,
            cfg.max_partners,
        )  # (C, n)
        for s in np.flatnonzero(asked.any(axis=1)):
            sel = np.flatnonzero(asked[s])
            if sel.size == 0:
                continue
            ncc = _ncc(images[s], rig[s], cam, rays[sel], z_best[sel, None], ref[sel])[:, 0]
            disagree[sel] += ncc < cfg.veto_ncc
        accept &= disagree < views.sum(axis=0)
    logger.debug(
        "densify camera %d: %d candidates, %d textured, %d peaked, %d accepted",
        r,
        n_cand,
        n,
        int((top >= cfg.min_ncc).sum()),
        int(accept.sum()),
    )
    return X[accept], views[:, accept]
