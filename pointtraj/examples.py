"""Real example captures, laid out as pointtraj capture folders (``pointtraj examples fetch``).

=====================  ========================================================================
name                   what
=====================  ========================================================================
``pose2sim``           Pose2Sim's ``Demo_SinglePerson`` (``pose2sim==0.10.49`` wheel from PyPI,
                       BSD-3-Clause): 4 portrait cameras, 100 frames at 60 fps, a man balancing
                       on a treadmill; Qualisys calibration.
``caliscope-board``    caliscope's ``post_optimization`` test session (BSD-2-Clause), read from
                       ``shared/data/caliscope_board_4cam``: 4 webcams, 57 frames at ~6 fps, a
                       person moving a ChArUco board; caliscope calibration and corner files.
=====================  ========================================================================

Each ``fetch_*`` function writes a capture folder (``data_specs/capture.md``): ``rig.toml``,
``videos/<camera>.mp4``, ``capture.toml``, ``labels.toml`` and a ``README.md`` on its origin,
plus the source files that matter for evaluation (``data_specs/examples.md``).

Two of Pose2Sim's demo videos (``cam01``, ``cam02``) are 1080 px wide while the calibration says
1088: they were rescaled by 1080/1088 and letterboxed with 7 black rows above and below. The
correction is measured from image content (:func:`measure_image_mapping` against the 1088 px
frames Pose2Sim ships in ``calibration/extrinsics``), checked against the candidate models of
:func:`candidate_mappings`, and applied to the intrinsics (:meth:`ImageMapping.apply`); see
``docs/real_captures.md`` for the evidence.
"""

from __future__ import annotations

import csv
import logging
import os
import shutil
import tempfile
import zipfile
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from .atomic import write_text_atomic
from .camera import Camera, CameraRig
from .errors import FileFormatError, PointtrajError, ValidationError
from .fetch import cache_root, fetch_verified_wheel
from .images import read_rgb

__all__ = [
    "EXAMPLES",
    "ExampleSpec",
    "ExampleCapture",
    "ExampleNotFoundError",
    "ImageMapping",
    "SyncReport",
    "candidate_mappings",
    "measure_image_mapping",
    "choose_image_mapping",
    "fetch_example",
    "fetch_pose2sim",
    "fetch_caliscope_board",
    "download_pose2sim_wheel",
    "find_shared_data",
    "caliscope_sync_report",
    "detect_landmarks",
    "landmark_reprojection_errors",
]

logger = logging.getLogger(__name__)

#: Environment variable naming the shared data root (holding ``data/caliscope_board_4cam``).
SHARED_ENV = "POINTTRAJ_SHARED"

POSE2SIM_REQUIREMENT = "pose2sim==0.10.49"
#: SHA-256 of ``pose2sim-0.10.49-py3-none-any.whl`` (the only file of that release on PyPI).
POSE2SIM_SHA256 = "403e0dc4065898ba6a595e72a8970950310979253d60e24c2e00b16b36bf21e1"
POSE2SIM_DEMO = "Pose2Sim/Demo_SinglePerson/"
POSE2SIM_FPS = 60.0
CALISCOPE_FOLDER = "caliscope_board_4cam"

#: Largest disagreement (px, at the image corners) between a measured image mapping and a
#: candidate model for the model to be accepted.
MAPPING_TOLERANCE_PX = 1.5
#: Mean grey level under which an image row counts as a black letterbox bar.
BAR_LEVEL = 12.0
#: Fewest RANSAC inliers for a measured image mapping to be trusted.
MIN_MAPPING_INLIERS = 50

_MARK = "pointtraj examples"


class ExampleNotFoundError(PointtrajError):
    """The source files of an example cannot be found or downloaded."""


@dataclass(frozen=True)
class ExampleSpec:
    """One example capture pointtraj knows how to lay out.

    Attributes
    ----------
    name : str
    description : str
    source : str
        Where the files come from.
    licence : str
        SPDX identifier of the source's licence.
    """

    name: str
    description: str
    source: str
    licence: str


#: Every example capture, by name.
EXAMPLES: dict[str, ExampleSpec] = {
    "pose2sim": ExampleSpec(
        "pose2sim",
        "Pose2Sim Demo_SinglePerson: 4 cameras, 100 frames at 60 fps, 1088x1920 portrait, a man "
        "balancing on a treadmill (Qualisys calibration)",
        f"PyPI wheel {POSE2SIM_REQUIREMENT}, folder {POSE2SIM_DEMO}",
        "BSD-3-Clause",
    ),
    "caliscope-board": ExampleSpec(
        "caliscope-board",
        "caliscope post_optimization session: 4 webcams, 57 frames at ~6 fps, 1280x720, a "
        "person moving a ChArUco board (caliscope calibration, 2D/3D corners)",
        "shared/data/caliscope_board_4cam (github.com/mprib/caliscope @ ddda95b, "
        "tests/sessions/post_optimization)",
        "BSD-2-Clause",
    ),
}


