"""Calibrated pinhole cameras with OpenCV lens distortion, and rigs of them.

Conventions (see ``docs/`` and the paper's Section "Notation"): a camera is
``P = K R [I | -C]``, so a world point X has camera coordinates ``x_cam = R (X - C)``. Pixel
coordinates follow OpenCV: the origin is the centre of the top-left pixel, x right, y down, and the
image covers ``[-0.5, w - 0.5) x [-0.5, h - 0.5)``. Distortion is OpenCV's rational model
``(k1, k2, p1, p2, k3, k4, k5, k6)``; shorter vectors (4 or 5 coefficients) are zero-padded.

All projection routines are vectorised over points and, in :class:`CameraRig`, over cameras. The
lens model (:func:`distort_normalized`, :func:`undistort_normalized`) and the Rodrigues conversions
live in :mod:`pointtraj.geometry` and are re-exported here.
"""

from __future__ import annotations

import functools
import logging
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field

import numpy as np

from .errors import ValidationError, check_array
from .geometry import (
    N_DIST,
    _no_distortion_xy,
    distort_normalized,
    finite_rows,
    pixel_distance,
    rodrigues_from_rotation,
    rotation_from_rodrigues,
    undistort_normalized,
)

__all__ = [
    "Camera",
    "CameraRig",
    "Projection",
    "distort_normalized",
    "undistort_normalized",
    "rotation_from_rodrigues",
    "rodrigues_from_rotation",
]

logger = logging.getLogger(__name__)

_ALLOWED_DIST_LENGTHS = (0, 4, 5, 8)
#: :meth:`CameraRig.project` works on blocks of about this many (camera, point) pairs.
_PROJECT_BLOCK = 1 << 16
#: Tolerance on ``R^T R = I`` and ``det R = 1`` when validating rotations.
ROTATION_TOL = 1e-5
#: :meth:`CameraRig.normalized` and :meth:`CameraRig.undistort_pixels` work on the finite pixels
#: alone where they are fewer than this share of a (C, N) array (each camera observes a few of
#: the points; the same values).
SPARSE_UNDISTORT = 0.15
#: :meth:`CameraRig.subset` keeps this many subsets of a rig (one per camera of a 256-camera rig).
KEPT_SUBSETS = 256


def _pad_dist(name: str, dist: object) -> np.ndarray:
    d = np.asarray(dist if dist is not None else [], dtype=float).ravel()
    if d.size not in _ALLOWED_DIST_LENGTHS:
        raise ValidationError(
            f"{name}: distortion must have 0, 4, 5 or 8 coefficients "
            f"(k1 k2 p1 p2 [k3 [k4 k5 k6]]), got {d.size}"
        )
    if not np.all(np.isfinite(d)):
        raise ValidationError(f"{name}: distortion contains NaN or infinite values")
    out = np.zeros(N_DIST)
    out[: d.size] = d
    return out


@dataclass(frozen=True)
class Projection:
    """Points projected into several cameras.

    Attributes
    ----------
    pixels : (C, N, 2) float ndarray
        Distorted pixel coordinates (NaN behind the camera).
    depth : (C, N) float ndarray
        Depth along each camera's optical axis (z of ``R (X - C)``), in metres.
    in_image : (C, N) bool ndarray
        In front of the camera, inside the lens's valid field of view, and inside the image.
    """

    pixels: np.ndarray
    depth: np.ndarray
    in_image: np.ndarray


