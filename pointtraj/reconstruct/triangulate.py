"""Robust multi-view triangulation with visibility (paper Section 5, step 2).

Every routine is vectorised over points and linear in the number of cameras: no camera subsets
are enumerated and there is no per-point Python loop.

* :func:`triangulate_points` is the linear DLT over all observed views of each point.
* :func:`triangulate_ransac` draws, per point, random pairs of its observed views, triangulates
  each two-view hypothesis in closed form (ray midpoint), scores it by the reprojection error in
  all observed views, keeps the best, refits on its inliers (DLT through batched
  ``np.linalg.eigh`` of the 4x4 normal matrices, then Gauss-Newton on the reprojection error),
  and re-evaluates the inliers. Hypotheses are drawn in rounds; a point stops as soon as the
  standard RANSAC bound says its best inlier set was found with ``confidence``.
* :func:`compute_visibility` is the paper's ``V(X, c) = exp(-(e_c / sigma)^2)``, 0 outside the
  image or behind the camera, optionally also 0 where :func:`~.occlusion.occlusion_test` finds
  the point behind the frame's own reconstructed surface.

Conventions: observations are distorted OpenCV pixels, ``(C, N, 2)`` with NaN where camera c
has no observation of point n. Reconstructed points are ``(N, 3)`` metres, NaN where fewer than
``min_views`` views agree.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from ..camera import CameraRig
from ..errors import ValidationError, check_array
from ..geometry import finite_rows, observed_first, pixel_distance, undistort_normalized
from .occlusion import occlusion_test

__all__ = [
    "TriangulationConfig",
    "Triangulation",
    "triangulate_points",
    "triangulate_ransac",
    "compute_visibility",
]

logger = logging.getLogger(__name__)

#: Hypothesis scores are evaluated on at most this many (hypothesis, point, camera) triples at
#: once; it bounds the scratch memory of one chunk to about 10 float32 arrays of this size.
_MAX_ELEMENTS = 1 << 21
#: Points are refit in chunks of about this many (point, camera) pairs (the refit keeps about
#: 20 float64 arrays of that size).
_MAX_REFIT_ELEMENTS = 1 << 20
#: Rigs with more than twice this many cameras pre-score hypotheses on this many random views.
_PRESCORE_VIEWS = 16


@dataclass(frozen=True)
class TriangulationConfig:
    """Tolerances of robust triangulation, in one place.

    Attributes
    ----------
    threshold_px : float
        RANSAC inlier threshold on the reprojection error, in pixels.
    sigma_px : float
        Visibility tolerance sigma of ``V = exp(-(e / sigma)^2)`` (paper Section 5, step 2).
        The default of 1 px matches the accuracy of dense matching / optical flow on HD images
        (about 0.5 px per axis): under Gaussian noise of std s per axis the expected visibility
        of a correct view is ``1 / (1 + 2 s^2 / sigma^2)``, 0.67 at s = 0.5 px, while a view at
        the inlier threshold (2 px) gets ``exp(-4) = 0.018`` -- it helps the position but is
        barely trusted for semantics, and outliers get 0.
    iterations : int
        Maximum number of two-view hypotheses per point.
    min_views : int
        A point needs at least this many inlier views, otherwise it is NaN.
    seed : int
        Seed of the hypothesis sampler (``np.random.default_rng``).
    confidence : float
        Adaptive stopping: a point stops drawing hypotheses once an all-inlier pair has been
        drawn with this probability, given its best inlier ratio so far.
    batch : int
        Hypotheses drawn per point and round (the adaptive stop is checked between rounds).
    refine_iterations : int
        Gauss-Newton iterations on the reprojection error after the DLT refit (0 disables).
    """

    threshold_px: float = 2.0
    sigma_px: float = 1.0
    iterations: int = 50
    min_views: int = 2
    seed: int = 0
    confidence: float = 0.999
    batch: int = 12
    refine_iterations: int = 1

    def __post_init__(self) -> None:
        checks = [
            ("threshold_px", self.threshold_px > 0, "must be > 0"),
            ("sigma_px", self.sigma_px > 0, "must be > 0"),
            ("iterations", int(self.iterations) >= 1, "must be >= 1"),
            ("min_views", int(self.min_views) >= 2, "must be >= 2"),
            ("confidence", 0.0 < self.confidence < 1.0, "must be in (0, 1)"),
            ("batch", int(self.batch) >= 1, "must be >= 1"),
            ("refine_iterations", int(self.refine_iterations) >= 0, "must be >= 0"),
        ]
        for name, ok, what in checks:
            if not ok:
                raise ValidationError(
                    f"TriangulationConfig.{name} {what}, got {getattr(self, name)!r}"
                )


@dataclass(frozen=True)
class Triangulation:
    """Result of :func:`triangulate_ransac`.

    Attributes
    ----------
    points : (N, 3) float64 ndarray
        World points in metres; NaN where fewer than ``min_views`` inlier views.
    inliers : (C, N) bool ndarray
        Views whose reprojection error is below the threshold (all False for failed points).
    errors : (C, N) float64 ndarray
        Reprojection error in pixels of every observed view (NaN where unobserved or failed).
    visibility : (N, C) float32 ndarray
        ``V(X, c) = exp(-(e_c / sigma)^2)`` for observed views, 0 outside the image, behind the
        camera, unobserved or failed.
    mean_error : (N,) float64 ndarray
        Mean reprojection error over the inlier views (NaN where failed).
    """

    points: np.ndarray
    inliers: np.ndarray
    errors: np.ndarray
    visibility: np.ndarray
    mean_error: np.ndarray

    @property
    def valid(self) -> np.ndarray:
        """(N,) bool: the points that were reconstructed."""
        return finite_rows(self.points)


# -- helpers ---------------------------------------------------------------------------------


def _check_observations(rig: CameraRig, observations: object) -> np.ndarray:
    if not isinstance(rig, CameraRig):
        raise ValidationError(f"rig: expected a CameraRig, got {type(rig).__name__}")
    obs = check_array("observations", observations, (len(rig), None, 2))
    if np.any(np.isinf(obs)):
        raise ValidationError("observations: contains infinite values (use NaN for unobserved)")
    return obs


@dataclass(frozen=True)
class _Frame:
    """The rig in a conditioned world frame ``Xn = (X - origin) / scale``.

    ``Rt`` (C, 3, 4) maps homogeneous ``Xn`` to camera coordinates divided by ``scale``.
    """

    origin: np.ndarray  # (3,)
    scale: float
    Rt: np.ndarray  # (C, 3, 4)
    centers: np.ndarray  # (C, 3) camera centres in the conditioned frame


def _conditioned_frame(rig: CameraRig) -> _Frame:
    origin = rig.C.mean(axis=0)
    scale = float(np.mean(np.linalg.norm(rig.C - origin, axis=1)))
    if not np.isfinite(scale) or scale < 1e-9:
        scale = 1.0
    centers = (rig.C - origin) / scale  # (C, 3)
    t = -np.einsum("cij,cj->ci", rig.R, centers)  # (C, 3)
    Rt = np.concatenate([rig.R, t[:, :, None]], axis=2)  # (C, 3, 4)
    return _Frame(origin, scale, Rt, centers)


def _normalized(
    rig: CameraRig, obs: np.ndarray, observed: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Undistorted normalised coordinates, point-major.

    Parameters
    ----------
    obs : (C, N, 2) distorted pixels
    observed : (C, N) bool

    Returns
    -------
    x, y : (N, C) float ndarrays, NaN where unobserved.
    """
    K = rig.K
    with np.errstate(invalid="ignore"):
        y = (obs[..., 1] - K[:, None, 1, 2]) / K[:, None, 1, 1]  # (C, N)
        x = (obs[..., 0] - K[:, None, 0, 2] - K[:, None, 0, 1] * y) / K[:, None, 0, 0]
    dcam = np.flatnonzero(np.any(rig.dist != 0, axis=1))  # cameras with lens distortion
    if dcam.size:
        seen = observed[dcam]  # (Cd, N)
        xd = np.where(seen, x[dcam], 0.0)
        yd = np.where(seen, y[dcam], 0.0)
        xy = undistort_normalized(np.stack([xd, yd], axis=-1), rig.dist[dcam])  # (Cd, N, 2)
        x[dcam] = np.where(seen, xy[..., 0], np.nan)
        y[dcam] = np.where(seen, xy[..., 1], np.nan)
    return np.ascontiguousarray(x.T), np.ascontiguousarray(y.T)


