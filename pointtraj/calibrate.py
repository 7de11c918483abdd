"""Rig calibration: structure from motion with pycolmap, metric scale and world frame.

The paper (Section 5, step 1) calibrates each camera's intrinsics (focal length, principal point,
radial distortion), recovers the extrinsics with structure from motion and refines both jointly
in a bundle adjustment. :func:`calibrate_images` does this with pycolmap on the CPU:

1. SIFT features of ``images/<camera>/<frame>.jpg`` with ``CameraMode.PER_FOLDER``, so each
   physical camera has one intrinsic model shared by all its frames;
2. exhaustive matching and two-view geometric verification;
3. incremental mapping, then a joint bundle adjustment of poses, points and intrinsics;
4. conversion to a :class:`~pointtraj.camera.CameraRig`: pycolmap's ``cam_from_world`` is
   ``x_cam = R X + t``; COLMAP's pixel origin is the top-left image corner, OpenCV's the centre
   of the top-left pixel, so principal points move by -0.5 px. A static rig gives one pose per
   frame for each camera; they are averaged (chordal mean of rotations, mean of centres) and
   their spread is reported;
5. rejection of degenerate cameras (:func:`find_degenerate_cameras`: an implausible focal
   length or distortion, or a reprojection error or observation count far from the other
   cameras'): they are taken out of the model, named as failed with the reason, and the rest
   is adjusted again.

SfM fixes the rig only up to a similarity. The metric scale and world frame come from what the
user knows: a distance between two camera centres (:func:`scale_rig_by_distance`), a ChArUco
board seen by the cameras (:func:`align_rig_to_charuco`), or an existing rig
(:func:`align_rig_to`: Umeyama's similarity between camera centres, after a
least-median-of-squares search that leaves out cameras whose centres disagree with the
others'). For footage where SfM cannot register the cameras (few, textureless views of a
moving board),
:func:`calibrate_charuco` calibrates from ChArUco corners alone: OpenCV's planar calibration per
camera, relative poses from shared board views, then a joint bundle adjustment of all intrinsics,
camera poses and board poses with the board's known geometry.
"""

from __future__ import annotations

import logging
import os
import tomllib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .camera import Camera, CameraRig, rodrigues_from_rotation, rotation_from_rodrigues
from .errors import FileFormatError, PointtrajError, ValidationError, check_array

__all__ = [
    "CAMERA_MODELS",
    "CalibrationError",
    "CalibrationOptions",
    "Calibration",
    "CharucoBoard",
    "RigComparison",
    "align_rig_to",
    "align_rig_to_charuco",
    "estimate_rig_similarity",
    "RigAlignment",
    "calibrate_charuco",
    "calibrate_images",
    "compare_rigs",
    "detect_charuco",
    "export_frames",
    "find_degenerate_cameras",
    "plot_match_graph",
    "scale_rig_by_distance",
    "transform_rig",
    "umeyama",
]

logger = logging.getLogger(__name__)

#: COLMAP camera models accepted by :class:`CalibrationOptions` (all map onto OpenCV's model).
CAMERA_MODELS = ("OPENCV", "FULL_OPENCV", "RADIAL", "SIMPLE_RADIAL", "PINHOLE", "SIMPLE_PINHOLE")
#: Image suffixes read from an image folder.
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png")

Stage = Callable[[str], None]


class CalibrationError(PointtrajError):
    """Calibration could not produce a rig from the given input (too few registered cameras,
    no overlap between cameras, missing images)."""


@dataclass(frozen=True)
class CalibrationOptions:
    """Parameters of :func:`calibrate_images`.

    Attributes
    ----------
    camera_model : str
        COLMAP camera model (one of :data:`CAMERA_MODELS`); ``OPENCV`` = fx fy cx cy k1 k2 p1 p2.
    max_image_size : int
        Images are downscaled for feature extraction so their longer side is at most this.
    max_num_features : int
        SIFT features per image.
    min_num_matches : int
        Verified inlier matches for an image pair to count as overlapping (mapper and failure
        diagnosis).
    min_pose_inliers : int
        2D-3D inliers for the mapper to register an image (COLMAP's default 30).
    refine_principal_point : bool
        Refine principal points in the final bundle adjustment (ill-conditioned with few
        views; off by default, as in COLMAP).
    num_threads : int
        CPU threads for pycolmap.
    seed : int
        Mapper random seed.
    min_focal_ratio, max_focal_ratio : float
        Plausible focal lengths, as multiples of the image's longer side (COLMAP's mapper
        defaults 0.1 and 10, i.e. fields of view of about 157 to 5.7 degrees); a camera whose
        final focal length is outside is rejected as degenerate.
    max_distortion : float
        Largest plausible magnitude of a distortion coefficient k1 k2 p1 p2 k3 (COLMAP's
        ``max_extra_param``).
    outlier_error_ratio, outlier_error_px : float
        A camera whose mean reprojection error exceeds both ``outlier_error_ratio`` times the
        median over the registered cameras and ``outlier_error_px`` is rejected.
    min_observation_ratio : float
        A camera with fewer observations (2D points of the model) than this fraction of the
        median over the registered cameras is rejected.
    retry_failed : bool
        Give cameras that were rejected or not registered a second chance: their focal length
        is set to the median over the calibrated cameras (relative to the image's longer side),
        marked as a prior, and the mapper continues from the model. COLMAP's default initial
        focal length, 1.2 x the longer side, is 2-2.5 times too long for wide-angle lenses and
        webcams, where absolute pose estimation then fails or converges to a degenerate focal
        length.
    """

    camera_model: str = "RADIAL"
    max_image_size: int = 3200
    max_num_features: int = 8192
    min_num_matches: int = 15
    min_pose_inliers: int = 30
    refine_principal_point: bool = False
    num_threads: int = 2
    seed: int = 0
    min_focal_ratio: float = 0.1
    max_focal_ratio: float = 10.0
    max_distortion: float = 1.0
    outlier_error_ratio: float = 3.0
    outlier_error_px: float = 1.0
    min_observation_ratio: float = 0.1
    retry_failed: bool = True

    def __post_init__(self) -> None:
        if self.camera_model not in CAMERA_MODELS:
            raise ValidationError(
                f"camera_model: unknown model {self.camera_model!r}; "
                f"choose from {', '.join(CAMERA_MODELS)}"
            )
        for name in ("max_image_size", "max_num_features", "min_num_matches", "num_threads"):
            if getattr(self, name) < 1:
                raise ValidationError(f"{name} must be >= 1, got {getattr(self, name)}")
        if not 0 < self.min_focal_ratio < self.max_focal_ratio:
            raise ValidationError(
                "min_focal_ratio and max_focal_ratio must satisfy 0 < min < max, got "
                f"{self.min_focal_ratio} and {self.max_focal_ratio}"
            )
        for name in ("max_distortion", "outlier_error_ratio", "outlier_error_px"):
            if not getattr(self, name) > 0:
                raise ValidationError(f"{name} must be positive, got {getattr(self, name)}")
        if not 0 <= self.min_observation_ratio < 1:
            raise ValidationError(
                f"min_observation_ratio must be in [0, 1), got {self.min_observation_ratio}"
            )


@dataclass
class Calibration:
    """Result of a calibration.

    Attributes
    ----------
    rig : CameraRig
        The registered cameras, in input order.
    camera_names : list of str
        Every input camera, registered or not.
    errors : dict of str to float
        Mean reprojection error in pixels per registered camera (final rig, all frames).
    observations : dict of str to int
        Observations (2D points of the model) per registered camera.
    failed : dict of str to str
        Camera -> why it is not in ``rig``.
    match_counts : (C, C) int ndarray
        Verified inlier matches between cameras (summed over frames), over ``camera_names``;
        zero diagonal.
    pose_spread_deg : dict of str to float
        Largest rotation difference between a camera's per-frame poses (0 for one frame).
    num_points : int
        3D points in the model.
    notes : list of str
        What was done to set the scale and world frame.
    """

    rig: CameraRig
    camera_names: list[str]
    errors: dict[str, float]
    observations: dict[str, int]
    failed: dict[str, str]
    match_counts: np.ndarray
    pose_spread_deg: dict[str, float] = field(default_factory=dict)
    num_points: int = 0
    notes: list[str] = field(default_factory=list)

    def with_rig(self, rig: CameraRig, note: str) -> Calibration:
        """A copy with a transformed rig (same cameras) and a note appended."""
        return Calibration(
            rig,
            self.camera_names,
            self.errors,
            self.observations,
            self.failed,
            self.match_counts,
            self.pose_spread_deg,
            self.num_points,
            [*self.notes, note],
        )

    def summary(self) -> str:
        """Several lines: per-camera reprojection errors and failures."""
        lines = [
            f"registered {len(self.rig)} of {len(self.camera_names)} cameras, "
            f"{self.num_points} points"
        ]
        for name in self.camera_names:
            if name in self.errors:
                spread = self.pose_spread_deg.get(name, 0.0)
                lines.append(
                    f"  {name}: {self.errors[name]:.3f} px mean reprojection error, "
                    f"{self.observations[name]} observations, pose spread {spread:.3f} deg"
                )
            else:
                lines.append(f"  {name}: FAILED - {self.failed.get(name, 'unknown')}")
        lines.extend(self.notes)
        return "\n".join(lines)