@dataclass(frozen=True, eq=False)
class Camera:
    """One calibrated camera, ``P = K R [I | -C]``.

    Parameters
    ----------
    name : str
        Unique name within its rig (used for folder and file names).
    K : (3, 3) float ndarray
        Intrinsics; positive focal lengths, ``K[2] == [0, 0, 1]``.
    R : (3, 3) float ndarray
        World-to-camera rotation (proper, orthonormal).
    C : (3,) float ndarray
        Camera centre in world coordinates (metres).
    size : (int, int)
        Image ``(width, height)`` in pixels.
    dist : (8,) float ndarray
        OpenCV distortion ``(k1, k2, p1, p2, k3, k4, k5, k6)``; 0, 4, 5 or 8 values accepted.

    Raises
    ------
    ValidationError
        On wrong shapes, a non-rotation ``R``, a non-positive focal length or image size.
    """

    name: str
    K: np.ndarray
    R: np.ndarray
    C: np.ndarray
    size: tuple[int, int]
    dist: np.ndarray = field(default_factory=lambda: np.zeros(N_DIST))

    def __post_init__(self) -> None:
        name = str(self.name)
        if not name or any(ch in name for ch in "/\\\0"):
            raise ValidationError(f"camera name {name!r} must be non-empty without slashes")
        where = f"camera {name!r}"
        K = check_array(f"{where} K", self.K, (3, 3), finite=True)
        R = check_array(f"{where} R", self.R, (3, 3), finite=True)
        C = check_array(f"{where} C", self.C, (3,), finite=True)
        if K[0, 0] <= 0 or K[1, 1] <= 0:
            raise ValidationError(
                f"{where}: focal lengths must be positive, got fx={K[0, 0]}, fy={K[1, 1]}"
            )
        if not np.allclose(K[2], [0, 0, 1]) or K[1, 0] != 0:
            raise ValidationError(f"{where}: K must be upper triangular with K[2] = [0, 0, 1]")
        if not np.allclose(R.T @ R, np.eye(3), atol=ROTATION_TOL) or np.linalg.det(R) < 0:
            raise ValidationError(
                f"{where}: R is not a rotation matrix (R^T R != I or det R = {np.linalg.det(R):.4f})"
            )
        try:
            w, h = (int(s) for s in self.size)
        except (TypeError, ValueError):
            raise ValidationError(
                f"{where}: size must be (width, height), got {self.size!r}"
            ) from None
        if w <= 0 or h <= 0:
            raise ValidationError(f"{where}: image size must be positive, got {w}x{h}")
        # Re-orthonormalise R so that small calibration-file rounding does not accumulate.
        u, _, vt = np.linalg.svd(R)
        for attr, val in (
            ("name", name),
            ("K", K),
            ("R", u @ vt),
            ("C", C),
            ("size", (w, h)),
            ("dist", _pad_dist(f"{where} dist", self.dist)),
        ):
            object.__setattr__(self, attr, val)
            if isinstance(val, np.ndarray):
                val.flags.writeable = False

    # -- alternative constructors ------------------------------------------------------------
    @classmethod
    def from_extrinsics(
        cls,
        name: str,
        K: object,
        R: object,
        t: object,
        size: tuple[int, int],
        dist: object = None,
    ) -> Camera:
        """Build from OpenCV-style extrinsics ``x_cam = R X + t`` (so ``C = -R^T t``)."""
        R = check_array(f"camera {name!r} R", R, (3, 3), finite=True)
        t = check_array(f"camera {name!r} t", t, (3,), finite=True)
        return cls(name, np.asarray(K, float), R, -R.T @ t, size, _pad_dist(name, dist))

    @classmethod
    def look_at(
        cls,
        name: str,
        center: object,
        target: object,
        size: tuple[int, int],
        focal: float,
        up: object = (0.0, 0.0, 1.0),
        dist: object = None,
    ) -> Camera:
        """A camera at ``center`` looking at ``target`` with world ``up`` pointing up in the image.

        Parameters
        ----------
        name : str
        center, target : (3,) array-like
        size : (int, int)
            ``(width, height)``; the principal point is the image centre.
        focal : float
            Focal length in pixels.
        up : (3,) array-like
            World up direction (default +z).
        dist : array-like, optional
        """
        c = check_array("center", center, (3,), finite=True)
        z = check_array("target", target, (3,), finite=True) - c
        if np.linalg.norm(z) == 0:
            raise ValidationError("look_at: center and target coincide")
        z /= np.linalg.norm(z)
        x = np.cross(z, np.asarray(up, float))
        if np.linalg.norm(x) < 1e-9:
            x = np.cross(z, [0.0, 1.0, 0.0])
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        w, h = size
        K = np.array([[focal, 0, (w - 1) / 2], [0, focal, (h - 1) / 2], [0, 0, 1.0]])
        return cls(name, K, np.stack([x, y, z]), c, (w, h), _pad_dist(name, dist))

    # -- derived quantities ------------------------------------------------------------------
    @property
    def t(self) -> np.ndarray:
        """(3,) translation of the OpenCV form ``x_cam = R X + t``."""
        return -self.R @ self.C

    @property
    def P(self) -> np.ndarray:
        """(3, 4) projection matrix ``K R [I | -C]`` (ignores distortion)."""
        return self.K @ np.hstack([self.R, self.t[:, None]])

    @property
    def width(self) -> int:
        return self.size[0]

    @property
    def height(self) -> int:
        return self.size[1]

    @property
    def has_distortion(self) -> bool:
        return bool(np.any(self.dist))

    @property
    def viewing_direction(self) -> np.ndarray:
        """(3,) unit optical axis in world coordinates."""
        return self.R[2].copy()

    def with_name(self, name: str) -> Camera:
        """A copy renamed."""
        return Camera(name, self.K, self.R, self.C, self.size, self.dist)

    def resized(self, scale: float) -> Camera:
        """The camera of its images resized by ``scale`` (as OpenCV's ``resize`` does).

        The size is rounded to whole pixels (at least 1), and pixel centres map as ``resize``
        maps them: ``u' = (u + 0.5) s - 0.5``, with ``s`` the rounded size's ratio on each
        axis. The distortion, in normalised coordinates, is unchanged.

        Parameters
        ----------
        scale : float
            Positive.

        Returns
        -------
        Camera
        """
        if not (np.isfinite(scale) and scale > 0):
            raise ValidationError(f"camera {self.name!r}: scale must be positive, got {scale!r}")
        w, h = self.size
        size = (max(1, round(w * scale)), max(1, round(h * scale)))
        sx, sy = size[0] / w, size[1] / h
        K = np.array(self.K, np.float64)
        K[0, :] *= sx
        K[1, :] *= sy
        K[0, 2] += 0.5 * sx - 0.5
        K[1, 2] += 0.5 * sy - 0.5
        return Camera(self.name, K, self.R, self.C, size, self.dist)

    def project(self, points: object) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Project world points into this camera.

        Parameters
        ----------
        points : (N, 3) array-like

        Returns
        -------
        pixels : (N, 2) float ndarray
        depth : (N,) float ndarray
        in_image : (N,) bool ndarray
        """
        proj = CameraRig([self]).project(points)
        return proj.pixels[0], proj.depth[0], proj.in_image[0]

    def undistort_pixels(self, pixels: object) -> np.ndarray:
        """Remove lens distortion from pixel coordinates.

        Parameters
        ----------
        pixels : (N, 2) array-like
            Distorted pixels.

        Returns
        -------
        (N, 2) float ndarray
            The pixels an ideal (distortion-free) camera with the same K would see.
        """
        return CameraRig([self]).undistort_pixels(check_array("pixels", pixels, (None, 2))[None])[0]

    def rays(self, pixels: object) -> tuple[np.ndarray, np.ndarray]:
        """Back-project pixels into world rays.

        Parameters
        ----------
        pixels : (N, 2) array-like
            Distorted pixel coordinates.

        Returns
        -------
        origins : (N, 3) float ndarray
            The camera centre, repeated.
        directions : (N, 3) float ndarray
            Unit directions in world coordinates.
        """
        o, d = CameraRig([self]).rays(check_array("pixels", pixels, (None, 2))[None])
        return o[0], d[0]

    def __repr__(self) -> str:
        fx, fy = self.K[0, 0], self.K[1, 1]
        return (
            f"Camera({self.name!r}, {self.width}x{self.height}, f=({fx:.1f}, {fy:.1f}), "
            f"C={np.round(self.C, 3).tolist()})"
        )


def _from_pixels(pix: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Normalised coordinates (..., 2) of pixels (..., 2) under intrinsics K (..., 3, 3)
    broadcast against them (lens distortion not removed)."""
    y = (pix[..., 1] - K[..., 1, 2]) / K[..., 1, 1]
    x = (pix[..., 0] - K[..., 0, 2] - K[..., 0, 1] * y) / K[..., 0, 0]
    return np.stack([x, y], axis=-1)