@dataclass(frozen=True)
class ImageMapping:
    """Axis-aligned pixel map from a camera's calibrated image to the frames actually stored.

    ``u' = sx * u + tx`` and ``v' = sy * v + ty`` (OpenCV pixel centres), which turns the
    intrinsics into ``diag-affine @ K`` and leaves the distortion coefficients unchanged.

    Attributes
    ----------
    model : str
        ``"identity"``, ``"letterbox"`` (scaled to the stored width, centred vertically with
        black bars), ``"centre-crop"`` (cropped symmetrically, no scaling) or ``"measured"``.
    sx, sy : float
        Scale factors.
    tx, ty : float
        Shifts in pixels.
    size : (int, int)
        ``(width, height)`` of the stored frames.
    inliers : int
        Feature matches supporting a measurement (0 for a model not measured).
    """

    model: str
    sx: float
    sy: float
    tx: float
    ty: float
    size: tuple[int, int]
    inliers: int = 0

    @property
    def matrix(self) -> np.ndarray:
        """(3, 3) float ndarray: the homogeneous pixel map."""
        return np.array([[self.sx, 0.0, self.tx], [0.0, self.sy, self.ty], [0.0, 0.0, 1.0]])

    def apply(self, camera: Camera) -> Camera:
        """The camera with intrinsics and size of the stored frames.

        Parameters
        ----------
        camera : Camera
            Calibrated for the original image.

        Returns
        -------
        Camera
            ``K' = matrix @ K``, ``size`` of the stored frames; pose and distortion unchanged.

        Examples
        --------
        >>> import numpy as np
        >>> cam = Camera.look_at("c", [3.0, 0, 1], [0, 0, 1], (1088, 1920), 1600.0)
        >>> m = candidate_mappings((1088, 1920), (1080, 1920))["centre-crop"]
        >>> bool(np.isclose(m.apply(cam).K[0, 2], cam.K[0, 2] - 4)), m.apply(cam).size
        (True, (1080, 1920))
        """
        return replace(camera, K=self.matrix @ camera.K, size=tuple(self.size))

    def corner_distance(self, other: ImageMapping, original_size: tuple[int, int]) -> float:
        """Largest distance (px) between where the two maps send the original image's corners."""
        w, h = original_size
        corners = np.array([[0, 0, 1], [w - 1, 0, 1], [0, h - 1, 1], [w - 1, h - 1, 1]], float)
        a = corners @ self.matrix.T  # (4, 3)
        b = corners @ other.matrix.T
        return float(np.max(np.linalg.norm(a[:, :2] - b[:, :2], axis=1)))

    def describe(self) -> str:
        """One line: model, scales and shifts."""
        return (
            f"{self.model}: u' = {self.sx:.5f} u {self.tx:+.2f}, v' = {self.sy:.5f} v "
            f"{self.ty:+.2f} (cx, cy shifted, fx, fy scaled), size {self.size[0]}x{self.size[1]}"
        )