# --------------------------------------------------------------------------------------------
# Similarity transforms


def umeyama(
    src: np.ndarray, dst: np.ndarray, with_scale: bool = True
) -> tuple[float, np.ndarray, np.ndarray]:
    """Least-squares similarity ``dst ≈ s R src + t`` (Umeyama 1991).

    Parameters
    ----------
    src, dst : (N, 3) float ndarray
        Corresponding points, N >= 3 (not collinear).
    with_scale : bool
        Estimate ``s``; otherwise ``s = 1`` (rigid).

    Returns
    -------
    s : float
    R : (3, 3) float ndarray
    t : (3,) float ndarray

    Raises
    ------
    ValidationError
        For mismatched shapes, fewer than 3 points or degenerate (collinear) points.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> a = rng.normal(size=(10, 3))
    >>> s, R, t = umeyama(a, 2.0 * a + [1.0, 2.0, 3.0])
    >>> round(s, 6), bool(np.allclose(R, np.eye(3))), np.round(t, 6).tolist()
    (2.0, True, [1.0, 2.0, 3.0])
    """
    src = check_array("src", src, (None, 3), finite=True)
    dst = check_array("dst", dst, (src.shape[0], 3), finite=True)
    if src.shape[0] < 3:
        raise ValidationError(f"umeyama needs at least 3 point pairs, got {src.shape[0]}")
    s, R, t, ok = _umeyama_batch(src[None], dst[None], with_scale)
    if not ok[0]:
        raise ValidationError("umeyama: points are degenerate (collinear or coincident)")
    return float(s[0]), R[0], t[0]


def transform_rig(rig: CameraRig, s: float, R: np.ndarray, t: np.ndarray) -> CameraRig:
    """Apply a world similarity ``X' = s R X + t`` to a rig (intrinsics unchanged).

    Camera centres become ``s R C + t`` and camera rotations ``R_cam R^T``, so every camera
    projects ``X'`` to the pixel it projected ``X`` to.

    Parameters
    ----------
    rig : CameraRig
    s : float
        Positive scale.
    R : (3, 3) float ndarray
        Rotation.
    t : (3,) float ndarray

    Returns
    -------
    CameraRig
    """
    if not s > 0:
        raise ValidationError(f"scale must be positive, got {s}")
    R = check_array("R", R, (3, 3), finite=True)
    t = check_array("t", t, (3,), finite=True)
    cams = [Camera(c.name, c.K, c.R @ R.T, s * R @ c.C + t, size=c.size, dist=c.dist) for c in rig]
    return CameraRig(cams)


@dataclass(frozen=True)
class RigAlignment:
    """A similarity between two rigs' world frames, fitted robustly to camera centres.

    Attributes
    ----------
    similarity : (s, R, t)
        ``X_reference = s R X_rig + t``.
    inliers : list of str
        Shared cameras the final fit used.
    outliers : list of str
        Shared cameras left out of the fit (their centres disagree with the others').
    residual_m : dict of str to float
        Per shared camera, ``|s R C_rig + t - C_reference|`` under the final similarity (units of
        ``reference``).
    threshold_m : float
        Residual above which a camera is an outlier (0 when no robust fit was made).
    """

    similarity: tuple[float, np.ndarray, np.ndarray]
    inliers: list[str]
    outliers: list[str]
    residual_m: dict[str, float]
    threshold_m: float = 0.0


def estimate_rig_similarity(
    rig: CameraRig,
    reference: CameraRig,
    with_scale: bool = True,
    robust: bool = True,
    outlier_factor: float = 3.0,
    min_outlier_rel: float = 0.05,
    max_triplets: int = 2000,
) -> RigAlignment:
    """Similarity taking ``rig``'s world frame to ``reference``'s, robust to outlier cameras.

    Cameras are paired by name. With 4 or more non-collinear shared centres and ``robust``, a
    least-median-of-squares search (Rousseeuw 1984) over camera triplets picks the Umeyama
    similarity whose median centre residual is smallest (all triplets, or ``max_triplets``
    drawn with a fixed seed); cameras whose residual under it exceeds
    ``max(outlier_factor * (1 + 5 / (N - 3)) * median residual, min_outlier_rel * spread)``
    are outliers, where ``1 + 5 / (N - 3)`` is Rousseeuw and Leroy's small-sample correction
    of the median for N cameras and ``spread`` the RMS distance of the reference centres from
    their mean, and Umeyama's fit is redone on the inliers. So one camera that SfM placed
    wrongly cannot skew the alignment of the others. With 3 shared centres the fit is
    Umeyama's on all of them; with 2 (or collinear centres) the rotation is the mean of the
    cameras' relative orientations and the scale the ratio of baselines.

    Parameters
    ----------
    rig, reference : CameraRig
    with_scale : bool
        Estimate the scale (True for SfM output).
    robust : bool
        Search for outlier cameras (otherwise one least-squares fit on all shared centres).
    outlier_factor : float
        Outlier threshold in multiples of the corrected least-median residual (for many
        cameras, 3 is about 4.6 standard deviations of isotropic Gaussian centre noise, whose
        3D norm has median 1.54 sigma).
    min_outlier_rel : float
        Floor of the outlier threshold as a fraction of the reference rig's spread, so that
        cameras that are merely less accurate than the median are kept (with 4 cameras the
        triplet fit leaves all the misfit to the fourth).
    max_triplets : int
        Most camera triplets tried.

    Returns
    -------
    RigAlignment

    Raises
    ------
    ValidationError
        If fewer than 2 cameras are shared by name.
    """
    common = [n for n in rig.names if n in reference.names]
    if len(common) < 2:
        raise ValidationError(
            f"align: the rigs share {len(common)} camera name(s) ({', '.join(common) or 'none'}); "
            "need at least 2"
        )
    src = rig.subset(common)
    dst = reference.subset(common)
    inliers = np.ones(len(common), bool)
    threshold = 0.0
    if len(common) >= 4 and robust:
        found = _lmeds_similarity(src.C, dst.C, with_scale, max_triplets)
        if found is not None:
            residual = np.linalg.norm(_apply(found, src.C) - dst.C, axis=1)  # (N,)
            spread = float(np.sqrt(np.mean(np.sum((dst.C - dst.C.mean(axis=0)) ** 2, axis=1))))
            small = 1 + 5 / (len(common) - 3)  # Rousseeuw & Leroy (1987), p = 3 cameras
            threshold = max(
                outlier_factor * small * float(np.median(residual)), min_outlier_rel * spread
            )
            inliers = residual <= threshold
    if inliers.sum() >= 3:
        try:
            sim = umeyama(src.C[inliers], dst.C[inliers], with_scale)
        except ValidationError:
            kept = [n for n, ok in zip(common, inliers, strict=True) if ok]
            sim = _align_two(src.subset(kept), dst.subset(kept), with_scale)
    else:
        sim = _align_two(src, dst, with_scale)
    residual = np.linalg.norm(_apply(sim, src.C) - dst.C, axis=1)  # (N,)
    outliers = [n for n, ok in zip(common, inliers, strict=True) if not ok]
    if outliers:
        logger.warning(
            "alignment: left out %d of %d cameras whose centres disagree with the others "
            "(residual > %.3g): %s",
            len(outliers),
            len(common),
            threshold,
            ", ".join(
                f"{n} ({r:.3g})"
                for n, r, ok in zip(common, residual, inliers, strict=True)
                if not ok
            ),
        )
    return RigAlignment(
        sim,
        [n for n, ok in zip(common, inliers, strict=True) if ok],
        outliers,
        {n: float(r) for n, r in zip(common, residual, strict=True)},
        threshold,
    )


def align_rig_to(
    rig: CameraRig, reference: CameraRig, with_scale: bool = True, robust: bool = True
) -> tuple[CameraRig, tuple[float, np.ndarray, np.ndarray]]:
    """Move ``rig`` into ``reference``'s world frame (similarity between camera centres).

    The similarity is :func:`estimate_rig_similarity`'s: cameras are paired by name and, with 4
    or more shared cameras, cameras whose centres disagree with the others' are left out of the
    fit (logged as a warning; use :func:`estimate_rig_similarity` to get their names).

    Parameters
    ----------
    rig, reference : CameraRig
    with_scale : bool
        Estimate the scale (True for SfM output).
    robust : bool
        Leave outlier cameras out of the fit.

    Returns
    -------
    aligned : CameraRig
    similarity : (s, R, t)
        ``X_reference = s R X_rig + t``.

    Raises
    ------
    ValidationError
        If fewer than 2 cameras are shared by name.
    """
    sim = estimate_rig_similarity(rig, reference, with_scale, robust).similarity
    return transform_rig(rig, *sim), sim


