"""Rig calibration by structure from motion with pycolmap (CPU).

The paper (Section 5, step 1) calibrates each camera's intrinsics (focal length, principal point,
radial distortion), recovers the extrinsics with structure from motion and refines both jointly
in a bundle adjustment. :func:`calibrate_images` does this with pycolmap:

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

The result has SfM's arbitrary similarity frame; :mod:`pointtraj.calibrate.align` and
:func:`~pointtraj.calibrate.charuco.align_rig_to_charuco` give it metric scale and a world frame.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..camera import Camera, CameraRig
from ..errors import PointtrajError, ValidationError
from ..geometry import mean_rotation, rotation_angle_deg
from ._common import Calibration, CalibrationError

__all__ = [
    "CAMERA_MODELS",
    "CalibrationOptions",
    "calibrate_images",
    "export_frames",
    "find_degenerate_cameras",
]

logger = logging.getLogger(__name__)

#: COLMAP camera models accepted by :class:`CalibrationOptions` (all map onto OpenCV's model).
CAMERA_MODELS = ("OPENCV", "FULL_OPENCV", "RADIAL", "SIMPLE_RADIAL", "PINHOLE", "SIMPLE_PINHOLE")
#: Image suffixes read from an image folder.
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png")

Stage = Callable[[str], None]


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
        R = mean_rotation(Rs)
        spread[name] = float(rotation_angle_deg(Rs, R[None]).max() * 2) if len(Rs) > 1 else 0.0
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