def candidate_mappings(
    original_size: tuple[int, int], stored_size: tuple[int, int]
) -> dict[str, ImageMapping]:
    """The usual ways a video of one size is made from images of another.

    Parameters
    ----------
    original_size : (int, int)
        Calibrated ``(width, height)``.
    stored_size : (int, int)
        ``(width, height)`` of the stored frames.

    Returns
    -------
    dict of str to ImageMapping
        ``"letterbox"`` (uniform scale to the stored width, black bars above and below, or to
        the stored height with bars at the sides) and ``"centre-crop"`` (symmetric crop or pad,
        no scaling).

    Examples
    --------
    >>> m = candidate_mappings((1088, 1920), (1080, 1920))["letterbox"]
    >>> round(m.sx, 5), round(m.ty, 2)
    (0.99265, 7.0)
    """
    (w0, h0), (w1, h1) = original_size, stored_size
    if w0 <= 0 or h0 <= 0 or w1 <= 0 or h1 <= 0:
        raise ValidationError(f"image sizes must be positive, got {original_size}, {stored_size}")
    out = {}
    if w1 / w0 <= h1 / h0:  # fit the width; bars above and below
        sx = w1 / w0
        hs = int(round(h0 * sx))
        sy = hs / h0
        tx, ty = 0.5 * (sx - 1), (h1 - hs) // 2 + 0.5 * (sy - 1)
    else:  # fit the height; bars at the sides
        sy = h1 / h0
        ws = int(round(w0 * sy))
        sx = ws / w0
        tx, ty = (w1 - ws) // 2 + 0.5 * (sx - 1), 0.5 * (sy - 1)
    out["letterbox"] = ImageMapping("letterbox", sx, sy, tx, ty, (w1, h1))
    out["centre-crop"] = ImageMapping(
        "centre-crop", 1.0, 1.0, -((w0 - w1) // 2), -((h0 - h1) // 2), (w1, h1)
    )
    return out


def measure_image_mapping(reference: np.ndarray, image: np.ndarray) -> ImageMapping | None:
    """Measure the scale and shift taking ``reference`` to ``image`` from matched features.

    SIFT features, Lowe's ratio test and a RANSAC similarity fit
    (``cv2.estimateAffinePartial2D``, 1 px threshold). Use images of a static scene taken by
    the same, unmoved camera.

    Parameters
    ----------
    reference : (H0, W0) or (H0, W0, 3) uint8 ndarray
        An image at the calibrated size.
    image : (H1, W1) or (H1, W1, 3) uint8 ndarray
        A stored frame.

    Returns
    -------
    ImageMapping or None
        ``model="measured"``; None with fewer than :data:`MIN_MAPPING_INLIERS` inliers or a
        rotation over 0.2 degrees (the images are not of the same view).
    """
    import cv2

    def gray(img: np.ndarray) -> np.ndarray:
        img = np.asarray(img)
        return cv2.cvtColor(img, cv2.COLOR_RGB2GRAY) if img.ndim == 3 else img

    a, b = gray(reference), gray(image)
    sift = cv2.SIFT_create(4000)
    ka, da = sift.detectAndCompute(a, None)
    kb, db = sift.detectAndCompute(b, None)
    if da is None or db is None or len(ka) < 2 or len(kb) < 2:
        return None
    pairs = cv2.BFMatcher().knnMatch(da, db, k=2)
    good = [p[0] for p in pairs if len(p) == 2 and p[0].distance < 0.7 * p[1].distance]
    if len(good) < MIN_MAPPING_INLIERS:
        return None
    pa = np.float32([ka[m.queryIdx].pt for m in good])
    pb = np.float32([kb[m.trainIdx].pt for m in good])
    A, inl = cv2.estimateAffinePartial2D(
        pa, pb, ransacReprojThreshold=1.0, maxIters=5000, confidence=0.999
    )
    if A is None or int(inl.sum()) < MIN_MAPPING_INLIERS:
        return None
    scale = float(np.hypot(A[0, 0], A[1, 0]))
    angle = float(np.degrees(np.arctan2(A[1, 0], A[0, 0])))
    if abs(angle) > 0.2:
        logger.debug("measured mapping has a rotation of %.3f degrees: rejected", angle)
        return None
    return ImageMapping(
        "measured",
        scale,
        scale,
        float(A[0, 2]),
        float(A[1, 2]),
        (int(b.shape[1]), int(b.shape[0])),
        int(inl.sum()),
    )


def _bar_rows(image: np.ndarray) -> tuple[int, int]:
    """Number of near-black rows at the top and the bottom of an image."""
    rows = np.asarray(image, float).reshape(image.shape[0], -1).mean(axis=1)  # (H,)
    dark = rows < BAR_LEVEL
    top = int(np.argmin(dark)) if not dark.all() else len(dark)
    bottom = int(np.argmin(dark[::-1])) if not dark.all() else len(dark)
    return top, bottom


def choose_image_mapping(
    camera: str,
    original_size: tuple[int, int],
    frame: np.ndarray,
    reference: np.ndarray | None = None,
) -> tuple[ImageMapping, str]:
    """Decide how a camera's stored frames relate to its calibrated image.

    With a ``reference`` image at the calibrated size the mapping is measured
    (:func:`measure_image_mapping`) and the closest candidate of :func:`candidate_mappings`
    within :data:`MAPPING_TOLERANCE_PX` is used (else the measurement itself). Without one,
    black bars of the expected height select ``letterbox``; otherwise ``centre-crop`` is
    assumed (logged as unverified).

    Parameters
    ----------
    camera : str
        For messages.
    original_size : (int, int)
        Calibrated ``(width, height)``.
    frame : (H, W, 3) uint8 ndarray
        A stored frame (RGB).
    reference : (H0, W0, 3) uint8 ndarray, optional
        An image of the same view at the calibrated size.

    Returns
    -------
    mapping : ImageMapping
    evidence : str
        One line on how the mapping was chosen.
    """
    stored = (int(frame.shape[1]), int(frame.shape[0]))
    cands = candidate_mappings(original_size, stored)
    top, bottom = _bar_rows(frame)
    bars = f"black rows at top/bottom: {top}/{bottom}"
    if reference is not None:
        if tuple(reference.shape[1::-1]) != tuple(original_size):
            raise ValidationError(
                f"reference image of camera {camera!r} is {reference.shape[1]}x"
                f"{reference.shape[0]}, not the calibrated {original_size[0]}x{original_size[1]}"
            )
        measured = measure_image_mapping(reference, frame)
        if measured is not None:
            dists = {k: m.corner_distance(measured, original_size) for k, m in cands.items()}
            best = min(dists, key=dists.__getitem__)
            text = (
                f"{measured.describe()} from {measured.inliers} SIFT inliers; corner "
                "distance to "
                + ", ".join(f"{k} {d:.2f} px" for k, d in dists.items())
                + f"; {bars}"
            )
            if dists[best] <= MAPPING_TOLERANCE_PX:
                return replace(cands[best], inliers=measured.inliers), text + f" -> {best}"
            return measured, text + " -> using the measurement"
        logger.warning(
            "camera %s: could not measure the image mapping from the reference image", camera
        )
    lb = cands["letterbox"]
    expected = stored[1] - int(round(original_size[1] * lb.sy))
    if expected > 0 and abs(top + bottom - expected) <= 1:
        return lb, f"{bars}, as the letterbox model expects -> letterbox"
    return (
        cands["centre-crop"],
        f"no reference image, {bars} (no letterbox) -> centre-crop (unverified)",
    )


@dataclass(frozen=True)
class SyncReport:
    """Frame timing of a software-synchronised capture.

    Attributes
    ----------
    frame_counts : dict of str to int
        Frames per camera (from the videos).
    timestamp_counts : dict of str to int
        Timestamps per camera.
    spread : (S,) float ndarray
        Per sync index seen by every camera: latest minus earliest frame time, seconds.
    fps : float
        1 / median frame interval.
    """

    frame_counts: dict[str, int]
    timestamp_counts: dict[str, int]
    spread: np.ndarray
    fps: float

    def describe(self) -> str:
        """A short text summary."""
        s = self.spread * 1000
        return (
            "frames per camera: "
            + ", ".join(f"{k}={v}" for k, v in self.frame_counts.items())
            + "; timestamps per camera: "
            + ", ".join(f"{k}={v}" for k, v in self.timestamp_counts.items())
            + f"; fps {self.fps:.3f}; spread of frame times per sync index over {len(s)} "
            f"indices: median {np.median(s):.1f} ms, 90th percentile "
            f"{np.percentile(s, 90):.1f} ms, max {s.max():.1f} ms"
        )


@dataclass(frozen=True)
class ExampleCapture:
    """What a ``fetch_*`` call wrote.

    Attributes
    ----------
    name : str
        Example name.
    path : pathlib.Path
        The capture folder.
    camera_names : list of str
    num_frames : dict of str to int
        Frames per camera.
    fps : float
    corrections : dict of str to ImageMapping
        Cameras whose calibration was adapted to the stored frames.
    notes : list of str
        Findings worth reporting (also in the capture's README.md).
    """

    name: str
    path: Path
    camera_names: list[str]
    num_frames: dict[str, int]
    fps: float
    corrections: dict[str, ImageMapping] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)


# -- locations ------------------------------------------------------------------------------