def _to_pixels(xy: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Pixels (..., 2) of normalised coordinates (..., 2) under K (..., 3, 3), broadcast."""
    u = K[..., 0, 0] * xy[..., 0] + K[..., 0, 1] * xy[..., 1] + K[..., 0, 2]
    v = K[..., 1, 1] * xy[..., 1] + K[..., 1, 2]
    return np.stack([u, v], axis=-1)


class CameraRig(Sequence[Camera]):
    """An ordered set of cameras with unique names, and vectorised operations over all of them.

    Parameters
    ----------
    cameras : iterable of Camera

    Raises
    ------
    ValidationError
        If the rig is empty or names repeat.
    """

    def __init__(self, cameras: Iterable[Camera]) -> None:
        cams = list(cameras)
        if not cams:
            raise ValidationError("a camera rig needs at least one camera")
        for c in cams:
            if not isinstance(c, Camera):
                raise ValidationError(f"CameraRig expects Camera objects, got {type(c).__name__}")
        names = [c.name for c in cams]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValidationError(f"duplicate camera names in rig: {', '.join(dup)}")
        self._cams = cams
        self.K = np.stack([c.K for c in cams])  # (C, 3, 3)
        self.R = np.stack([c.R for c in cams])  # (C, 3, 3)
        self.C = np.stack([c.C for c in cams])  # (C, 3)
        self.dist = np.stack([c.dist for c in cams])  # (C, 8)
        self.sizes = np.array([c.size for c in cams], dtype=np.int64)  # (C, 2)
        self._max_r2 = self._valid_radius2()
        for a in (self.K, self.R, self.C, self.dist, self.sizes, self._max_r2):
            a.flags.writeable = False
        self._subsets: dict[tuple[int | str, ...], CameraRig] = {}

    # -- sequence protocol -------------------------------------------------------------------
    def __len__(self) -> int:
        return len(self._cams)

    def __getitem__(self, key):  # type: ignore[override]
        if isinstance(key, str):
            return self._cams[self.index(key)]
        if isinstance(key, slice):
            return CameraRig(self._cams[key])
        return self._cams[key]

    def __iter__(self) -> Iterator[Camera]:
        return iter(self._cams)

    def __repr__(self) -> str:
        return f"CameraRig({len(self)} cameras: {', '.join(self.names[:6])}{'...' if len(self) > 6 else ''})"

    @property
    def names(self) -> list[str]:
        """Camera names, in order."""
        return [c.name for c in self._cams]

    def index(self, name: str) -> int:  # type: ignore[override]
        """Index of the camera called ``name``."""
        for i, c in enumerate(self._cams):
            if c.name == name:
                return i
        raise ValidationError(f"no camera named {name!r}; the rig has {', '.join(self.names)}")

    def subset(self, cameras: Iterable[int | str]) -> CameraRig:
        """A rig made of some cameras, by index or name.

        The first :data:`KEPT_SUBSETS` subsets asked for are kept (a rig's arrays are
        read-only): densification asks for the same one per reference camera every frame,
        and making one bounds every camera's lens anew.
        """
        key = tuple(c if isinstance(c, str) else int(c) for c in cameras)
        sub = self._subsets.get(key)
        if sub is None:
            sub = CameraRig([self[c] for c in key])
            if len(self._subsets) < KEPT_SUBSETS:
                self._subsets[key] = sub
        return sub

    @property
    def P(self) -> np.ndarray:
        """(C, 3, 4) projection matrices ``K R [I | -C]``."""
        t = -np.einsum("cij,cj->ci", self.R, self.C)
        return self.K @ np.concatenate([self.R, t[:, :, None]], axis=2)

    # -- geometry ----------------------------------------------------------------------------
    def _valid_radius2(self) -> np.ndarray:
        """(C,) squared normalised radius beyond which a point cannot be in the image.

        Polynomial distortion models fold back outside the calibrated field of view, so a point
        far outside it can land inside the image. We bound the undistorted radius by that of the
        image corners, with a 10 % margin.
        """
        out = np.empty(len(self))
        for i, c in enumerate(self._cams):
            w, h = c.size
            corners = np.array([[-0.5, -0.5], [w - 0.5, -0.5], [-0.5, h - 0.5], [w - 0.5, h - 0.5]])
            edges = np.array(
                [
                    [(w - 1) / 2, -0.5],
                    [(w - 1) / 2, h - 0.5],
                    [-0.5, (h - 1) / 2],
                    [w - 0.5, (h - 1) / 2],
                ]
            )
            pix = np.concatenate([corners, edges])
            xy_d = (pix - c.K[:2, 2]) / np.diag(c.K)[:2]
            xy_d[:, 0] -= c.K[0, 1] * xy_d[:, 1] / c.K[0, 0]
            xy = undistort_normalized(xy_d, c.dist)
            r2 = np.max(np.sum(xy**2, axis=1))
            # Where undistortion failed to converge, fall back to the distorted radius.
            back = distort_normalized(xy, c.dist)
            if not np.allclose(back, xy_d, atol=1e-6) or not np.isfinite(r2):
                r2 = np.max(np.sum(xy_d**2, axis=1))
            out[i] = r2 * 1.1**2
        return out

    def project(self, points: object) -> Projection:
        """Project world points into every camera at once.

        Parameters
        ----------
        points : (N, 3) array-like
            World points in metres. NaN rows give NaN pixels and ``in_image`` False.

        Returns
        -------
        Projection
            ``pixels`` (C, N, 2), ``depth`` (C, N) and ``in_image`` (C, N).
        """
        X = check_array("points", points, (None, 3))
        C, N = len(self), X.shape[0]
        step = max(1, _PROJECT_BLOCK // max(C, 1))
        if N <= step:
            return Projection(*self._project_block(X))
        # in blocks of points whose (C, n) temporaries stay in the CPU's cache: half the time
        # of one pass over all points (69 cameras, 75,000 points), the same values
        pixels = np.empty((C, N, 2))
        depth = np.empty((C, N))
        in_image = np.empty((C, N), bool)
        for i in range(0, N, step):
            block = slice(i, i + step)
            pixels[:, block], depth[:, block], in_image[:, block] = self._project_block(X[block])
        return Projection(pixels, depth, in_image)

    def _project_block(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`project` of (n, 3) checked points: pixels (C, n, 2), depth and in_image."""
        # R (X - C) = X R^T - R C; a batched matmul is 5x faster than the einsum.
        RC, distorted = self._projection_constants
        cam = np.matmul(X[None], self.R.transpose(0, 2, 1))  # (C, N, 3)
        cam -= RC[:, None, :]
        depth = cam[..., 2]
        front = np.where(depth > 0, depth, np.nan)
        with np.errstate(divide="ignore", invalid="ignore"):
            x = cam[..., 0] / front  # (C, N) each
            y = cam[..., 1] / front
        r2 = x * x + y * y  # (C, N), as the sum over the last axis of xy**2
        if distorted:
            xy_d = distort_normalized(np.stack([x, y], axis=-1), self.dist)  # (C, N, 2)
            xd, yd = xy_d[..., 0], xy_d[..., 1]
        else:  # no lens distortion: skip its arithmetic (the same values)
            xd, yd = _no_distortion_xy(x, y, r2)
        K = self.K
        u = K[:, None, 0, 0] * xd + K[:, None, 0, 1] * yd + K[:, None, 0, 2]
        v = K[:, None, 1, 1] * yd + K[:, None, 1, 2]
        pixels = np.stack([u, v], axis=-1)  # (C, N, 2)
        w = self.sizes[:, None, 0]
        h = self.sizes[:, None, 1]
        with np.errstate(invalid="ignore"):
            in_image = (
                (depth > 0)
                & (r2 <= self._max_r2[:, None])
                & (u >= -0.5)
                & (u < w - 0.5)
                & (v >= -0.5)
                & (v < h - 0.5)
            )
        return pixels, depth, in_image

    @functools.cached_property
    def _projection_constants(self) -> tuple[np.ndarray, bool]:
        """``R C`` (C, 3) and whether any camera has lens distortion, computed once."""
        RC = np.einsum("cij,cj->ci", self.R, self.C)
        RC.flags.writeable = False
        return RC, bool(np.any(self.dist))

    def undistort_pixels(self, pixels: object) -> np.ndarray:
        """Remove lens distortion, camera by camera.

        Parameters
        ----------
        pixels : (C, N, 2) array-like
            Distorted pixels, one row of points per camera.

        Returns
        -------
        (C, N, 2) float ndarray
            Ideal pixel coordinates under each camera's K without distortion (a float64 copy
            of ``pixels`` where no camera has a lens model: there is nothing to remove).
        """
        pix = check_array("pixels", pixels, (len(self), None, 2))
        if not self._projection_constants[1]:
            return pix.astype(np.float64)
        sparse = self._on_finite(pix, self._ideal)
        if sparse is not None:
            return sparse
        return _to_pixels(self.normalized(pix), self.K[:, None])

    def undistort_observed(self, pixels: object) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`undistort_pixels` of the finite pixels alone, as a list.

        Parameters
        ----------
        pixels : (C, N, 2) array-like
            Distorted pixels, NaN where a camera has none.

        Returns
        -------
        cams, columns : (M,) int64 ndarrays
            Where the finite pixels are, camera by camera (``np.nonzero``'s order).
        ideal : (M, 2) float ndarray
            Their ideal pixels (the values :meth:`undistort_pixels` gives there).
        """
        pix = check_array("pixels", pixels, (len(self), None, 2))
        cams, idx = np.nonzero(finite_rows(pix))
        return cams, idx, self._ideal(cams, pix[cams, idx])

    def normalized(self, pixels: object) -> np.ndarray:
        """Undistorted normalised coordinates ``(X/Z, Y/Z)`` of distorted pixels.

        Parameters
        ----------
        pixels : (C, N, 2) array-like

        Returns
        -------
        (C, N, 2) float ndarray
        """
        pix = check_array("pixels", pixels, (len(self), None, 2))
        sparse = self._on_finite(pix, self._normalized_at)
        if sparse is not None:
            return sparse
        xy = _from_pixels(pix, self.K[:, None])
        return undistort_normalized(xy, self.dist) if self._projection_constants[1] else xy

    def _on_finite(self, pix: np.ndarray, at) -> np.ndarray | None:
        """``at(cams, pixels)`` of the finite pixels of ``pix`` (C, N, 2) alone, in a NaN array
        of its shape, where they are fewer than :data:`SPARSE_UNDISTORT` of it (each camera
        observes a few of the points); None where they are not."""
        ok = finite_rows(pix)  # (C, N)
        if ok.sum() >= SPARSE_UNDISTORT * ok.size:
            return None
        cams, idx = np.nonzero(ok)
        out = np.full(pix.shape, np.nan)
        out[cams, idx] = at(cams, pix[cams, idx])
        return out

    def _normalized_at(self, cams: np.ndarray, pix: np.ndarray) -> np.ndarray:
        """:meth:`normalized` of pixels (M, 2) of the cameras ``cams`` (M,), each with its
        camera's K and lens: the values of the whole (C, N, 2) form, element by element."""
        return self._by_camera(cams, pix, ideal=False)

    def _ideal(self, cams: np.ndarray, pix: np.ndarray) -> np.ndarray:
        """:meth:`undistort_pixels` of pixels (M, 2) of the cameras ``cams`` (M,)."""
        if not self._projection_constants[1]:
            return pix.astype(np.float64)
        return self._by_camera(cams, pix, ideal=True)

    def _by_camera(self, cams: np.ndarray, pix: np.ndarray, ideal: bool) -> np.ndarray:
        """:meth:`_normalized_at` (or, with ``ideal``, :meth:`_ideal`) one camera's rows at a
        time, with that camera's K and lens as scalars: the same arithmetic, element by
        element, as with a (M, 3, 3) copy of the intrinsics, without making that copy (a
        frame's observations on paper69 are about 1.3 M rows)."""
        order = None
        if np.any(cams[1:] < cams[:-1]):  # np.nonzero's order is camera by camera already
            order = np.argsort(cams, kind="stable")
            cams, pix = cams[order], pix[order]
        out = np.empty((len(cams), 2))
        bounds = np.searchsorted(cams, np.arange(len(self) + 1))
        distorted = self._projection_constants[1]
        for c in np.flatnonzero(np.diff(bounds)):
            a, b = bounds[c], bounds[c + 1]
            K = self.K[c]
            xy = _from_pixels(pix[a:b], K)
            if distorted:  # as for the (M, 8) rows of every camera's coefficients
                dist = np.broadcast_to(self.dist[c], (b - a, self.dist.shape[1]))
                xy = undistort_normalized(xy[:, None, :], dist)[:, 0]
            out[a:b] = _to_pixels(xy, K) if ideal else xy
        if order is not None:
            back = np.empty_like(out)
            back[order] = out
            out = back
        return out

    def rays(self, pixels: object) -> tuple[np.ndarray, np.ndarray]:
        """Back-project pixels into world rays, camera by camera.

        Parameters
        ----------
        pixels : (C, N, 2) array-like
            Distorted pixels.

        Returns
        -------
        origins : (C, N, 3) float ndarray
        directions : (C, N, 3) float ndarray
            Unit vectors in world coordinates.
        """
        xy = self.normalized(pixels)
        d_cam = np.concatenate([xy, np.ones(xy.shape[:-1] + (1,))], axis=-1)  # (C, N, 3)
        d = np.einsum("cji,cnj->cni", self.R, d_cam)  # R^T d_cam
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
        o = np.broadcast_to(self.C[:, None, :], d.shape).copy()
        return o, d

    def reprojection_errors(self, points: object, observations: object) -> np.ndarray:
        """Pixel distance between projected points and observations.

        Parameters
        ----------
        points : (N, 3) array-like
        observations : (C, N, 2) array-like
            NaN where a camera has no observation.

        Returns
        -------
        (C, N) float ndarray
            NaN where there is no observation or the point is behind the camera.
        """
        obs = check_array("observations", observations, (len(self), None, 2))
        proj = self.project(points)
        return pixel_distance(proj.pixels, obs)
