"""Image mapping between a camera's calibrated image and the frames actually stored."""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace

import numpy as np

from ..camera import Camera
from ..errors import ValidationError

logger = logging.getLogger(__name__)


#: Largest disagreement (px, at the image corners) between a measured image mapping and a
#: candidate model for the model to be accepted.
MAPPING_TOLERANCE_PX = 1.5
#: Mean grey level under which an image row counts as a black letterbox bar.
BAR_LEVEL = 12.0
#: Fewest RANSAC inliers for a measured image mapping to be trusted.
MIN_MAPPING_INLIERS = 50


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