def find_shared_data(name: str = CALISCOPE_FOLDER) -> Path | None:
    """``<shared>/data/<name>`` from ``$POINTTRAJ_SHARED``, ``<repo>/../shared`` or
    ``/work/shared``; None if none exists."""
    roots = []
    if os.environ.get(SHARED_ENV):
        roots.append(Path(os.environ[SHARED_ENV]).expanduser())
    roots += [Path(__file__).resolve().parents[1].parent / "shared", Path("/work/shared")]
    for root in roots:
        if (root / "data" / name).is_dir():
            return root / "data" / name
    return None


# -- output folder --------------------------------------------------------------------------


def _start_output(out: Path, overwrite: bool) -> Path:
    """A temporary folder beside ``out`` to build the capture in (checked before any work)."""
    if out.exists():
        if not out.is_dir():
            raise ValidationError(f"out: {out} exists and is not a folder")
        if any(out.iterdir()):
            if not overwrite:
                raise ValidationError(
                    f"out: {out} exists and is not empty; choose a new folder or overwrite it "
                    "(overwrite=True, --force)"
                )
            mark = out / "capture.toml"
            if not (mark.is_file() and _MARK in mark.read_text(errors="replace")):
                raise ValidationError(
                    f"out: {out} is not a capture written by {_MARK}; refusing to overwrite it"
                )
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    umask = os.umask(0)
    os.umask(umask)
    tmp.chmod(0o777 & ~umask)  # mkdtemp makes it private; the capture is an ordinary folder
    return tmp


def _finish_output(tmp: Path, out: Path) -> None:
    """Move the finished capture into place, replacing an old one."""
    old = None
    if out.exists():
        old = Path(tempfile.mkdtemp(prefix=f".{out.name}.old.", dir=out.parent))
        os.replace(out, old / "capture")
    os.replace(tmp, out)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


def _save_capture_toml(path: Path, fps: float, source: str, description: str) -> None:
    """Write an example's ``capture.toml``, marked as written by :data:`_MARK`."""
    from .config import save_toml

    doc = {"fps": float(fps), "source": source, "description": description}
    save_toml(path, doc, comment=f"written by {_MARK}")


def _video_info(path: Path) -> tuple[int, tuple[int, int], float]:
    """Frame count, (width, height) and fps of a video, or a FileFormatError."""
    import cv2

    cap = cv2.VideoCapture(str(path))
    try:
        if not cap.isOpened():
            raise FileFormatError(path, "OpenCV cannot open this video")
        count = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
        size = (int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)))
        fps = float(cap.get(cv2.CAP_PROP_FPS))
    finally:
        cap.release()
    return count, size, fps


def _first_frame(path: Path) -> np.ndarray:
    """(H, W, 3) uint8 RGB first frame of a video."""
    import cv2

    cap = cv2.VideoCapture(str(path))
    try:
        ok, img = cap.read()
    finally:
        cap.release()
    if not ok or img is None:
        raise FileFormatError(path, "cannot decode the first frame")
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


# -- pose2sim -------------------------------------------------------------------------------


def download_pose2sim_wheel(cache: str | os.PathLike | None = None) -> Path:
    """The ``pose2sim==0.10.49`` wheel, from the cache or downloaded with pip.

    Parameters
    ----------
    cache : path-like, optional
        Folder for the wheel (default ``<cache root>/examples``,
        :func:`pointtraj.fetch.cache_root`).

    Returns
    -------
    pathlib.Path
        The wheel file.

    Raises
    ------
    ExampleNotFoundError
        If pip cannot download it (with pip's last lines), or it fails its pinned SHA-256
        (:func:`pointtraj.fetch.fetch_verified_wheel`).
    """
    folder = Path(cache) if cache is not None else cache_root() / "examples"
    return fetch_verified_wheel(
        POSE2SIM_REQUIREMENT,
        folder,
        POSE2SIM_SHA256,
        options=["--timeout", "30", "--retries", "2"],
        error=ExampleNotFoundError,
    )


def _extract(z: zipfile.ZipFile, member: str, dest: Path) -> Path:
    dest.parent.mkdir(parents=True, exist_ok=True)
    with z.open(member) as src, open(dest, "wb") as dst:
        shutil.copyfileobj(src, dst, 1 << 20)
    return dest


def _match_cameras(rig: CameraRig, videos: list[str], calib: Path) -> CameraRig:
    """Rename rig cameras to the video names (by name, else in sorted order as Pose2Sim does)."""
    if sorted(rig.names) == sorted(videos):
        return rig.subset(sorted(videos))
    if len(rig) != len(videos):
        raise FileFormatError(
            calib,
            f"{len(rig)} calibrated cameras ({', '.join(rig.names)}) but {len(videos)} "
            f"videos ({', '.join(videos)})",
        )
    logger.warning(
        "%s: camera names %s differ from the videos %s; matching them in sorted order",
        calib,
        rig.names,
        videos,
    )
    return CameraRig([c.with_name(v) for c, v in zip(rig, sorted(videos))])