def _dlt_blocks(Rt: np.ndarray) -> np.ndarray:
    """(4C, 16) per-camera constants of the DLT normal matrix (see :func:`_dlt`)."""
    P0, P1, P2 = Rt[:, 0], Rt[:, 1], Rt[:, 2]  # (C, 4)

    def outer(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return (a[:, :, None] * b[:, None, :]).reshape(-1, 16)  # (C, 16)

    A = outer(P2, P2)
    B = -(outer(P2, P0) + outer(P0, P2))
    D = -(outer(P2, P1) + outer(P1, P2))
    E = outer(P0, P0) + outer(P1, P1)
    return np.concatenate([A, B, D, E], axis=0)


def _dlt(Rt: np.ndarray, x: np.ndarray, y: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Weighted linear triangulation (DLT) in the conditioned frame.

    Each view contributes the rows ``x P2 - P0`` and ``y P2 - P1`` of ``A``. Expanding
    ``A^T W A = sum_c w [(x^2 + y^2) P2 P2^T - x (P2 P0^T + P0 P2^T) - y (P2 P1^T + P1 P2^T)
    + P0 P0^T + P1 P1^T]`` makes the normal matrices of all points one matrix product; the
    solution is the eigenvector of the smallest eigenvalue (batched ``np.linalg.eigh``).

    Parameters
    ----------
    Rt : (C, 3, 4) float ndarray
    x, y : (N, C) float ndarrays
        Normalised coordinates (any value where the weight is 0).
    weights : (N, C) float or bool ndarray

    Returns
    -------
    (N, 3) float ndarray
        NaN where fewer than two views have a positive weight or the solution is at infinity.
    """
    w = np.where(weights > 0, weights, 0.0)  # (N, C)
    use = w > 0
    x = np.where(use, x, 0.0)
    y = np.where(use, y, 0.0)
    S = np.concatenate([w * (x * x + y * y), w * x, w * y, w], axis=1)  # (N, 4C)
    M = (S @ _dlt_blocks(Rt)).reshape(-1, 4, 4)  # (N, 4, 4)
    _, vec = np.linalg.eigh(M)
    h = vec[:, :, 0]  # (N, 4) smallest eigenvector
    bad = (np.count_nonzero(use, axis=1) < 2) | (np.abs(h[:, 3]) < 1e-12)
    with np.errstate(divide="ignore", invalid="ignore"):
        X = h[:, :3] / h[:, 3:4]
    X[bad] = np.nan
    return X


def _sym(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(C, 9) flattened ``a b^T + b a^T`` of per-camera 3-vectors (C, 3)."""
    m = a[:, :, None] * b[:, None, :]
    return (m + m.transpose(0, 2, 1)).reshape(-1, 9)


def _gauss_newton(
    Rt: np.ndarray,
    K: np.ndarray,
    x_obs: np.ndarray,
    y_obs: np.ndarray,
    weights: np.ndarray,
    X: np.ndarray,
    iterations: int,
) -> np.ndarray:
    """Minimise the weighted squared reprojection error (undistorted pixels) from ``X``.

    The pixel residual of a view is ``A (x - x_obs, y - y_obs)`` with ``A`` the upper 2x2 of K,
    so its square is ``d^T M d`` with ``M = A^T A``. With ``dx/dX = (R0 - x R2) / z`` and
    ``dy/dX = (R1 - y R2) / z``, the normal matrix ``J^T J`` is a sum of per-camera constant
    3x3 matrices (``R_i R_j^T`` products) times per-point scalars, so for all points it is one
    matrix product, as is the gradient.

    Parameters
    ----------
    Rt : (C, 3, 4) float ndarray
    K : (C, 3, 3) float ndarray
    x_obs, y_obs : (N, C) float ndarrays
        Undistorted normalised observations.
    weights : (N, C) float or bool ndarray
    X : (N, 3) float ndarray
        Start, in the conditioned frame (NaN rows stay NaN).
    iterations : int

    Returns
    -------
    (N, 3) float ndarray
    """
    R, t = Rt[:, :, :3], Rt[:, :, 3]  # (C, 3, 3), (C, 3)
    R0, R1, R2 = R[:, 0], R[:, 1], R[:, 2]  # (C, 3)
    fx, skew, fy = K[:, 0, 0], K[:, 0, 1], K[:, 1, 1]  # (C,)
    m11, m12, m22 = fx * fx, fx * skew, skew * skew + fy * fy  # M = A^T A
    G = np.concatenate(
        [
            (R0[:, :, None] * R0[:, None, :]).reshape(-1, 9),
            (R1[:, :, None] * R1[:, None, :]).reshape(-1, 9),
            (R2[:, :, None] * R2[:, None, :]).reshape(-1, 9),
            _sym(R0, R2),
            _sym(R1, R2),
            _sym(R0, R1),
        ]
    )  # (6C, 9)
    Gg = np.concatenate([R0, R1, R2])  # (3C, 3)
    w = np.where(np.isfinite(x_obs) & (weights > 0), weights, 0.0)  # (N, C)
    ox = np.where(w > 0, x_obs, 0.0)
    oy = np.where(w > 0, y_obs, 0.0)
    ok = finite_rows(X)
    X = np.where(ok[:, None], X, 0.0)
    for _ in range(iterations):
        X0, X1, X2 = X[:, 0:1], X[:, 1:2], X[:, 2:3]  # (N, 1)
        z = X0 * R2[:, 0] + X1 * R2[:, 1] + X2 * R2[:, 2] + t[:, 2]  # (N, C)
        front = (z > 1e-12) & (w > 0)
        iz = np.where(front, 1.0 / np.where(front, z, 1.0), 0.0)
        x = (X0 * R0[:, 0] + X1 * R0[:, 1] + X2 * R0[:, 2] + t[:, 0]) * iz
        y = (X0 * R1[:, 0] + X1 * R1[:, 1] + X2 * R1[:, 2] + t[:, 1]) * iz
        dx, dy = x - ox, y - oy
        wiz = w * iz  # (N, C), 0 where unused
        q = wiz * iz
        S = np.concatenate(
            [
                q * m11,
                q * m22,
                q * (m11 * x * x + m22 * y * y + 2 * m12 * x * y),
                -q * (m11 * x + m12 * y),
                -q * (m22 * y + m12 * x),
                q * m12,
            ],
            axis=1,
        )  # (N, 6C)
        JtJ = (S @ G).reshape(-1, 3, 3)
        ex = wiz * (m11 * dx + m12 * dy)  # (N, C)
        ey = wiz * (m12 * dx + m22 * dy)
        Jtr = np.concatenate([ex, ey, -(ex * x + ey * y)], axis=1) @ Gg  # (N, 3)
        # Levenberg damping keeps the solve well posed for near-degenerate geometry.
        JtJ += 1e-9 * np.trace(JtJ, axis1=1, axis2=2)[:, None, None] * np.eye(3)
        good = ok & (np.count_nonzero(q, axis=1) >= 2)
        good &= np.linalg.det(JtJ) > 0
        step = np.zeros_like(X)
        if np.any(good):
            step[good] = np.linalg.solve(JtJ[good], -Jtr[good][..., None])[..., 0]
        X = X + step
    X[~ok] = np.nan
    return X


def _scoring_matrix(frame: _Frame, K: np.ndarray) -> np.ndarray:
    """(3, 4, C) float32 matrices: ``X @ W[r, :3] + W[r, 3]`` is row r of the homogeneous
    undistorted pixel ``(u w, v w, w)`` of the conditioned point X in every camera."""
    KRt = K @ frame.Rt  # (C, 3, 4)
    return np.ascontiguousarray(KRt.transpose(1, 2, 0), dtype=np.float32)


def _score_hypotheses(
    W: np.ndarray, X: np.ndarray, obs_u: np.ndarray, obs_v: np.ndarray, thr2: float
) -> tuple[np.ndarray, np.ndarray]:
    """Inliers and lexicographic score of hypotheses (undistorted-pixel error, float32).

    Parameters
    ----------
    W : (3, 4, C) or (3, 4, n, C) float32 ndarray
        From :func:`_scoring_matrix`, or per point (a subset of views for pre-scoring).
    X : (H, n, 3) float ndarray
        Hypotheses in the conditioned frame (NaN = no hypothesis).
    obs_u, obs_v : (n, C) float32 ndarrays
        Undistorted pixel observations (NaN where unobserved).
    thr2 : float
        Squared inlier threshold in pixels.

    Returns
    -------
    is_in : (H, n, C) bool ndarray
        Observed, in front of the camera, and within the threshold.
    key : (H, n) float32 ndarray
        Inlier count minus the sum of squared inlier errors over ``thr2 (C + 1)`` (< 1), so that
        the largest key has the most inliers and, among those, the smallest error.
    """
    C = obs_u.shape[1]
    Xf = X.astype(np.float32)
    x0, x1, x2 = (np.ascontiguousarray(Xf[..., k]) for k in range(3))  # (H, n)
    # the products x_k W[r, k] are outer products over the views: einsum writes them twice as
    # fast as a broadcast multiply over the short last axis (one rounded product each: the
    # same values)
    outer = "hn,c->hnc" if W.ndim == 3 else "hn,nc->hnc"

    def row(r: int) -> np.ndarray:  # (H, n, C); broadcasting beats BLAS for this 3-deep product
        out = np.einsum(outer, x0, W[r, 0])
        out += np.einsum(outer, x1, W[r, 1])
        out += np.einsum(outer, x2, W[r, 2])
        out += W[r, 3]
        return out

    pu, pv, w = row(0), row(1), row(2)
    with np.errstate(divide="ignore", invalid="ignore"):
        iz = np.reciprocal(w)
        du = pu * iz
        du -= obs_u
        dv = pv * iz
        dv -= obs_v
        e2 = du * du
        e2 += dv * dv
        is_in = e2 < thr2  # NaN (unobserved / no hypothesis) -> False
        is_in &= w > 0
    # key = sum over inlier views of (1 - e2 / (thr2 (C + 1))), reduced by a matrix product.
    score = np.where(is_in, np.float32(1.0) - e2 * np.float32(1.0 / (thr2 * (C + 1))), 0.0)
    key = score.astype(np.float32, copy=False) @ np.ones(C, np.float32)  # (H, n)
    return is_in, key


def _sample_pairs(
    rng: np.random.Generator, order: np.ndarray, n_obs: np.ndarray, count: int
) -> tuple[np.ndarray, np.ndarray]:
    """Draw ``count`` random pairs of distinct observed views per point.

    Parameters
    ----------
    order : (N, C) int ndarray
        Per point, camera indices with the observed ones first.
    n_obs : (N,) int ndarray
        Number of observed views (>= 2).

    Returns
    -------
    a, b : (count, N) int ndarrays of camera indices, ``a != b``.
    """
    N = n_obs.shape[0]
    i = np.floor(rng.random((count, N)) * n_obs).astype(np.intp)  # (H, N)
    j = np.floor(rng.random((count, N)) * (n_obs - 1)).astype(np.intp)
    j += j >= i
    cols = np.arange(N)
    return order[cols, i], order[cols, j]


def _rays(frame: _Frame, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """(n, C, 3) world ray directions ``R^T (x, y, 1)`` (not normalised)."""
    R = frame.Rt[:, :, :3]  # (C, 3, 3)
    return np.stack([R[:, 0, k] * x + R[:, 1, k] * y + R[:, 2, k] for k in range(3)], axis=-1)


def _midpoints(
    frame: _Frame,
    x: np.ndarray,
    y: np.ndarray,
    a: np.ndarray,
    b: np.ndarray,
    rays: np.ndarray | None = None,
) -> np.ndarray:
    """Closed-form two-view triangulation: midpoint of the common perpendicular of two rays.

    Parameters
    ----------
    frame : _Frame
        The rig in the conditioned frame.
    x, y : (n, C) float ndarrays
        Undistorted normalised observations.
    a, b : (H, n) int ndarrays
        Camera indices of each hypothesis.
    rays : (n, C, 3) float ndarray, optional
        Precomputed :func:`_rays` (worth it when C is small next to the hypotheses drawn);
        otherwise only the rays of the drawn views are computed.

    Returns
    -------
    X : (H, n, 3) hypotheses, NaN for (near-)parallel rays or points behind either camera.
    """
    n, C = x.shape
    flat = np.arange(n) * C
    Rf = frame.Rt[:, :, :3].reshape(C, 9)

    def ray(cam: np.ndarray) -> np.ndarray:  # (H, n, 3) world direction R^T (x, y, 1)
        if rays is not None:
            return rays.reshape(-1, 3)[cam + flat]
        u, v = x.ravel()[cam + flat], y.ravel()[cam + flat]  # (H, n)
        r = Rf[cam]  # (H, n, 9)
        return np.stack([r[..., k] * u + r[..., 3 + k] * v + r[..., 6 + k] for k in range(3)], -1)

    da, db = ray(a), ray(b)
    ca, cb = frame.centers[a], frame.centers[b]  # (H, n, 3)
    w0 = ca - cb
    aa = np.einsum("hni,hni->hn", da, da)
    bb = np.einsum("hni,hni->hn", da, db)
    cc = np.einsum("hni,hni->hn", db, db)
    d = np.einsum("hni,hni->hn", da, w0)
    e = np.einsum("hni,hni->hn", db, w0)
    denom = aa * cc - bb * bb
    ok = denom > 1e-10 * aa * cc  # not (near-)parallel
    denom = np.where(ok, denom, 1.0)
    s = (bb * e - cc * d) / denom  # depth along ray a (its camera z is 1 per unit)
    t = (aa * e - bb * d) / denom  # depth along ray b
    X = ca + s[..., None] * da
    X += cb
    X += t[..., None] * db
    X *= 0.5
    X[~(ok & (s > 0) & (t > 0))] = np.nan
    return X


def _inlier_ratio_bound(n_inl: np.ndarray, n_obs: np.ndarray, confidence: float) -> np.ndarray:
    """Hypotheses needed to draw an all-inlier pair with ``confidence`` (pairs without
    replacement)."""
    p = n_inl * (n_inl - 1) / np.maximum(n_obs * (n_obs - 1), 1)  # (N,)
    with np.errstate(divide="ignore", invalid="ignore"):
        need = np.log1p(-confidence) / np.log1p(-np.clip(p, 0.0, 1.0 - 1e-12))
    need = np.where(p >= 1.0 - 1e-12, 1.0, need)
    return np.where(p > 0, np.ceil(need), np.inf)


# -- public API ------------------------------------------------------------------------------


def triangulate_points(rig: CameraRig, observations: np.ndarray) -> np.ndarray:
    """Linear (DLT) triangulation of every point over all its observed views.

    Parameters
    ----------
    rig : CameraRig
        C calibrated cameras.
    observations : (C, N, 2) float ndarray
        Distorted pixel coordinates; NaN where a camera does not observe a point.

    Returns
    -------
    (N, 3) float64 ndarray
        World points in metres; NaN where fewer than 2 views observe the point.

    Raises
    ------
    ValidationError
        If ``observations`` does not have shape (C, N, 2) for the rig's C cameras.

    Notes
    -----
    Observations are undistorted to normalised coordinates (the same result as
    ``rig.normalized``, by Newton steps with an analytic Jacobian), the world is conditioned
    (centred on the rig and scaled to unit camera distance), and each point's ``A^T A`` (4x4)
    is solved with one batched ``np.linalg.eigh``.

    Examples
    --------
    >>> import numpy as np
    >>> from pointtraj.camera import Camera, CameraRig
    >>> rig = CameraRig([Camera.look_at(f"c{i}", [3 * np.cos(a), 3 * np.sin(a), 1.0],
    ...                  [0, 0, 1.0], (640, 480), 500.0) for i, a in enumerate([0, 1.5, 3])])
    >>> X = np.array([[0.1, -0.2, 1.3]])
    >>> np.allclose(triangulate_points(rig, rig.project(X).pixels), X, atol=1e-9)
    True
    """
    obs = _check_observations(rig, observations)
    observed = finite_rows(obs)  # (C, N)
    frame = _conditioned_frame(rig)
    x, y = _normalized(rig, obs, observed)
    Xn = _dlt(frame.Rt, x, y, observed.T)
    return frame.origin + frame.scale * Xn


def triangulate_ransac(
    rig: CameraRig,
    observations: np.ndarray,
    config: TriangulationConfig = TriangulationConfig(),  # frozen, so a safe default
    *,
    chunk_size: int | None = None,
) -> Triangulation:
    """Robust triangulation: RANSAC over views, DLT + Gauss-Newton refit, visibility.

    Parameters
    ----------
    rig : CameraRig
        C calibrated cameras.
    observations : (C, N, 2) float ndarray
        Distorted pixel coordinates; NaN where a camera does not observe a point.
    config : TriangulationConfig
        Thresholds and RANSAC settings.
    chunk_size : int, optional
        Points whose hypotheses are scored at once (default: chosen so that a chunk's
        (hypotheses, points, cameras) score arrays stay around 8 MiB each). The refit runs on
        chunks of at least this size holding about 1M (point, camera) pairs, so memory stays
        bounded whatever N.

    Returns
    -------
    Triangulation
        Points (N, 3) (NaN where fewer than ``config.min_views`` inlier views), inliers and
        errors (C, N), visibility (N, C) and mean inlier error (N,).

    Raises
    ------
    ValidationError
        On a wrong ``observations`` shape or infinite values.

    Notes
    -----
    Per point, pairs of observed views are drawn in rounds of ``config.batch``; each pair gives
    a closed-form midpoint hypothesis scored on all observed views by (inlier count, then the
    sum of squared inlier errors). A point stops when its best inlier ratio makes a further
    all-inlier draw unnecessary at ``config.confidence`` or after ``config.iterations``
    hypotheses. Scores use the undistorted-pixel error (observations are undistorted once); the
    returned errors and inliers use the full distorted projection of :meth:`CameraRig.project`.
    The refit solves the DLT on the inliers, runs ``config.refine_iterations`` Gauss-Newton
    steps on the reprojection error, re-evaluates inliers, and repeats once (local
    optimisation). Visibility follows the paper (Section 5, step 2):
    ``V(X, c) = exp(-(e_c / sigma)^2)``.
    """
    if not isinstance(config, TriangulationConfig):
        raise ValidationError(
            f"config: expected a TriangulationConfig, got {type(config).__name__}"
        )
    obs = _check_observations(rig, observations)
    C, N = obs.shape[:2]
    frame = _conditioned_frame(rig)
    rng = np.random.default_rng(config.seed)
    batch = min(int(config.batch), int(config.iterations))
    if chunk_size is None:
        chunk_size = _MAX_ELEMENTS // max(C * batch, 1)
    chunk_size = max(1, int(chunk_size))
    # The refit works on (n, 6C) arrays: process the points in outer chunks of bounded size.
    outer = max(chunk_size, _MAX_REFIT_ELEMENTS // max(C, 1))
    points = np.full((N, 3), np.nan)
    inliers = np.zeros((C, N), bool)
    errors = np.full((C, N), np.nan)
    visibility = np.zeros((N, C), np.float32)
    mean_error = np.full(N, np.nan)
    for start in range(0, N, outer):
        sl = slice(start, min(start + outer, N))
        part = _triangulate_chunk(rig, frame, obs[:, sl], config, rng, batch, chunk_size)
        points[sl], inliers[:, sl], errors[:, sl], visibility[sl], mean_error[sl] = part
    logger.debug("triangulated %d of %d points", int(np.isfinite(points[:, 0]).sum()), N)
    return Triangulation(points, inliers, errors, visibility, mean_error)


def _triangulate_chunk(
    rig: CameraRig,
    frame: _Frame,
    obs: np.ndarray,
    config: TriangulationConfig,
    rng: np.random.Generator,
    batch: int,
    chunk_size: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`triangulate_ransac` on (C, n, 2) observations; returns its five arrays."""
    C, N = obs.shape[:2]
    observed = finite_rows(obs)  # (C, N)
    n_obs = np.count_nonzero(observed, axis=0)  # (N,)
    x, y = _normalized(rig, obs, observed)  # (N, C) each
    K = rig.K
    obs_u = (K[:, 0, 0] * x + K[:, 0, 1] * y + K[:, 0, 2]).astype(np.float32)  # (N, C)
    obs_v = (K[:, 1, 1] * y + K[:, 1, 2]).astype(np.float32)  # undistorted pixels

    thr2 = float(config.threshold_px) ** 2
    W = _scoring_matrix(frame, K)
    inl = np.zeros((N, C), bool)
    cand = np.flatnonzero(n_obs >= max(2, config.min_views))
    for start in range(0, cand.size, chunk_size):
        idx = cand[start : start + chunk_size]
        inl[idx] = _ransac_chunk(
            rng,
            frame,
            W,
            obs_u[idx],
            obs_v[idx],
            x[idx],
            y[idx],
            observed[:, idx],
            n_obs[idx],
            thr2,
            batch,
            config,
        )
    del obs_u, obs_v

    # Refit on the inliers: DLT, Gauss-Newton, then re-evaluate the inliers with the full
    # (distorted) projection. Points whose inlier set changed are refit once more.
    Xn = _dlt(frame.Rt, x, y, inl)
    Xn = _gauss_newton(frame.Rt, K, x, y, inl, Xn, config.refine_iterations)
    X = frame.origin + frame.scale * Xn
    proj = rig.project(X)
    errors = pixel_distance(proj.pixels, obs)  # (C, N)
    with np.errstate(invalid="ignore"):
        new = (errors < config.threshold_px).T  # (N, C)
    changed = np.flatnonzero(np.any(new != inl, axis=1) & (new.sum(axis=1) >= config.min_views))
    if changed.size:
        Xc = _dlt(frame.Rt, x[changed], y[changed], new[changed])
        Xc = _gauss_newton(
            frame.Rt,
            K,
            x[changed],
            y[changed],
            new[changed],
            Xc,
            max(config.refine_iterations, 1),
        )
        X[changed] = frame.origin + frame.scale * Xc
        pc = rig.project(X[changed])
        proj.pixels[:, changed] = pc.pixels
        proj.in_image[:, changed] = pc.in_image
        errors[:, changed] = pixel_distance(pc.pixels, obs[:, changed])
        with np.errstate(invalid="ignore"):
            new[changed] = (errors[:, changed] < config.threshold_px).T
    inl = new.T  # (C, N)
    failed = (np.count_nonzero(inl, axis=0) < config.min_views) | ~finite_rows(X)
    X[failed] = np.nan
    inl = inl & ~failed
    errors[:, failed] = np.nan
    n_inl = inl.sum(axis=0)
    mean_error = np.where(inl, errors, 0.0).sum(axis=0) / np.maximum(n_inl, 1)
    mean_error[failed] = np.nan
    visibility = _visibility(errors, proj.in_image, config.sigma_px)
    logger.debug(
        "chunk: %d of %d points triangulated (%d with enough views, %d refit twice)",
        int((~failed).sum()),
        N,
        cand.size,
        changed.size,
    )
    return X, inl, errors, visibility, mean_error


def _visibility(errors: np.ndarray, in_image: np.ndarray, sigma_px: float) -> np.ndarray:
    """(N, C) float32 ``exp(-(e / sigma)^2)`` from (C, N) errors, 0 where NaN or not in image."""
    with np.errstate(invalid="ignore"):
        v = np.exp(-np.square(errors / sigma_px))
    v = np.where(in_image & np.isfinite(errors), v, 0.0)
    return np.ascontiguousarray(v.T, dtype=np.float32)


def _ransac_chunk(
    rng: np.random.Generator,
    frame: _Frame,
    W: np.ndarray,
    obs_u: np.ndarray,
    obs_v: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
    observed: np.ndarray,
    n_obs: np.ndarray,
    thr2: float,
    batch: int,
    config: TriangulationConfig,
) -> np.ndarray:
    """Inlier masks (n, C) of the best hypothesis for one chunk of points with >= 2 views.

    ``obs_u``/``obs_v`` are (n, C) float32 undistorted pixels, ``x``/``y`` (n, C) normalised
    coordinates.
    """
    C, n = observed.shape
    order = observed_first(observed).T  # (n, C) observed cameras first (only those are drawn)
    # Pre-scoring for large rigs: all hypotheses are scored on a random subset of each point's
    # observed views, and only the best one on all views (cost H S + C instead of H C).
    S = _PRESCORE_VIEWS
    pre = C > 2 * S
    if pre:
        keys = rng.random((n, C))
        keys[~observed.T] = 2.0
        sub = np.argsort(keys, axis=1)[:, :S]  # (n, S) random observed views first
        sub_u = np.take_along_axis(obs_u, sub, axis=1)  # (n, S)
        sub_v = np.take_along_axis(obs_v, sub, axis=1)
        sub_W = W[:, :, sub]  # (3, 4, n, S)
    # Rays of all views cost n C; those of the drawn pairs 2 H n per round.
    rays = _rays(frame, x, y) if C <= 2 * batch else None
    best_key = np.full(n, -np.inf, dtype=np.float32)
    best_inl = np.zeros((n, C), bool)
    drawn = np.zeros(n, np.int64)
    active = np.arange(n)
    while active.size:
        # Active points have all drawn the same number so far; never exceed ``iterations``.
        count = min(batch, int(config.iterations) - int(drawn[active[0]]))
        a, b = _sample_pairs(rng, order[active], n_obs[active], count)  # (H, n_a)
        X = _midpoints(
            frame, x[active], y[active], a, b, None if rays is None else rays[active]
        )  # (H, n_a, 3)
        cols = np.arange(active.size)
        if pre:
            _, pre_key = _score_hypotheses(
                sub_W[:, :, active], X, sub_u[active], sub_v[active], thr2
            )
            X = X[np.argmax(pre_key, axis=0), cols][None]  # (1, n_a, 3)
        is_in, key = _score_hypotheses(W, X, obs_u[active], obs_v[active], thr2)
        h = np.argmax(key, axis=0)  # (n_a,)
        k = key[h, cols]
        better = k > best_key[active]
        upd = active[better]
        best_key[upd] = k[better]
        best_inl[upd] = is_in[h[better], cols[better]]
        drawn[active] += count
        n_best = np.count_nonzero(best_inl[active], axis=1)
        need = _inlier_ratio_bound(n_best, n_obs[active], config.confidence)
        done = (drawn[active] >= np.minimum(need, config.iterations)) | (n_best == n_obs[active])
        active = active[~done]
    return best_inl


def compute_visibility(
    rig: CameraRig,
    points: np.ndarray,
    observations: np.ndarray | None,
    sigma_px: float,
    occlusion_depth: float | None = None,
    *,
    occlusion_cell_px: float | None = None,
) -> np.ndarray:
    """Probability of visibility ``V(X, c) = exp(-(e_c / sigma)^2)`` (paper Section 5, step 2).

    Parameters
    ----------
    rig : CameraRig
        C cameras.
    points : (N, 3) float ndarray
        World points; NaN rows get visibility 0 everywhere.
    observations : (C, N, 2) float ndarray or None
        Distorted pixel observations (NaN = unobserved). Where a camera has no observation the
        visibility is 0. With ``None`` the visibility is projection-based: 1 wherever the point
        projects inside the image in front of the camera.
    sigma_px : float
        Reprojection-error tolerance sigma in pixels.
    occlusion_depth : float, optional
        If given, also set the visibility to 0 where :func:`occlusion_test` with this depth
        tolerance (metres) finds the point behind the surface formed by ``points``.
    occlusion_cell_px : float, optional
        Z-buffer cell size for the occlusion test (default: automatic, see
        :func:`occlusion_test`).

    Returns
    -------
    (N, C) float32 ndarray
        Values in [0, 1]; 0 outside the image, behind the camera, unobserved, or occluded.

    Raises
    ------
    ValidationError
        On wrong shapes or a non-positive ``sigma_px``.

    Examples
    --------
    >>> import numpy as np
    >>> from pointtraj.camera import Camera, CameraRig
    >>> rig = CameraRig([Camera.look_at("a", [3, 0, 1], [0, 0, 1], (640, 480), 500.0)])
    >>> X = np.array([[0.0, 0.0, 1.0], [6.0, 0.0, 1.0]])  # in front, behind
    >>> compute_visibility(rig, X, None, 1.0)[:, 0].tolist()
    [1.0, 0.0]
    """
    if not isinstance(rig, CameraRig):
        raise ValidationError(f"rig: expected a CameraRig, got {type(rig).__name__}")
    X = check_array("points", points, (None, 3))
    if not sigma_px > 0:
        raise ValidationError(f"sigma_px must be > 0, got {sigma_px!r}")
    proj = rig.project(X)
    if observations is None:
        vis = proj.in_image.astype(np.float32).T  # (N, C)
    else:
        obs = check_array("observations", observations, (len(rig), X.shape[0], 2))
        e = pixel_distance(proj.pixels, obs)  # (C, N), NaN where unobserved
        vis = _visibility(e, proj.in_image, sigma_px)
    if occlusion_depth is not None:
        occluded = occlusion_test(rig, X, occlusion_depth, cell_px=occlusion_cell_px)  # (N, C)
        vis = np.where(occluded, 0.0, vis)
    return np.ascontiguousarray(vis, dtype=np.float32)