def _apply(sim: tuple[float, np.ndarray, np.ndarray], X: np.ndarray) -> np.ndarray:
    """``s R X + t`` for (N, 3) points."""
    s, R, t = sim
    return s * X @ R.T + t


def _umeyama_batch(src: np.ndarray, dst: np.ndarray, with_scale: bool):
    """Umeyama similarities of (T, k, 3) point sets; also a (T,) mask of non-degenerate sets."""
    mu_s, mu_d = src.mean(axis=1, keepdims=True), dst.mean(axis=1, keepdims=True)  # (T, 1, 3)
    a, b = src - mu_s, dst - mu_d
    cov = np.einsum("tki,tkj->tij", b, a) / src.shape[1]  # (T, 3, 3)
    U, S, Vt = np.linalg.svd(cov)
    ok = S[:, 1] > 1e-12 * np.maximum(S[:, 0], 1e-300)
    d = np.sign(np.linalg.det(U) * np.linalg.det(Vt))  # (T,)
    D = np.ones((len(src), 3))
    D[:, 2] = np.where(d < 0, -1.0, 1.0)
    R = np.einsum("tij,tj,tjk->tik", U, D, Vt)  # (T, 3, 3)
    var_s = np.sum(a**2, axis=(1, 2)) / src.shape[1]  # (T,)
    if with_scale:
        s = np.sum(S * D, axis=1) / np.where(var_s > 0, var_s, 1.0)
    else:
        s = np.ones(len(src))
    t = mu_d[:, 0] - s[:, None] * np.einsum("tij,tj->ti", R, mu_s[:, 0])  # (T, 3)
    return s, R, t, ok & (var_s > 0)


def _lmeds_similarity(
    src: np.ndarray, dst: np.ndarray, with_scale: bool, max_triplets: int
) -> tuple[float, np.ndarray, np.ndarray] | None:
    """Least-median-of-squares similarity ``dst ≈ s R src + t`` from point triplets.

    Parameters
    ----------
    src, dst : (N, 3) float ndarray
        N >= 4.

    Returns
    -------
    (s, R, t), or None if every triplet is degenerate.
    """
    from itertools import combinations

    n = len(src)
    if n * (n - 1) * (n - 2) // 6 <= max_triplets:
        triplets = np.array(list(combinations(range(n), 3)))  # (T, 3)
    else:
        rng = np.random.default_rng(0)
        triplets = np.argsort(rng.random((max_triplets, n)), axis=1)[:, :3]  # (T, 3) distinct
    s, R, t, ok = _umeyama_batch(src[triplets], dst[triplets], with_scale)
    if not ok.any():
        return None
    s, R, t = s[ok], R[ok], t[ok]
    moved = s[:, None, None] * np.einsum("tij,nj->tni", R, src) + t[:, None]  # (T, N, 3)
    med = np.median(np.sum((moved - dst) ** 2, axis=2), axis=1)  # (T,)
    best = int(np.argmin(med))
    return float(s[best]), R[best], t[best]


def _align_two(
    src: CameraRig, dst: CameraRig, with_scale: bool
) -> tuple[float, np.ndarray, np.ndarray]:
    """Similarity from two (or collinear) cameras: rotation from mean orientation, scale from
    the baseline."""
    # X_dst = s R X_src + t with R_cam_dst = R_cam_src R^T  =>  R = R_cam_dst^T R_cam_src.
    Rs = np.einsum("cji,cjk->cik", dst.R, src.R)  # (C, 3, 3)
    R = _mean_rotation(Rs)
    s = 1.0
    if with_scale:
        base_src = np.linalg.norm(src.C[-1] - src.C[0])
        base_dst = np.linalg.norm(dst.C[-1] - dst.C[0])
        if base_src <= 0:
            raise ValidationError("align: the shared cameras have coincident centres")
        s = float(base_dst / base_src)
    t = dst.C.mean(axis=0) - s * R @ src.C.mean(axis=0)
    return s, R, t


def _mean_rotation(Rs: np.ndarray) -> np.ndarray:
    """Chordal L2 mean of (N, 3, 3) rotations."""
    U, _, Vt = np.linalg.svd(Rs.sum(axis=0))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


def _rotation_angle_deg(Ra: np.ndarray, Rb: np.ndarray) -> np.ndarray:
    """Angles in degrees between stacked rotations (..., 3, 3)."""
    tr = np.einsum("...ij,...ij->...", Ra, Rb)  # trace(Ra^T Rb)
    return np.degrees(np.arccos(np.clip((tr - 1) / 2, -1.0, 1.0)))


def scale_rig_by_distance(rig: CameraRig, camera_a: str, camera_b: str, metres: float) -> CameraRig:
    """Scale a rig so the centres of two cameras are ``metres`` apart.

    Scaling is about the world origin (``C -> s C``); orientations are kept.

    Parameters
    ----------
    rig : CameraRig
    camera_a, camera_b : str
        Camera names.
    metres : float
        Known distance between their centres.

    Returns
    -------
    CameraRig
    """
    for name in (camera_a, camera_b):
        if name not in rig.names:
            raise ValidationError(
                f"scale distance: camera {name!r} is not in the calibrated rig "
                f"({', '.join(rig.names)})"
            )
    if not metres > 0:
        raise ValidationError(f"scale distance must be positive, got {metres}")
    d = float(np.linalg.norm(rig[rig.index(camera_a)].C - rig[rig.index(camera_b)].C))
    if d <= 0:
        raise ValidationError(f"cameras {camera_a} and {camera_b} have the same centre")
    return transform_rig(rig, metres / d, np.eye(3), np.zeros(3))


@dataclass(frozen=True)
class RigComparison:
    """Per-camera differences between an estimated rig and a reference, after alignment.

    Attributes
    ----------
    names : list of str
        Shared cameras.
    rotation_deg : (C,) float ndarray
        Angle of ``R_est R_ref^T``.
    centre_m : (C,) float ndarray
        Distance between camera centres (metres).
    focal_rel : (C,) float ndarray
        ``(f_est - f_ref) / f_ref`` with f the mean of fx and fy.
    principal_px : (C,) float ndarray
        Distance between principal points (pixels).
    distortion_px : (C,) float ndarray
        RMS over an 8x8 grid of image points of the difference between the two lens models'
        distortion displacements (pixels): compares distortion independently of how it is
        parameterised.
    similarity : (s, R, t)
        ``X_ref = s R X_est + t`` used for the alignment.
    alignment_outliers : list of str
        Shared cameras left out of the similarity fit (see :func:`estimate_rig_similarity`);
        they are still compared.
    """

    names: list[str]
    rotation_deg: np.ndarray
    centre_m: np.ndarray
    focal_rel: np.ndarray
    principal_px: np.ndarray
    distortion_px: np.ndarray
    similarity: tuple[float, np.ndarray, np.ndarray]
    alignment_outliers: list[str] = field(default_factory=list)

    def summary(self) -> dict[str, float]:
        """Maxima and means of the per-camera differences."""
        return {
            "cameras": len(self.names),
            "rotation_deg_mean": float(self.rotation_deg.mean()),
            "rotation_deg_max": float(self.rotation_deg.max()),
            "centre_mm_mean": float(1e3 * self.centre_m.mean()),
            "centre_mm_max": float(1e3 * self.centre_m.max()),
            "focal_pct_mean": float(100 * np.abs(self.focal_rel).mean()),
            "focal_pct_max": float(100 * np.abs(self.focal_rel).max()),
            "principal_px_max": float(self.principal_px.max()),
            "distortion_px_rms_max": float(self.distortion_px.max()),
            "scale": float(self.similarity[0]),
            "alignment_outliers": float(len(self.alignment_outliers)),
        }


def compare_rigs(
    estimate: CameraRig, reference: CameraRig, align: bool = True, robust: bool = True
) -> RigComparison:
    """Compare two rigs camera by camera (paired by name), optionally after a similarity.

    Parameters
    ----------
    estimate, reference : CameraRig
    align : bool
        First align ``estimate`` to ``reference`` with :func:`estimate_rig_similarity`.
    robust : bool
        Leave cameras whose centres disagree with the others' out of the alignment (they are
        still compared, and named in ``alignment_outliers``).

    Returns
    -------
    RigComparison
    """
    sim: tuple[float, np.ndarray, np.ndarray] = (1.0, np.eye(3), np.zeros(3))
    outliers: list[str] = []
    if align:
        fit = estimate_rig_similarity(estimate, reference, robust=robust)
        sim, outliers = fit.similarity, fit.outliers
        estimate = transform_rig(estimate, *sim)
    names = [n for n in estimate.names if n in reference.names]
    if not names:
        raise ValidationError("compare: the rigs share no camera names")
    est, ref = estimate.subset(names), reference.subset(names)
    rot = _rotation_angle_deg(est.R, ref.R)
    centre = np.linalg.norm(est.C - ref.C, axis=1)
    f_est = (est.K[:, 0, 0] + est.K[:, 1, 1]) / 2
    f_ref = (ref.K[:, 0, 0] + ref.K[:, 1, 1]) / 2
    pp = np.linalg.norm(est.K[:, :2, 2] - ref.K[:, :2, 2], axis=1)
    dist_px = np.array([_distortion_difference(a, b) for a, b in zip(est, ref, strict=True)])
    return RigComparison(names, rot, centre, (f_est - f_ref) / f_ref, pp, dist_px, sim, outliers)