def fetch_pose2sim(
    out: str | os.PathLike,
    *,
    wheel: str | os.PathLike | None = None,
    cache: str | os.PathLike | None = None,
    overwrite: bool = False,
) -> ExampleCapture:
    """Lay out Pose2Sim's ``Demo_SinglePerson`` as a pointtraj capture.

    Writes ``rig.toml`` (from ``calibration/Calib.qca.txt``, cameras named like the videos,
    intrinsics adapted to the stored video size where it differs, logged as a warning),
    ``videos/<camera>.mp4``, ``capture.toml`` (fps 60), ``labels.toml``
    (:meth:`LabelSet.default`), ``README.md``, ``LICENSE`` (Pose2Sim's, BSD-3-Clause) and
    ``source/`` (the Qualisys file, Pose2Sim's ``Config.toml`` and the 1088 px
    ``extrinsics/*.png`` frames used to measure the size correction).

    Parameters
    ----------
    out : path-like
        The capture folder to write (new or empty).
    wheel : path-like, optional
        A downloaded ``pose2sim-0.10.49-*.whl``; default :func:`download_pose2sim_wheel`.
    cache : path-like, optional
        Wheel cache folder for :func:`download_pose2sim_wheel`.
    overwrite : bool
        Replace ``out`` if it holds a capture written by this module.

    Returns
    -------
    ExampleCapture

    Raises
    ------
    ExampleNotFoundError
        If the wheel cannot be downloaded.
    FileFormatError
        If the wheel lacks the demo's videos or calibration.
    """
    from .labelset import LabelSet
    from .rigio.qualisys import load_qualisys
    from .rigio.toml import save_rig_toml

    out = Path(out)
    tmp = _start_output(out, overwrite)
    try:
        wheel = Path(wheel) if wheel is not None else download_pose2sim_wheel(cache)
        try:
            z = zipfile.ZipFile(wheel)
        except (OSError, zipfile.BadZipFile) as exc:
            raise FileFormatError(wheel, f"not a readable wheel ({exc})") from None
        with z:
            names = z.namelist()
            demo = [n for n in names if n.startswith(POSE2SIM_DEMO) and not n.endswith("/")]
            videos = sorted(
                n for n in demo if n.startswith(POSE2SIM_DEMO + "videos/") and n.endswith(".mp4")
            )
            calibs = sorted(
                n
                for n in demo
                if n.startswith(POSE2SIM_DEMO + "calibration/") and n.endswith(".qca.txt")
            )
            if not videos or not calibs:
                raise FileFormatError(
                    wheel, f"no {POSE2SIM_DEMO}videos/*.mp4 or calibration/*.qca.txt inside"
                )
            src = tmp / "source"
            calib = _extract(z, calibs[0], src / Path(calibs[0]).name)
            for n in demo:
                rel = n[len(POSE2SIM_DEMO) :]
                if rel == "Config.toml" or rel.startswith("calibration/extrinsics/"):
                    _extract(z, n, src / rel.removeprefix("calibration/"))
            for n in videos:
                _extract(z, n, tmp / "videos" / Path(n).name)
            lic = [n for n in names if n.endswith(".dist-info/licenses/LICENSE")]
            if lic:
                _extract(z, lic[0], tmp / "LICENSE")
            shipped = sorted({n[len(POSE2SIM_DEMO) :].split("/")[0] for n in demo})
        cams = [Path(n).stem for n in videos]
        rig = _match_cameras(load_qualisys(calib), cams, calib)
        counts, corrections, evidence, fixed = {}, {}, {}, []
        for cam in rig:
            vpath = tmp / "videos" / f"{cam.name}.mp4"
            count, size, _ = _video_info(vpath)
            counts[cam.name] = count
            if tuple(size) == tuple(cam.size):
                fixed.append(cam)
                continue
            ref_path = src / "extrinsics" / f"{cam.name}_ext.png"
            ref = read_rgb(ref_path) if ref_path.is_file() else None
            if ref is not None and tuple(ref.shape[1::-1]) != tuple(cam.size):
                ref = None
            mapping, why = choose_image_mapping(cam.name, cam.size, _first_frame(vpath), ref)
            corrections[cam.name] = mapping
            evidence[cam.name] = why
            fixed.append(mapping.apply(cam))
        if corrections:
            logger.warning(
                "pose2sim: video size differs from the calibration for camera(s) %s; adapted "
                "their intrinsics: %s",
                ", ".join(corrections),
                "; ".join(f"{k}: {m.describe()}" for k, m in corrections.items()),
            )
        rig = CameraRig(fixed)
        save_rig_toml(rig, tmp / "rig.toml")
        spec = EXAMPLES["pose2sim"]
        _save_capture_toml(
            tmp / "capture.toml",
            POSE2SIM_FPS,
            f"{spec.source} (https://pypi.org/project/pose2sim/0.10.49/, "
            "https://github.com/perfanalytics/pose2sim)",
            f"{spec.description}. Licence: {spec.licence} (LICENSE, Copyright (c) 2022, "
            "perfanalytics).",
        )
        LabelSet.default().save(tmp / "labels.toml")
        notes = [f"{k}: {evidence[k]}" for k in corrections]
        reference = [s for s in shipped if s.startswith("pose")]
        notes.append(
            "reference pose outputs shipped in the wheel: "
            + (", ".join(reference) if reference else "none (only " + ", ".join(shipped) + ")")
        )
        _write_pose2sim_readme(tmp, rig, counts, corrections, notes)
        _finish_output(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    logger.info("wrote %s: %d cameras, %s frames", out, len(rig), counts)
    return ExampleCapture("pose2sim", out, rig.names, counts, POSE2SIM_FPS, corrections, notes)


def _write_pose2sim_readme(
    folder: Path,
    rig: CameraRig,
    counts: Mapping[str, int],
    corrections: Mapping[str, ImageMapping],
    notes: list[str],
) -> None:
    rows = "\n".join(
        f"| {c.name} | {c.size[0]}x{c.size[1]} | {counts[c.name]} | "
        + (corrections[c.name].describe() if c.name in corrections else "none")
        + " |"
        for c in rig
    )
    text = (
        f"""# Pose2Sim Demo_SinglePerson, as a pointtraj capture

Written by `pointtraj examples fetch pose2sim`.

- **Origin**: folder `{POSE2SIM_DEMO}` of the PyPI wheel `{POSE2SIM_REQUIREMENT}`
  (<https://github.com/perfanalytics/pose2sim>), by David Pagnon / perfanalytics.
- **Licence**: BSD-3-Clause, Copyright (c) 2022, perfanalytics (`LICENSE`). Keep the licence
  with any copy of these files.
- **Content**: {len(rig)} static cameras filming a man balancing on a treadmill, portrait
  1088x1920, 60 fps; calibration by a Qualisys system (`source/Calib.qca.txt`), converted to
  `rig.toml` by `pointtraj.rigio.load_qualisys`.
- `labels.toml` is pointtraj's default label set (14 body parts, ball, racket).
- `source/extrinsics/*.png` are 1088 px frames of the same static cameras that Pose2Sim ships
  with its calibration; they are the reference for the size correction below.

| camera | stored size | frames | calibration adapted |
|---|---|---|---|
{rows}

Notes:

"""
        + "\n".join(f"- {n}" for n in notes)
        + "\n"
    )
    write_text_atomic(folder / "README.md", text)


# -- caliscope ------------------------------------------------------------------------------


def _read_csv(path: Path, required: tuple[str, ...]) -> list[dict[str, str]]:
    if not path.is_file():
        raise FileFormatError(path, "no such file")
    with open(path, newline="") as f:
        reader = csv.DictReader(f)
        missing = [c for c in required if c not in (reader.fieldnames or [])]
        if missing:
            raise FileFormatError(path, f"missing column(s) {', '.join(missing)}")
        return list(reader)


def caliscope_sync_report(
    timestamps: str | os.PathLike, frame_counts: Mapping[str, int] | None = None
) -> SyncReport:
    """Frame-time spread per sync index of a caliscope ``timestamps.csv``.

    Parameters
    ----------
    timestamps : path-like
        CSV with columns ``sync_index, cam_id, frame_time`` (seconds).
    frame_counts : mapping of str to int, optional
        Frames per camera found in the videos (reported as is).

    Returns
    -------
    SyncReport

    Raises
    ------
    FileFormatError
        On missing columns or non-numeric values.
    """
    path = Path(timestamps)
    rows = _read_csv(path, ("sync_index", "cam_id", "frame_time"))
    try:
        data = np.array(
            [[float(r["sync_index"]), float(r["cam_id"]), float(r["frame_time"])] for r in rows]
        )  # (R, 3)
    except ValueError as exc:
        raise FileFormatError(path, f"non-numeric value ({exc})") from None
    if len(data) == 0:
        raise FileFormatError(path, "no rows")
    cams = np.unique(data[:, 1]).astype(int)
    sync = np.unique(data[:, 0]).astype(int)
    times = np.full((len(sync), len(cams)), np.nan)  # (S, C)
    times[np.searchsorted(sync, data[:, 0]), np.searchsorted(cams, data[:, 1])] = data[:, 2]
    full = np.all(np.isfinite(times), axis=1)
    spread = times[full].max(axis=1) - times[full].min(axis=1)
    order = np.argsort(times, axis=0)
    dt = np.diff(np.take_along_axis(times, order, axis=0), axis=0)
    fps = float(1.0 / np.nanmedian(dt))
    ts_counts = {f"cam_{c}": int(np.isfinite(times[:, i]).sum()) for i, c in enumerate(cams)}
    return SyncReport(dict(frame_counts or {}), ts_counts, spread, fps)


def _sync_to_frame(outer: Path, inner: Path) -> dict[int, int]:
    """caliscope's outer sync_index -> video frame index, matched through the frame times."""
    o = _read_csv(outer, ("sync_index", "cam_id", "frame_time"))
    i = _read_csv(inner, ("sync_index", "cam_id", "frame_index", "frame_time"))
    frame_of = {(r["cam_id"], r["frame_time"]): int(r["frame_index"]) for r in i}
    out: dict[int, set[int]] = {}
    for r in o:
        f = frame_of.get((r["cam_id"], r["frame_time"]))
        if f is not None:
            out.setdefault(int(r["sync_index"]), set()).add(f)
    bad = {s: f for s, f in out.items() if len(f) != 1}
    if bad:
        raise FileFormatError(outer, f"sync indices map to several frames: {bad}")
    frame_of = {s: next(iter(f)) for s, f in out.items()}
    offsets = {s - f for s, f in frame_of.items()}
    if len(offsets) == 1:  # a constant offset also holds for sync indices without a time match
        off = offsets.pop()
        frame_of.update({int(r["sync_index"]): int(r["sync_index"]) - off for r in o})
    return frame_of


def _write_corners(src: Path, dst: Path, frame_of: Mapping[int, int]) -> tuple[int, int]:
    """Corner files with a video ``frame`` column; returns (2D rows, 3D rows) written."""
    xy = _read_csv(
        src / "xy_CHARUCO.csv",
        ("sync_index", "cam_id", "keypoint_id", "img_loc_x", "img_loc_y"),
    )
    xyz = _read_csv(
        src / "xyz_CHARUCO.csv", ("sync_index", "keypoint_id", "x_coord", "y_coord", "z_coord")
    )
    lines2 = ["frame,camera,keypoint_id,x,y,board_x,board_y,board_z"]
    for r in xy:
        f = frame_of.get(int(r["sync_index"]))
        if f is None:
            continue
        lines2.append(
            f"{f},cam_{r['cam_id']},{r['keypoint_id']},{r['img_loc_x']},{r['img_loc_y']},"
            f"{r.get('obj_loc_x', '')},{r.get('obj_loc_y', '')},{r.get('obj_loc_z', '')}"
        )
    lines3 = ["frame,keypoint_id,x,y,z"]
    for r in xyz:
        f = frame_of.get(int(r["sync_index"]))
        if f is None:
            continue
        lines3.append(f"{f},{r['keypoint_id']},{r['x_coord']},{r['y_coord']},{r['z_coord']}")
    write_text_atomic(dst / "corners_2d.csv", "\n".join(lines2) + "\n")
    write_text_atomic(dst / "corners_3d.csv", "\n".join(lines3) + "\n")
    return len(lines2) - 1, len(lines3) - 1


def fetch_caliscope_board(
    out: str | os.PathLike,
    *,
    source: str | os.PathLike | None = None,
    link: bool = True,
    overwrite: bool = False,
) -> ExampleCapture:
    """Lay out caliscope's 4-camera ChArUco session as a pointtraj capture.

    Writes ``rig.toml`` (from ``camera_array.toml``), ``videos/cam_N.mp4`` (symlinks to, or
    copies of, ``calibration/extrinsic/cam_N.mp4``), ``capture.toml`` (fps from
    ``CHARUCO/timestamps.csv``), ``labels.toml`` (14 body parts and a ``board`` object),
    ``charuco.toml``, ``charuco/`` (caliscope's corner and timestamp files unchanged, plus
    ``corners_2d.csv`` / ``corners_3d.csv`` indexed by video frame), ``LICENSE``,
    ``SOURCE.md`` and ``README.md`` (with the synchronisation report).

    Parameters
    ----------
    out : path-like
        The capture folder to write (new or empty).
    source : path-like, optional
        The ``caliscope_board_4cam`` folder; default :func:`find_shared_data`.
    link : bool
        Symlink the videos (absolute paths) instead of copying them.
    overwrite : bool
        Replace ``out`` if it holds a capture written by this module.

    Returns
    -------
    ExampleCapture
        ``notes`` holds the :class:`SyncReport` summary.

    Raises
    ------
    ExampleNotFoundError
        If the source folder is missing (saying where to get it).
    FileFormatError
        For a missing or malformed source file.
    """
    from .labelset import BODY_PARTS, LabelSet
    from .rigio.caliscope import load_caliscope
    from .rigio.toml import save_rig_toml

    src = Path(source) if source is not None else find_shared_data(CALISCOPE_FOLDER)
    if src is None or not src.is_dir():
        raise ExampleNotFoundError(
            f"caliscope-board: source folder {src or CALISCOPE_FOLDER!s} not found (looked in "
            f"${SHARED_ENV}/data, <repo>/../shared/data and /work/shared/data); get it from "
            "https://github.com/mprib/caliscope at commit ddda95b44ba2, folder "
            "tests/sessions/post_optimization, and pass --source DIR"
        )
    src = src.resolve()
    ext = src / "calibration" / "extrinsic"
    for need in (src / "camera_array.toml", ext / "CHARUCO" / "timestamps.csv"):
        if not need.is_file():
            raise ExampleNotFoundError(
                f"caliscope-board: {need} is missing; --source must be the caliscope_board_4cam "
                "folder (camera_array.toml, calibration/extrinsic/cam_N.mp4, CHARUCO/*.csv)"
            )
    rig = load_caliscope(src / "camera_array.toml")
    out = Path(out)
    tmp = _start_output(out, overwrite)
    try:
        counts = {}
        for cam in rig:
            video = ext / f"{cam.name}.mp4"
            if not video.is_file():
                raise FileFormatError(video, f"no video for calibrated camera {cam.name}")
            count, size, _ = _video_info(video)
            if tuple(size) != tuple(cam.size):
                raise FileFormatError(
                    video,
                    f"video is {size[0]}x{size[1]} but the calibration says "
                    f"{cam.size[0]}x{cam.size[1]}",
                )
            counts[cam.name] = count
            dst = tmp / "videos" / video.name
            dst.parent.mkdir(parents=True, exist_ok=True)
            if link:
                dst.symlink_to(video)
            else:
                shutil.copyfile(video, dst)
        save_rig_toml(rig, tmp / "rig.toml")
        charuco = ext / "CHARUCO"
        sync = caliscope_sync_report(charuco / "timestamps.csv", counts)
        outer = ext / "timestamps.csv"
        full_sync = caliscope_sync_report(outer, counts) if outer.is_file() else sync
        spec = EXAMPLES["caliscope-board"]
        _save_capture_toml(
            tmp / "capture.toml",
            sync.fps,
            f"{spec.source}, read from {src}",
            f"{spec.description}. Licence: {spec.licence} (LICENSE, Copyright (c) 2024, "
            'Donald "Mac" Prible).',
        )
        base = LabelSet.default()
        LabelSet(
            (*BODY_PARTS, "board"),
            np.vstack([base.colors[: len(BODY_PARTS)], [[255, 225, 25]]]),
            ("body",) * len(BODY_PARTS) + ("object",),
        ).save(tmp / "labels.toml")
        for name in ("charuco.toml", "LICENSE", "SOURCE.md"):
            if (src / name).is_file():
                shutil.copyfile(src / name, tmp / name)
        (tmp / "charuco").mkdir()
        for f in sorted(charuco.glob("*.csv")):
            shutil.copyfile(f, tmp / "charuco" / f.name)
        if outer.is_file():
            shutil.copyfile(outer, tmp / "charuco" / "timestamps_sync.csv")
            frame_of = _sync_to_frame(outer, charuco / "timestamps.csv")
        else:
            frame_of = {s: s for s in range(max(counts.values()))}
        n2, n3 = _write_corners(charuco, tmp / "charuco", frame_of)
        offsets = sorted({s - f for s, f in frame_of.items()})
        notes = [
            "sync (CHARUCO/timestamps.csv): " + sync.describe(),
            "sync (extrinsic/timestamps.csv): " + full_sync.describe(),
            f"caliscope's corner files use sync_index = video frame + {offsets[0]}"
            if len(offsets) == 1
            else f"sync_index - frame offsets vary: {offsets}",
            f"charuco/corners_2d.csv: {n2} detections, charuco/corners_3d.csv: {n3} corners, "
            "indexed by video frame",
        ]
        _write_caliscope_readme(tmp, rig, counts, sync.fps, notes)
        _finish_output(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    logger.info("wrote %s: %s", out, sync.describe())
    return ExampleCapture("caliscope-board", out, rig.names, counts, sync.fps, {}, notes)


def _write_caliscope_readme(
    folder: Path, rig: CameraRig, counts: Mapping[str, int], fps: float, notes: list[str]
) -> None:
    rows = "\n".join(f"| {c.name} | {c.size[0]}x{c.size[1]} | {counts[c.name]} |" for c in rig)
    text = (
        f"""# caliscope ChArUco board session, as a pointtraj capture

Written by `pointtraj examples fetch caliscope-board`.

- **Origin**: caliscope (<https://github.com/mprib/caliscope>), commit ddda95b44ba2, folder
  `tests/sessions/post_optimization` (see `SOURCE.md`).
- **Licence**: BSD-2-Clause, Copyright (c) 2024, Donald "Mac" Prible (`LICENSE`).
- **Content**: 4 webcams, software-synchronised, ~{fps:.2f} fps; a person moves a ChArUco board
  (`charuco.toml`: 4x5 squares of 5.4 cm, DICT_4X4_1000, printed inverted).
- `rig.toml` is caliscope's `camera_array.toml` converted by `pointtraj.rigio.load_caliscope`.
- `videos/` link to (or copy) caliscope's `calibration/extrinsic/cam_N.mp4`.
- `labels.toml`: the 14 body parts and `board` (object).
- `charuco/`: caliscope's `xy_CHARUCO.csv` (2D corners), `xyz_CHARUCO.csv` (their
  triangulation), `timestamps.csv` (CHARUCO) and `timestamps_sync.csv` (extrinsic) unchanged,
  plus `corners_2d.csv` and `corners_3d.csv` with a `frame` column (video frame index) for the
  rigidity evaluation.

| camera | size | frames |
|---|---|---|
{rows}

Notes:

"""
        + "\n".join(f"- {n}" for n in notes)
        + "\n"
    )
    write_text_atomic(folder / "README.md", text)


def fetch_example(name: str, out: str | os.PathLike, **options: object) -> ExampleCapture:
    """Lay out the example capture ``name`` (a key of :data:`EXAMPLES`) in ``out``.

    Parameters
    ----------
    name : str
    out : path-like
    **options
        Passed to :func:`fetch_pose2sim` or :func:`fetch_caliscope_board`.

    Returns
    -------
    ExampleCapture

    Raises
    ------
    ValidationError
        For an unknown name (listing the valid ones).
    """
    funcs = {"pose2sim": fetch_pose2sim, "caliscope-board": fetch_caliscope_board}
    if name not in funcs:
        raise ValidationError(f"unknown example {name!r}; valid names: {', '.join(EXAMPLES)}")
    return funcs[name](out, **options)  # type: ignore[operator]


# -- verification with detected body landmarks ----------------------------------------------


def detect_landmarks(
    capture: object,
    frames: object,
    *,
    min_visibility: float = 0.5,
    threads: int = 1,
) -> np.ndarray:
    """MediaPipe Pose body landmarks of the most prominent person, per camera and frame.

    Uses :class:`pointtraj.semantics.recognizers.bodyparts.BodyPartRecognizer` (the
    ``body-parts`` model must be in the cache: ``pointtraj models fetch body-parts``).

    Parameters
    ----------
    capture : pointtraj.session.Capture
    frames : sequence of int
        F frame indices.
    min_visibility : float
        Landmarks with a lower MediaPipe visibility are NaN.
    threads : int
        LiteRT threads.

    Returns
    -------
    (C, F, 33, 2) float ndarray
        Pixels in each camera's stored frames; NaN where nobody was found or a landmark is
        not visible enough.
    """
    from .semantics.recognizers.bodyparts import BodyPartRecognizer

    frames = [int(f) for f in frames]  # type: ignore[attr-defined]
    rec = BodyPartRecognizer(["person"], mapping={}, threads=threads)
    names = capture.camera_names  # type: ignore[attr-defined]
    out = np.full((len(names), len(frames), 33, 2), np.nan)
    for c, cam in enumerate(names):
        for i, t in enumerate(frames):
            poses = rec.estimate_poses(capture.read(cam, t))  # type: ignore[attr-defined]
            if poses:
                p = poses[0]
                ok = p.visibility >= min_visibility  # (33,)
                out[c, i, ok] = p.landmarks[ok]
    return out


def landmark_reprojection_errors(
    rig: CameraRig, landmarks: np.ndarray, *, leave_one_out: bool = False
) -> np.ndarray:
    """Reprojection errors of landmarks triangulated over the rig's cameras.

    Parameters
    ----------
    rig : CameraRig
        C cameras.
    landmarks : (C, ...) float ndarray
        Pixel observations ``(C, F, L, 2)`` or ``(C, N, 2)``; NaN where missing.
    leave_one_out : bool
        Triangulate each point from the other cameras only (at least 2) and measure the error
        in the left-out camera: a test of each camera's calibration that its own observations
        cannot absorb.

    Returns
    -------
    (C, N) float ndarray
        Pixel errors (N = all points), NaN where not measurable.
    """
    from .reconstruct.triangulate import triangulate_points

    obs = np.asarray(landmarks, float).reshape(len(rig), -1, 2)  # (C, N, 2)
    if not leave_one_out:
        X = triangulate_points(rig, obs)  # (N, 3)
        return rig.reprojection_errors(X, obs)
    err = np.full(obs.shape[:2], np.nan)
    for c in range(len(rig)):
        others = [i for i in range(len(rig)) if i != c]
        X = triangulate_points(rig.subset(others), obs[others])  # (N, 3)
        err[c] = rig.subset([c]).reprojection_errors(X, obs[c : c + 1])[0]
    return err
