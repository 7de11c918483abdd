"""Similarities between world frames: Umeyama's fit, robust rig alignment, rig comparison.

SfM fixes a rig only up to a similarity. :func:`align_rig_to` moves a rig into an existing rig's
world frame with Umeyama's similarity between camera centres (:func:`estimate_rig_similarity`:
after a least-median-of-squares search that leaves out cameras whose centres disagree with the
others'); :func:`scale_rig_by_distance` sets the scale from one known distance;
:func:`compare_rigs` measures an estimated rig against a reference camera by camera.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from ..camera import Camera, CameraRig
from ..errors import ValidationError, check_array
from ..geometry import distort_normalized, fit_rigid, mean_rotation, rotation_angle_deg

__all__ = [
    "RigAlignment",
    "RigComparison",
    "align_rig_to",
    "compare_rigs",
    "estimate_rig_similarity",
    "scale_rig_by_distance",
    "transform_rig",
    "umeyama",
]

logger = logging.getLogger(__name__)


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
    s, R, t, ok = fit_rigid(src[None], dst[None], with_scale=with_scale)
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
    with_scale, robust : bool
        As in :func:`estimate_rig_similarity`.

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
    s, R, t, ok = fit_rigid(src[triplets], dst[triplets], with_scale=with_scale)
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
    R = mean_rotation(Rs)
    s = 1.0
    if with_scale:
        base_src = np.linalg.norm(src.C[-1] - src.C[0])
        base_dst = np.linalg.norm(dst.C[-1] - dst.C[0])
        if base_src <= 0:
            raise ValidationError("align: the shared cameras have coincident centres")
        s = float(base_dst / base_src)
    t = dst.C.mean(axis=0) - s * R @ src.C.mean(axis=0)
    return s, R, t


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
    rot = rotation_angle_deg(est.R, ref.R)
    centre = np.linalg.norm(est.C - ref.C, axis=1)
    f_est = (est.K[:, 0, 0] + est.K[:, 1, 1]) / 2
    f_ref = (ref.K[:, 0, 0] + ref.K[:, 1, 1]) / 2
    pp = np.linalg.norm(est.K[:, :2, 2] - ref.K[:, :2, 2], axis=1)
    dist_px = np.array([_distortion_difference(a, b) for a, b in zip(est, ref, strict=True)])
    return RigComparison(names, rot, centre, (f_est - f_ref) / f_ref, pp, dist_px, sim, outliers)


def _distortion_difference(a: Camera, b: Camera, grid: int = 8) -> float:
    """RMS pixel difference of the distortion displacement of two cameras over b's image."""
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