def _distortion_difference(a: Camera, b: Camera, grid: int = 8) -> float:
    """RMS pixel difference of the distortion displacement of two cameras over b's image."""
    from .camera import distort_normalized

    w, h = b.size
    u, v = np.meshgrid(np.linspace(0.05, 0.95, grid) * w, np.linspace(0.05, 0.95, grid) * h)
    pix = np.stack([u.ravel(), v.ravel()], axis=1)
    xy = (pix - b.K[:2, 2]) / np.diag(b.K)[:2]  # ideal normalised coordinates
    f = np.diag(b.K)[:2]
    da = (distort_normalized(xy, a.dist) - xy) * f
    db = (distort_normalized(xy, b.dist) - xy) * f
    return float(np.sqrt(np.mean(np.sum((da - db) ** 2, axis=1))))


# --------------------------------------------------------------------------------------------
# Images


def export_frames(capture, frames: Sequence[int], image_dir: str | os.PathLike, quality: int = 95):
    """Write ``image_dir/<camera>/<frame:06d>.jpg`` from a capture; a generator of file paths.

    Iterate it to completion (e.g. inside ``click.progressbar``); each step writes one image.

    Parameters
    ----------
    capture : pointtraj.session.Capture
        Anything with ``camera_names``, ``num_frames`` and ``read(camera, frame)`` (RGB uint8).
    frames : sequence of int
        Frame indices.
    image_dir : path-like
    quality : int
        JPEG quality.

    Yields
    ------
    Path
        Each written image.
    """
    import cv2

    frames = list(frames)
    for f in frames:
        if not 0 <= f < capture.num_frames:
            raise ValidationError(
                f"frames: frame {f} is outside the capture (0..{capture.num_frames - 1})"
            )
    root = Path(image_dir)
    for cam in capture.camera_names:
        (root / cam).mkdir(parents=True, exist_ok=True)
        for f in frames:
            img = capture.read(cam, f)
            out = root / cam / f"{f:06d}.jpg"
            if not cv2.imwrite(str(out), img[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, quality]):
                raise PointtrajError(f"could not write {out}")
            yield out


def _list_images(image_dir: Path) -> dict[str, list[str]]:
    """Camera folder -> sorted image names relative to ``image_dir``."""
    if not image_dir.is_dir():
        raise CalibrationError(f"image folder {image_dir} does not exist")
    out: dict[str, list[str]] = {}
    for sub in sorted(p for p in image_dir.iterdir() if p.is_dir()):
        names = sorted(
            f"{sub.name}/{p.name}" for p in sub.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES
        )
        out[sub.name] = names
    if not out:
        raise CalibrationError(
            f"missing images: {image_dir} has no camera folders (expected <camera>/<frame>.jpg)"
        )
    return out


# --------------------------------------------------------------------------------------------
# pycolmap


def _opencv_from_colmap(model: str, params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV K (3, 3) and 8 distortion coefficients from COLMAP camera parameters.

    COLMAP's pixel origin is the image corner, OpenCV's the first pixel's centre: -0.5 px.
    """
    p = np.asarray(params, float)
    dist = np.zeros(8)
    if model in ("SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL"):
        fx = fy = p[0]
        cx, cy = p[1], p[2]
        dist[: len(p) - 3] = p[3:]  # k1 [k2]
    elif model in ("PINHOLE", "OPENCV", "FULL_OPENCV"):
        fx, fy, cx, cy = p[:4]
        dist[: len(p) - 4] = p[4:]  # k1 k2 p1 p2 [k3 k4 k5 k6]
    else:
        raise ValidationError(f"unsupported COLMAP camera model {model}")
    K = np.array([[fx, 0.0, cx - 0.5], [0.0, fy, cy - 0.5], [0.0, 0.0, 1.0]])
    return K, dist


def _match_counts(
    database: Path, image_camera: Mapping[int, int], num_cameras: int
) -> tuple[np.ndarray, np.ndarray]:
    """Verified inlier matches summed per camera pair, and per image pair (as rows)."""
    import pycolmap

    db = pycolmap.Database.open(str(database))
    try:
        pair_ids, geometries = db.read_two_view_geometries()
    finally:
        db.close()
    counts = np.zeros((num_cameras, num_cameras), np.int64)
    rows = []
    for pid, geo in zip(pair_ids, geometries, strict=True):
        i, j = pycolmap.pair_id_to_image_pair(pid)
        n = int(geo.inlier_matches.shape[0])
        rows.append((i, j, n))
        ci, cj = image_camera.get(i), image_camera.get(j)
        if ci is None or cj is None or ci == cj:
            continue
        counts[ci, cj] += n
        counts[cj, ci] += n
    return counts, np.asarray(rows, np.int64).reshape(-1, 3)


def calibrate_images(
    image_dir: str | os.PathLike,
    work_dir: str | os.PathLike,
    options: CalibrationOptions | None = None,
    stage: Stage | None = None,
) -> Calibration:
    """Calibrate a rig from ``image_dir/<camera>/<frame>.jpg`` with pycolmap (CPU).

    Parameters
    ----------
    image_dir : path-like
        One folder per camera; image names need not match across cameras.
    work_dir : path-like
        Scratch folder for the COLMAP database and models (created; a previous database
        there is replaced).
    options : CalibrationOptions, optional
    stage : callable, optional
        Called with a one-line message as each stage starts.

    Returns
    -------
    Calibration
        Rig in SfM's arbitrary similarity frame (scale and world frame undefined; see
        :func:`scale_rig_by_distance`, :func:`align_rig_to`, :func:`align_rig_to_charuco`).

    Raises
    ------
    CalibrationError
        Missing images, no overlapping camera pair, or fewer than 2 cameras registered.
    """
    import pycolmap

    options = options or CalibrationOptions()
    say = stage or (lambda msg: None)
    image_dir, work_dir = Path(image_dir), Path(work_dir)
    per_camera = _list_images(image_dir)
    camera_names = list(per_camera)
    empty = [c for c, ims in per_camera.items() if not ims]
    if len(camera_names) - len(empty) < 2:
        raise CalibrationError(
            f"missing images: need images of at least 2 cameras in {image_dir}, found "
            f"{len(camera_names) - len(empty)}"
        )
    work_dir.mkdir(parents=True, exist_ok=True)
    database = work_dir / "database.db"
    for p in (database, work_dir / "database.db-wal", work_dir / "database.db-shm"):
        p.unlink(missing_ok=True)
    if logger.getEffectiveLevel() > logging.DEBUG:
        pycolmap.logging.minloglevel = 2  # errors only from glog

    n_images = sum(len(v) for v in per_camera.values())
    say(f"extracting SIFT features from {n_images} images of {len(camera_names)} cameras")
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = options.camera_model
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.num_threads = options.num_threads
    extraction.use_gpu = False
    extraction.max_image_size = options.max_image_size
    extraction.sift.max_num_features = options.max_num_features
    pycolmap.extract_features(
        database,
        image_dir,
        image_names=[n for ims in per_camera.values() for n in ims],
        camera_mode=pycolmap.CameraMode.PER_FOLDER,
        reader_options=reader,
        extraction_options=extraction,
        device=pycolmap.Device.cpu,
    )

    say("matching all image pairs (exhaustive) and verifying two-view geometry")
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = options.num_threads
    matching.use_gpu = False
    verification = pycolmap.TwoViewGeometryOptions()
    verification.min_num_inliers = options.min_num_matches
    pycolmap.match_exhaustive(
        database,
        matching_options=matching,
        verification_options=verification,
        device=pycolmap.Device.cpu,
    )

    db = pycolmap.Database.open(str(database))
    try:
        db_images = db.read_all_images()
        keypoints = {im.image_id: db.num_keypoints_for_image(im.image_id) for im in db_images}
    finally:
        db.close()
    cam_index = {name: i for i, name in enumerate(camera_names)}
    image_camera = {im.image_id: cam_index[im.name.split("/")[0]] for im in db_images}
    counts, _ = _match_counts(database, image_camera, len(camera_names))
    if not np.any(counts >= options.min_num_matches):
        raise CalibrationError(
            "no overlap: no pair of cameras has "
            f">= {options.min_num_matches} verified feature matches (too little texture, or the "
            "views do not overlap)"
        )

    say("incremental mapping")
    mapper = pycolmap.IncrementalPipelineOptions()
    mapper.num_threads = options.num_threads
    mapper.random_seed = options.seed
    mapper.min_num_matches = options.min_num_matches
    mapper.ba_refine_principal_point = False
    mapper.mapper.abs_pose_min_num_inliers = options.min_pose_inliers
    models = pycolmap.incremental_mapping(database, image_dir, work_dir / "sparse", mapper)
    if not models:
        raise CalibrationError(
            "mapping failed: no initial image pair could be reconstructed (too few matches "
            "with enough parallax)"
        )
    ranked = sorted(models.values(), key=lambda r: r.num_reg_images(), reverse=True)
    rec = ranked[0]

    say("joint bundle adjustment of poses, points and intrinsics")
    ba = pycolmap.BundleAdjustmentOptions()
    ba.print_summary = False
    ba.refine_focal_length = True
    ba.refine_extra_params = True
    ba.refine_principal_point = options.refine_principal_point
    if logger.getEffectiveLevel() > logging.DEBUG:
        pycolmap.logging.minloglevel = 2
    pycolmap.bundle_adjustment(rec, ba)
    cal = _calibration_from_reconstruction(rec, camera_names, counts, options)
    # Degenerate cameras (e.g. a focal length collapsed in the bundle adjustment) are taken out
    # of the model, and the others adjusted again without them, until none is left. Then, once,
    # the rejected and unregistered cameras are retried with the median focal length.
    rejected: dict[str, str] = {}
    retried = not options.retry_failed
    while True:
        bad = find_degenerate_cameras(cal, options)
        if bad:
            rejected.update(bad)
            if len(cal.rig) - len(bad) < 2:
                raise CalibrationError(
                    f"only {len(cal.rig) - len(bad)} camera(s) registered with a plausible "
                    "calibration; need at least 2 "
                    f"({'; '.join(f'{k}: {v}' for k, v in bad.items())})"
                )
            say(f"rejecting degenerate camera(s) {', '.join(bad)} and adjusting again")
            for image_id in list(rec.reg_image_ids()):
                im = rec.images[image_id]
                if im.name.split("/")[0] in bad:
                    rec.deregister_frame(im.frame_id)
            pycolmap.bundle_adjustment(rec, ba)
            cal = _calibration_from_reconstruction(rec, camera_names, counts, options)
            continue
        missing = [n for n in camera_names if n not in cal.rig.names and per_camera[n]]
        if retried or not missing:
            break
        retried = True
        say(f"retrying camera(s) {', '.join(missing)} with the median focal length")
        rec = _retry_registration(rec, cal, missing, database, image_dir, work_dir, mapper)
        pycolmap.bundle_adjustment(rec, ba)
        cal = _calibration_from_reconstruction(rec, camera_names, counts, options)
        for name in cal.rig.names:
            if rejected.pop(name, None) is not None:
                logger.info("camera %s registered on retry", name)
    rec.write(str(_fresh_dir(work_dir / "model")))
    registered_elsewhere = {
        image_camera[i]
        for other in ranked[1:]
        for i in other.reg_image_ids()
        if image_camera.get(i) is not None
    }
    for ci in registered_elsewhere:
        name = camera_names[ci]
        if name in cal.failed:
            cal.failed[name] = (
                "in a separate, smaller model (no overlap with the main one: "
                f"{_best_matches(counts, ci, cal)} verified matches with registered cameras)"
            )
    for name in camera_names:
        if name not in cal.failed or "separate" in cal.failed[name]:
            continue
        ci = cam_index[name]
        ids = [i for i, c in image_camera.items() if c == ci]
        if not per_camera[name]:
            cal.failed[name] = "missing images (empty folder)"
        elif sum(keypoints.get(i, 0) for i in ids) == 0:
            cal.failed[name] = "no features detected (blank or unreadable images)"
        else:
            n = _best_matches(counts, ci, cal)
            if n < options.min_num_matches:
                cal.failed[name] = (
                    f"too few matches: {n} verified matches with registered cameras "
                    f"(need {options.min_num_matches})"
                )
            else:
                cal.failed[name] = (
                    f"not in the model: {n} verified matches with registered cameras, but "
                    "registration (absolute pose) failed"
                )
    cal.failed.update(rejected)
    for name, why in cal.failed.items():
        logger.warning("camera %s not calibrated: %s", name, why)
    if len(cal.rig) < 2:
        raise CalibrationError(
            f"only {len(cal.rig)} camera(s) registered; need at least 2 "
            f"({'; '.join(f'{k}: {v}' for k, v in cal.failed.items())})"
        )
    return cal


def find_degenerate_cameras(
    cal: Calibration, options: CalibrationOptions | None = None
) -> dict[str, str]:
    """Registered cameras whose calibration is implausible, with the reason.

    A camera is degenerate when its focal length is outside
    ``[min_focal_ratio, max_focal_ratio]`` times its image's longer side, when a distortion
    coefficient exceeds ``max_distortion``, when its mean reprojection error is not finite or
    exceeds both ``outlier_error_ratio`` times the median over the registered cameras and
    ``outlier_error_px``, or when it has fewer than ``min_observation_ratio`` times the median
    number of observations.

    Parameters
    ----------
    cal : Calibration
    options : CalibrationOptions, optional
        Thresholds (defaults if omitted).

    Returns
    -------
    dict of str to str
        Camera name -> reason, in rig order; empty when every camera is plausible.
    """
    options = options or CalibrationOptions()
    rig = cal.rig
    if len(rig) == 0:
        return {}
    longer = np.max(np.asarray(rig.sizes, float), axis=1)  # (C,)
    focal = (rig.K[:, 0, 0] + rig.K[:, 1, 1]) / 2  # (C,)
    ratio = focal / longer
    coef = np.abs(rig.dist[:, :5]).max(axis=1)  # (C,) k1 k2 p1 p2 k3
    errors = np.array([cal.errors.get(n, np.nan) for n in rig.names])  # (C,)
    nobs = np.array([cal.observations.get(n, 0) for n in rig.names], float)  # (C,)
    med_err = float(np.median(errors[np.isfinite(errors)])) if np.isfinite(errors).any() else 0.0
    med_obs = float(np.median(nobs))
    out: dict[str, str] = {}
    for c, name in enumerate(rig.names):
        why = []
        if not options.min_focal_ratio <= ratio[c] <= options.max_focal_ratio:
            why.append(
                f"focal length {focal[c]:.4g} px is {ratio[c]:.3g} x the image's longer side "
                f"{longer[c]:.0f} px (plausible: {options.min_focal_ratio:g} to "
                f"{options.max_focal_ratio:g})"
            )
        if coef[c] > options.max_distortion:
            why.append(
                f"distortion coefficient of magnitude {coef[c]:.3g} "
                f"(plausible: <= {options.max_distortion:g})"
            )
        if not np.isfinite(errors[c]):
            why.append("no reprojection error (no observations)")
        elif (
            errors[c] > options.outlier_error_ratio * med_err
            and errors[c] > options.outlier_error_px
        ):
            why.append(
                f"mean reprojection error {errors[c]:.3g} px is > {options.outlier_error_ratio:g}"
                f" x the median {med_err:.3g} px"
            )
        if nobs[c] < options.min_observation_ratio * med_obs:
            why.append(
                f"{int(nobs[c])} observations, < {options.min_observation_ratio:g} x the median "
                f"{med_obs:.0f}"
            )
        if why:
            out[name] = "degenerate: " + "; ".join(why)
    return out


def _retry_registration(
    rec,
    cal: Calibration,
    names: Sequence[str],
    database: Path,
    image_dir: Path,
    work_dir: Path,
    mapper,
):
    """Continue incremental mapping from ``rec`` after giving the cameras ``names`` the median
    focal length of the calibrated ones as a prior (principal point at the image centre, no
    distortion). Returns the model with the most registered images (``rec`` if none has more).
    """
    import pycolmap

    ratio = float(
        np.median((cal.rig.K[:, 0, 0] + cal.rig.K[:, 1, 1]) / 2 / cal.rig.sizes.max(axis=1))
    )
    db = pycolmap.Database.open(str(database))
    try:
        camera_of = {im.name.split("/")[0]: im.camera_id for im in db.read_all_images()}
        for name in names:
            cam = db.read_camera(camera_of[name])
            params = np.zeros(len(cam.params))
            params[cam.focal_length_idxs()] = ratio * max(cam.width, cam.height)
            params[cam.principal_point_idxs()] = [cam.width / 2, cam.height / 2]
            cam.params = params
            cam.has_prior_focal_length = True
            db.update_camera(cam)
            if cam.camera_id in rec.cameras:
                rec.cameras[cam.camera_id] = cam
    finally:
        db.close()
    start = _fresh_dir(work_dir / "retry_input")
    rec.write(str(start))
    if logger.getEffectiveLevel() > logging.DEBUG:
        pycolmap.logging.minloglevel = 2  # errors only from glog
    models = pycolmap.incremental_mapping(
        database, image_dir, _fresh_dir(work_dir / "retry"), mapper, input_path=start
    )
    best = max(models.values(), key=lambda r: r.num_reg_images(), default=None)
    if best is None or best.num_reg_images() <= rec.num_reg_images():
        logger.info("retry registered no further camera")
        return rec
    return best


def _best_matches(counts: np.ndarray, ci: int, cal: Calibration) -> int:
    """Verified matches of camera ``ci`` with the registered cameras."""
    reg = [cal.camera_names.index(n) for n in cal.rig.names]
    return int(counts[ci, reg].sum()) if reg else 0


def _fresh_dir(path: Path) -> Path:
    import shutil

    if path.exists():
        shutil.rmtree(path)
    path.mkdir(parents=True)
    return path


def _calibration_from_reconstruction(
    rec, camera_names: list[str], counts: np.ndarray, options: CalibrationOptions
) -> Calibration:
    """Convert a pycolmap reconstruction (image names ``<camera>/<frame>``) to a Calibration."""
    poses: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {}
    obs_xy: dict[str, list[np.ndarray]] = {}
    obs_xyz: dict[str, list[np.ndarray]] = {}
    intrinsics: dict[str, tuple[np.ndarray, np.ndarray, tuple[int, int]]] = {}
    point_ids = np.asarray(sorted(rec.point3D_ids()), np.int64)
    xyz_all = (
        np.stack([rec.points3D[int(i)].xyz for i in point_ids])
        if len(point_ids)
        else np.zeros((0, 3))
    )
    row_of = {int(pid): r for r, pid in enumerate(point_ids)}
    for image_id in rec.reg_image_ids():
        im = rec.images[image_id]
        name = im.name.split("/")[0]
        cam = rec.cameras[im.camera_id]
        K, dist = _opencv_from_colmap(cam.model.name, cam.params)
        intrinsics[name] = (K, dist, (int(cam.width), int(cam.height)))
        cfw = im.cam_from_world() if callable(im.cam_from_world) else im.cam_from_world
        poses.setdefault(name, []).append(
            (np.asarray(cfw.rotation.matrix()), np.asarray(cfw.translation))
        )
        pts = [(p.xy, row_of[int(p.point3D_id)]) for p in im.points2D if p.has_point3D()]
        if pts:
            obs_xy.setdefault(name, []).append(np.array([p[0] for p in pts]) - 0.5)
            obs_xyz.setdefault(name, []).append(xyz_all[[p[1] for p in pts]])
    cams, spread = [], {}
    for name in camera_names:
        if name not in poses:
            continue
        K, dist, size = intrinsics[name]
        Rs = np.stack([p[0] for p in poses[name]])  # (F, 3, 3)
        Cs = np.stack([-p[0].T @ p[1] for p in poses[name]])  # (F, 3)
        R = _mean_rotation(Rs)
        spread[name] = float(_rotation_angle_deg(Rs, R[None]).max() * 2) if len(Rs) > 1 else 0.0
        cams.append(Camera(name, K, R, Cs.mean(axis=0), size=size, dist=dist))
    rig = CameraRig(cams) if cams else CameraRig([])
    errors, nobs = {}, {}
    for c, cam in enumerate(rig):
        xy = np.concatenate(obs_xy.get(cam.name, [np.zeros((0, 2))]))
        X = np.concatenate(obs_xyz.get(cam.name, [np.zeros((0, 3))]))
        nobs[cam.name] = len(xy)
        if len(xy):
            err = rig.subset([c]).reprojection_errors(X, xy[None])[0]
            errors[cam.name] = float(np.nanmean(err))
        else:
            errors[cam.name] = float("nan")
    failed = {n: "not in the model" for n in camera_names if n not in poses}
    return Calibration(
        rig=rig,
        camera_names=camera_names,
        errors=errors,
        observations=nobs,
        failed=failed,
        match_counts=counts,
        pose_spread_deg=spread,
        num_points=len(point_ids),
    )


# --------------------------------------------------------------------------------------------
# ChArUco


@dataclass(frozen=True)
class CharucoBoard:
    """A ChArUco board in caliscope's ``charuco.toml`` layout.

    Attributes
    ----------
    columns, rows : int
        Squares across and down.
    square_m : float
        Square side in metres.
    marker_m : float
        ArUco marker side in metres.
    dictionary : str
        OpenCV predefined dictionary name, e.g. ``DICT_4X4_1000``.
    inverted : bool
        Printed white-on-black: images are inverted before detection.
    """

    columns: int
    rows: int
    square_m: float
    marker_m: float
    dictionary: str = "DICT_4X4_50"
    inverted: bool = False

    @classmethod
    def from_toml(cls, path: str | os.PathLike) -> CharucoBoard:
        """Read caliscope's ``charuco.toml`` (columns, rows, board_width/height and units or
        ``square_size_override_cm``, aruco_scale, dictionary, inverted)."""
        path = Path(path)
        try:
            data = tomllib.loads(path.read_text())
        except FileNotFoundError:
            raise FileFormatError(path, "no such file") from None
        except tomllib.TOMLDecodeError as exc:
            raise FileFormatError(path, f"not valid TOML: {exc}") from None
        for key in ("columns", "rows", "dictionary"):
            if key not in data:
                raise FileFormatError(path, f"missing field {key!r}")
        columns, rows = int(data["columns"]), int(data["rows"])
        if columns < 2 or rows < 2:
            raise FileFormatError(path, f"columns and rows must be >= 2, got {columns}x{rows}")
        if data.get("square_size_override_cm"):
            square = float(data["square_size_override_cm"]) / 100
        elif "board_width" in data:
            unit = {"inch": 0.0254, "cm": 0.01, "mm": 0.001, "m": 1.0}.get(
                str(data.get("units", "inch"))
            )
            if unit is None:
                raise FileFormatError(path, f"unknown units {data.get('units')!r}")
            square = (
                min(float(data["board_width"]) / columns, float(data["board_height"]) / rows) * unit
            )
        else:
            raise FileFormatError(path, "missing square_size_override_cm or board_width")
        import cv2

        if not hasattr(cv2.aruco, str(data["dictionary"])):
            raise FileFormatError(path, f"unknown ArUco dictionary {data['dictionary']!r}")
        scale = float(data.get("aruco_scale", 0.75))
        return cls(
            columns,
            rows,
            square,
            square * scale,
            str(data["dictionary"]),
            bool(data.get("inverted", False)),
        )

    def cv_board(self):
        """The ``cv2.aruco.CharucoBoard``."""
        import cv2

        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        return cv2.aruco.CharucoBoard(
            (self.columns, self.rows), self.square_m, self.marker_m, dictionary
        )

    def corners(self) -> np.ndarray:
        """(N, 3) float ndarray: inner chessboard corners in the board frame (metres, z = 0),
        indexed by ChArUco corner id."""
        return np.asarray(self.cv_board().getChessboardCorners(), float).reshape(-1, 3)


def detect_charuco(image: np.ndarray, board: CharucoBoard) -> tuple[np.ndarray, np.ndarray]:
    """Detect ChArUco corners.

    Parameters
    ----------
    image : (H, W, 3) uint8 ndarray
        RGB image (or (H, W) grey).
    board : CharucoBoard

    Returns
    -------
    ids : (n,) int ndarray
        Corner ids (rows of :meth:`CharucoBoard.corners`).
    corners : (n, 2) float ndarray
        Sub-pixel corner positions (OpenCV pixels).
    """
    import cv2

    img = np.asarray(image)
    grey = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY) if img.ndim == 3 else img
    if board.inverted:
        grey = 255 - grey
    detector = cv2.aruco.CharucoDetector(board.cv_board())
    corners, ids, _, _ = detector.detectBoard(grey)
    if ids is None or len(ids) == 0:
        return np.zeros(0, int), np.zeros((0, 2))
    return ids.ravel().astype(int), corners.reshape(-1, 2).astype(float)


Detections = Mapping[tuple[int, int], tuple[np.ndarray, np.ndarray]]


def _observations(
    detections: Detections, num_cameras: int, num_corners: int
) -> tuple[np.ndarray, list[int]]:
    """(C, F * n, 2) pixel array (NaN where unseen) and the frame of each block of n rows."""
    frames = sorted({f for _, f in detections})
    fi = {f: i for i, f in enumerate(frames)}
    obs = np.full((num_cameras, len(frames) * num_corners, 2), np.nan)
    for (c, f), (ids, xy) in detections.items():
        if len(ids):
            obs[c, fi[f] * num_corners + np.asarray(ids)] = xy
    return obs, frames


def align_rig_to_charuco(
    rig: CameraRig, detections: Detections, board: CharucoBoard, min_corners: int = 6
) -> tuple[CameraRig, dict[str, float]]:
    """Give a rig metric scale and the board's frame from ChArUco detections.

    Corners seen by >= 2 cameras are triangulated frame by frame; each frame's triangulated
    board is fitted to the board's geometry by a similarity. The scale is the median over
    frames; the world frame is the board (x along columns, y along rows, z out of the board)
    in the frame with the most triangulated corners.

    Parameters
    ----------
    rig : CameraRig
    detections : mapping (camera index, frame) -> (ids (n,), corners (n, 2))
    board : CharucoBoard
    min_corners : int
        Triangulated corners for a frame to be used.

    Returns
    -------
    rig : CameraRig
    stats : dict
        ``frames`` used, ``reference_frame`` (the frame whose board defines the world),
        ``board_rms_mm`` (RMS distance of triangulated corners to the fitted
        board, metric), ``scale_spread`` (relative MAD of the per-frame scales).

    Raises
    ------
    CalibrationError
        If no frame has ``min_corners`` corners seen by two cameras.
    """
    from .reconstruct.triangulate import triangulate_points

    ref_pts = board.corners()
    n = len(ref_pts)
    obs, frames = _observations(detections, len(rig), n)
    X = triangulate_points(rig, obs).reshape(len(frames), n, 3)
    fits = []
    for k in range(len(frames)):
        ok = np.all(np.isfinite(X[k]), axis=1)
        if ok.sum() < min_corners:
            continue
        try:
            s, R, t = umeyama(ref_pts[ok], X[k][ok])
        except ValidationError:
            continue
        fits.append((int(ok.sum()), k, s, R, t))
    if not fits:
        raise CalibrationError(
            f"ChArUco: no frame has {min_corners} corners detected in two registered cameras"
        )
    scales = np.array([f[2] for f in fits])
    s_med = float(np.median(scales))
    _, k_ref, _, R_ref, t_ref = max(fits, key=lambda f: f[0])
    # Board frame of the reference frame: X_board = R_ref^T (X - t_ref) / s_med.
    aligned = transform_rig(rig, 1.0 / s_med, R_ref.T, -R_ref.T @ t_ref / s_med)
    resid = []
    for _, k, s, R, t in fits:
        ok = np.all(np.isfinite(X[k]), axis=1)
        fitted = (s * ref_pts[ok] @ R.T + t) / s_med
        resid.append(np.linalg.norm(X[k][ok] / s_med - fitted, axis=1))
    r = np.concatenate(resid)
    stats = {
        "frames": float(len(fits)),
        "reference_frame": float(frames[k_ref]),
        "board_rms_mm": float(1e3 * np.sqrt(np.mean(r**2))),
        "scale_spread": float(np.median(np.abs(scales - s_med)) / s_med),
    }
    logger.info("ChArUco alignment: %s", stats)
    return aligned, stats


def calibrate_charuco(
    detections: Detections,
    board: CharucoBoard,
    camera_names: Sequence[str],
    sizes: Sequence[tuple[int, int]],
    min_corners: int = 6,
    lens: str = "simple",
    min_k2_coverage: float = 0.5,
) -> tuple[Calibration, dict[str, float]]:
    """Calibrate a rig from ChArUco corners alone (when feature-based SfM cannot register).

    1. Per camera, OpenCV's planar calibration (``cv2.calibrateCamera``) on its board views
       gives K and distortion (k1 k2 p1 p2 k3) and a board pose per view.
    2. Camera poses: camera 0 is the reference; every other camera's pose relative to a camera
       already placed is the chordal mean over the frames both see the board in.
    3. Joint bundle adjustment (``scipy.optimize.least_squares``, Huber loss, sparse Jacobian)
       of all intrinsics, camera poses and one board pose per frame, with the board's known
       metric geometry, minimising corner reprojection errors.

    The world frame is the board in the frame where most cameras see it.

    Higher-order radial terms are only constrained where the board was seen: for a camera whose
    board corners stay within ``min_k2_coverage`` of the half-diagonal from the image centre,
    k2 (and k3) are held at 0. Otherwise k2 is fitted to the central part of the image and
    extrapolates wildly towards the corners (caliscope's cam_3, corners within 0.33 of the
    half-diagonal: k2 = +2.78, 761 px RMS distortion difference from caliscope's calibration
    over the image; 82 px with k1 alone).

    Parameters
    ----------
    detections : mapping (camera index, frame) -> (ids (n,), corners (n, 2))
    board : CharucoBoard
    camera_names : sequence of str
    sizes : sequence of (w, h)
    min_corners : int
        Corners for a view to be used.
    lens : {"simple", "full"}
        ``full``: fx fy cx cy k1 k2 p1 p2 k3 per camera. ``simple``: fx fy k1 k2, with the
        principal point at the image centre and p1 = p2 = k3 = 0; far better conditioned when
        the board covers little of each image.
    min_k2_coverage : float
        Board coverage (largest distance of a detected corner from the image centre, over the
        half-diagonal) below which k2 and k3 are held at 0; 0 fits them for every camera.

    Returns
    -------
    calibration : Calibration
        Its notes name the cameras calibrated with k1 alone.
    stats : dict
        ``views`` used, ``rms_px`` after the adjustment, ``rms_px_initial``, and
        ``coverage_<camera>`` per calibrated camera.
    """
    import cv2
    from scipy.optimize import least_squares

    if lens not in ("simple", "full"):
        raise ValidationError(f"lens: expected 'simple' or 'full', got {lens!r}")
    ref = board.corners().astype(np.float32)
    C = len(camera_names)
    views = {
        (c, f): (np.asarray(ids), np.asarray(xy))
        for (c, f), (ids, xy) in detections.items()
        if len(ids) >= min_corners
    }
    K0, d0, board_pose = [], [], {}
    failed: dict[str, str] = {}
    coverage: dict[int, float] = {}
    k1_only: list[int] = []
    for c in range(C):
        keys = sorted(k for k in views if k[0] == c)
        if len(keys) < 3:
            failed[camera_names[c]] = (
                f"board seen with >= {min_corners} corners in {len(keys)} frames"
            )
            K0.append(None)
            d0.append(None)
            continue
        objp = [ref[views[k][0]] for k in keys]
        imgp = [views[k][1].astype(np.float32) for k in keys]
        w, h = sizes[c]
        K_init = np.array([[w, 0.0, (w - 1) / 2], [0.0, w, (h - 1) / 2], [0.0, 0.0, 1.0]])
        flags = cv2.CALIB_USE_INTRINSIC_GUESS
        if lens == "simple":
            flags |= cv2.CALIB_FIX_PRINCIPAL_POINT | cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K3
        reach = np.linalg.norm(np.concatenate(imgp) - K_init[:2, 2], axis=1)  # (n,)
        coverage[c] = float(reach.max() / np.hypot(w / 2, h / 2))
        if coverage[c] < min_k2_coverage:
            flags |= cv2.CALIB_FIX_K2 | cv2.CALIB_FIX_K3
            k1_only.append(c)
        _, K, d, rvecs, tvecs = cv2.calibrateCamera(
            objp, imgp, (int(w), int(h)), K_init, np.zeros(5), flags=flags
        )
        K0.append(K)
        d0.append(d.ravel()[:5])
        for k, rv, tv in zip(keys, rvecs, tvecs, strict=True):
            board_pose[k] = (rotation_from_rodrigues(rv.ravel()), tv.ravel())
    ok_cams = [c for c in range(C) if K0[c] is not None]
    if len(ok_cams) < 2:
        raise CalibrationError(
            f"ChArUco: only {len(ok_cams)} camera(s) saw the board often enough; need 2"
        )
    # Relative poses: x_c = R_c X + t_c (world = camera ok_cams[0]).
    cam_pose = {ok_cams[0]: (np.eye(3), np.zeros(3))}
    frames_of = {c: {f for (cc, f) in board_pose if cc == c} for c in ok_cams}
    while len(cam_pose) < len(ok_cams):
        best = None
        for c in ok_cams:
            if c in cam_pose:
                continue
            for p in cam_pose:
                shared = frames_of[c] & frames_of[p]
                if best is None or len(shared) > len(best[2]):
                    best = (c, p, shared)
        c, p, shared = best
        if not shared:
            for cc in ok_cams:
                if cc not in cam_pose:
                    failed[camera_names[cc]] = "never sees the board together with a placed camera"
            break
        # cam_c_from_cam_p = board_in_c * board_in_p^-1.
        Rs, ts = [], []
        for f in shared:
            Rc, tc = board_pose[(c, f)]
            Rp, tp = board_pose[(p, f)]
            Rcp = Rc @ Rp.T
            Rs.append(Rcp)
            ts.append(tc - Rcp @ tp)
        Rcp = _mean_rotation(np.stack(Rs))
        tcp = np.median(np.stack(ts), axis=0)
        Rp_w, tp_w = cam_pose[p]
        cam_pose[c] = (Rcp @ Rp_w, Rcp @ tp_w + tcp)
    placed = sorted(cam_pose)
    # Board pose per frame in world from the first placed camera that sees it.
    frames = sorted({f for (c, f) in board_pose if c in cam_pose})
    frame_pose = {}
    for f in frames:
        for c in placed:
            if (c, f) in board_pose:
                Rb, tb = board_pose[(c, f)]
                Rc, tc = cam_pose[c]
                frame_pose[f] = (Rc.T @ Rb, Rc.T @ (tb - tc))
                break
    obs = [(c, f, views[(c, f)]) for (c, f) in sorted(views) if c in cam_pose and f in frame_pose]
    cam_i = np.concatenate([np.full(len(v[0]), placed.index(c)) for c, f, v in obs])
    fr_i = np.concatenate([np.full(len(v[0]), frames.index(f)) for c, f, v in obs])
    pts = np.concatenate([ref[v[0]] for c, f, v in obs]).astype(float)  # (P, 3)
    uv = np.concatenate([v[1] for c, f, v in obs])  # (P, 2)
    NC, NF = len(placed), len(frames)
    n_int = 9  # fx fy cx cy k1 k2 p1 p2 k3

    def pack() -> np.ndarray:
        x = []
        for c in placed:
            K, d = K0[c], d0[c]
            x += [K[0, 0], K[1, 1], K[0, 2], K[1, 2], *d]
            R, t = cam_pose[c]
            x += [*rodrigues_from_rotation(R), *t]
        for f in frames:
            R, t = frame_pose[f]
            x += [*rodrigues_from_rotation(R), *t]
        return np.asarray(x, float)

    def unpack(x: np.ndarray):
        cam = x[: NC * (n_int + 6)].reshape(NC, n_int + 6)
        fr = x[NC * (n_int + 6) :].reshape(NF, 6)
        return cam, fr

    def rotate(rvec: np.ndarray, p: np.ndarray) -> np.ndarray:
        """Rodrigues rotation of points p (P, 3) by per-point rvec (P, 3)."""
        th = np.linalg.norm(rvec, axis=1, keepdims=True)
        k = rvec / np.where(th > 1e-12, th, 1.0)
        cos, sin = np.cos(th), np.sin(th)
        return p * cos + np.cross(k, p) * sin + k * np.sum(k * p, axis=1, keepdims=True) * (1 - cos)

    def residuals(x: np.ndarray) -> np.ndarray:
        cam, fr = unpack(x)
        Xw = rotate(fr[fr_i, :3], pts) + fr[fr_i, 3:]  # (P, 3)
        cp = cam[cam_i]
        Xc = rotate(cp[:, n_int : n_int + 3], Xw) + cp[:, n_int + 3 :]
        xn = Xc[:, :2] / Xc[:, 2:3]
        k1, k2, p1, p2, k3 = (cp[:, 4 + i] for i in range(5))
        x_, y_ = xn[:, 0], xn[:, 1]
        r2 = x_**2 + y_**2
        radial = 1 + k1 * r2 + k2 * r2**2 + k3 * r2**3
        xd = x_ * radial + 2 * p1 * x_ * y_ + p2 * (r2 + 2 * x_**2)
        yd = y_ * radial + p1 * (r2 + 2 * y_**2) + 2 * p2 * x_ * y_
        u = cp[:, 0] * xd + cp[:, 2]
        v = cp[:, 1] * yd + cp[:, 3]
        return np.concatenate([u - uv[:, 0], v - uv[:, 1]])

    P = len(pts)
    x0 = pack()
    free = np.ones_like(x0, bool)
    if lens == "simple":
        for i in range(NC):  # cx cy p1 p2 k3 stay at their initial values
            free[i * (n_int + 6) + np.array([2, 3, 6, 7, 8])] = False
    for i in range(NC):
        if placed[i] in k1_only:  # k2 k3 stay at 0
            free[i * (n_int + 6) + np.array([5, 8])] = False

    def residuals_free(z: np.ndarray) -> np.ndarray:
        x = x0.copy()
        x[free] = z
        return residuals(x)

    r0 = residuals(x0)
    scale = np.concatenate([np.tile(_CAMERA_SCALE, NC), np.full(NF * 6, 0.01)])
    # Levenberg-Marquardt with a dense finite-difference Jacobian: a few hundred parameters.
    sol = least_squares(residuals_free, x0[free], x_scale=scale[free], method="lm")
    x_opt = x0.copy()
    x_opt[free] = sol.x
    cam, fr = unpack(x_opt)
    res = sol.fun.reshape(2, P)
    err = np.hypot(res[0], res[1])
    # World frame: the board in the frame seen by the most cameras.
    seen = np.bincount(fr_i, minlength=NF)
    f_ref = int(np.argmax(seen))
    Rb = rotation_from_rodrigues(fr[f_ref, :3])
    tb = fr[f_ref, 3:]
    cams, errors, nobs = [], {}, {}
    for i, c in enumerate(placed):
        K = np.array([[cam[i, 0], 0, cam[i, 2]], [0, cam[i, 1], cam[i, 3]], [0, 0, 1.0]])
        R = rotation_from_rodrigues(cam[i, n_int : n_int + 3])
        t = cam[i, n_int + 3 :]
        # x = R (Rb Xb + tb) + t = (R Rb) Xb + (R tb + t).
        name = camera_names[c]
        cams.append(
            Camera.from_extrinsics(name, K, R @ Rb, R @ tb + t, tuple(sizes[c]), cam[i, 4:9])
        )
        errors[name] = float(err[cam_i == i].mean())
        nobs[name] = int((cam_i == i).sum())
    stats = {
        "views": float(len(obs)),
        "rms_px_initial": float(np.sqrt(np.mean(r0**2) * 2)),
        "rms_px": float(np.sqrt(np.mean(err**2))),
        **{f"coverage_{camera_names[c]}": v for c, v in coverage.items()},
    }
    cal = Calibration(
        rig=CameraRig(cams),
        camera_names=list(camera_names),
        errors=errors,
        observations=nobs,
        failed={n: failed.get(n, "not placed") for n in camera_names if n not in errors},
        match_counts=_shared_corner_counts(views, C),
        num_points=int(P),
        notes=[
            f"ChArUco calibration: {len(obs)} board views, world = board in frame {frames[f_ref]}"
        ],
    )
    if k1_only:
        cal.notes.append(
            "radial distortion k1 only (board corners within "
            f"{min_k2_coverage:g} of the half-diagonal): "
            + ", ".join(f"{camera_names[c]} ({coverage[c]:.2f})" for c in k1_only)
        )
    return cal, stats


#: Typical magnitudes of fx fy cx cy k1 k2 p1 p2 k3 rvec(3) t(3) (least-squares x_scale).
_CAMERA_SCALE = np.array([10, 10, 10, 10, 0.05, 0.05, 0.005, 0.005, 0.05] + [0.01] * 6)


def _shared_corner_counts(views: Detections, C: int) -> np.ndarray:
    """Corners seen by both cameras of each pair (summed over frames)."""
    counts = np.zeros((C, C), np.int64)
    by_frame: dict[int, dict[int, set]] = {}
    for (c, f), (ids, _) in views.items():
        by_frame.setdefault(f, {})[c] = set(np.asarray(ids).tolist())
    for cams in by_frame.values():
        for a in cams:
            for b in cams:
                if a != b:
                    counts[a, b] += len(cams[a] & cams[b])
    return counts


# --------------------------------------------------------------------------------------------
# Figures


def plot_match_graph(
    rig: CameraRig,
    match_counts: np.ndarray,
    path: str | os.PathLike,
    names: Sequence[str] | None = None,
    geometric_edges: Sequence[tuple[int, int]] | None = None,
    min_matches: int = 15,
) -> None:
    """Top view of the rig with camera pairs joined by their verified match counts.

    Parameters
    ----------
    rig : CameraRig
    match_counts : (N, N) int ndarray
        Over ``names`` (default ``rig.names``).
    path : path-like
        PNG written atomically.
    names : sequence of str, optional
        Camera names indexing ``match_counts``.
    geometric_edges : sequence of (i, j), optional
        Edges of the geometric connectivity graph (indices into ``rig``), drawn dashed grey.
    min_matches : int
        Pairs with fewer matches are not drawn.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .atomic import atomic_path

    names = list(names) if names is not None else rig.names
    counts = check_array("match_counts", match_counts, (len(names), len(names)))
    pos = {n: rig.C[rig.index(n), :2] for n in rig.names}
    fig, ax = plt.subplots(figsize=(6.5, 6))
    if geometric_edges is not None:
        for i, j in geometric_edges:
            a, b = rig.C[i, :2], rig.C[j, :2]
            ax.plot([a[0], b[0]], [a[1], b[1]], "--", color="0.75", lw=0.8, zorder=1)
    vmax = max(int(counts.max()), 1)
    cmap = plt.get_cmap("viridis")
    for i in range(len(names)):
        for j in range(i + 1, len(names)):
            n = int(counts[i, j])
            if n < min_matches or names[i] not in pos or names[j] not in pos:
                continue
            a, b = pos[names[i]], pos[names[j]]
            ax.plot([a[0], b[0]], [a[1], b[1]], color=cmap(n / vmax), lw=0.5 + 2.5 * n / vmax)
    xy = rig.C[:, :2]
    ax.plot(xy[:, 0], xy[:, 1], "r^", ms=6, zorder=3)
    for n, p in pos.items():
        ax.annotate(n, p, fontsize=7, xytext=(3, 3), textcoords="offset points")
    sm = plt.cm.ScalarMappable(cmap=cmap, norm=plt.Normalize(0, vmax))
    fig.colorbar(sm, ax=ax, label="verified inlier matches")
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title("camera pairs by verified matches (dashed: geometric graph)")
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)
