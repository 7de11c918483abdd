"""Shared geometry, one routine each: rigid fits, rotations, camera axis angles, lens distortion.

Everything here works on numpy arrays and sits at the bottom of the import graph (it imports
only :mod:`pointtraj.errors`, numpy and, lazily, scipy), so that :mod:`pointtraj.camera`, the
reconstruction, the affinity and the calibration all use the same implementation:

- :func:`fit_rigid`: batched Kabsch/Umeyama, ``dst ≈ s R src + t`` with optional weights, scale
  and centring (the local rigid transforms of the affinity, the similarity between rigs);
  :func:`fit_rigid_groups`, the same fit for ragged groups of points (the body-part poses);
- :func:`rotation_from_triads`: the closed-form rotation of two vector pairs, RANSAC's hypothesis
  (the affinity's local fits), and :func:`ransac_rigid_groups`, RANSAC rigid fits of many point
  groups at once (the body-part poses of :mod:`pointtraj.segments`);
- :func:`rotation_from_rodrigues`, :func:`rodrigues_from_rotation`: axis-angle vectors, both
  through ``scipy.spatial.transform.Rotation``;
- :func:`mean_rotation`, :func:`rotation_angle_deg`: chordal mean of rotations and the angle
  between rotations;
- :func:`axis_angles`: angles between the optical axes of a rig's cameras;
- :func:`parse_up`, :func:`detect_up`, :func:`resolve_up`: the world's up direction, set by
  the user (``"+z"``, ``"-y"``, 3 numbers) or detected from the cameras (a ring's plane, or
  the cameras' mean image-up direction), for floors and orbits in frames that are not z-up;
- :func:`distort_normalized`, :func:`undistort_normalized`: OpenCV's lens model
  ``(k1, k2, p1, p2, k3, k4, k5, k6)`` and its inverse (``benchmarks/bench_undistort.py``
  compares the inverse with ``cv2.undistortPoints``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from .errors import check_array

if TYPE_CHECKING:
    from .camera import CameraRig

__all__ = [
    "N_DIST",
    "RigidFit",
    "fit_rigid",
    "fit_rigid_groups",
    "RansacFit",
    "ransac_rigid_groups",
    "rotation_from_triads",
    "squared_norm",
    "finite_rows",
    "observed_first",
    "pixel_distance",
    "rotation_from_rodrigues",
    "rodrigues_from_rotation",
    "mean_rotation",
    "rotation_angle_deg",
    "axis_angles",
    "UP_CHOICES",
    "parse_up",
    "detect_up",
    "resolve_up",
    "distort_normalized",
    "undistort_normalized",
]

#: Number of distortion coefficients (OpenCV's rational model ``k1 k2 p1 p2 k3 k4 k5 k6``).
N_DIST = 8

#: Undistortion: fixed-point steps before the Newton refinement, Newton steps, and the larger
#: number of fixed-point steps for entries where the first pass did not converge.
_UNDISTORT_FIXED_POINT = 3
_UNDISTORT_NEWTON = 3
_UNDISTORT_FIXED_POINT_SLOW = 30
#: A last Newton step below this (normalised units) counts as converged: Newton converges
#: quadratically, so the error left is near 1e-16.
_UNDISTORT_CONVERGED = 1e-9


# -- rigid fits ----------------------------------------------------------------------------------
class RigidFit(NamedTuple):
    """Batched similarities ``dst ≈ s R src + t`` from :func:`fit_rigid`.

    Attributes
    ----------
    scale : (B,) float64 ndarray
        ``s`` (1 without ``with_scale``).
    rotation : (B, 3, 3) float64 ndarray
        Proper rotations (``det R = +1``).
    translation : (B, 3) float64 ndarray
        ``t`` (0 without ``center``).
    valid : (B,) bool ndarray
        False where the fit is degenerate: the source points are coincident, or the
        cross-covariance has rank below 2 (collinear points), so the rotation is not unique.
    """

    scale: np.ndarray
    rotation: np.ndarray
    translation: np.ndarray
    valid: np.ndarray


def fit_rigid(
    src: np.ndarray,
    dst: np.ndarray,
    weights: np.ndarray | None = None,
    *,
    with_scale: bool = False,
    center: bool = True,
) -> RigidFit:
    """Least-squares rigid or similarity transforms of B point sets at once (Kabsch/Umeyama).

    Minimises ``Σ_k w_k ‖dst_k - (s R src_k + t)‖²`` per set, with R a proper rotation (the
    determinant sign fix of Kabsch and Umeyama). With ``center`` the sets are centred on their
    (weighted) means and t is fitted; without it ``t = 0``: the rotation best aligning the
    vectors as given (for displacements relative to an anchor point).

    Parameters
    ----------
    src, dst : (B, N, 3) float ndarray
        Corresponding points (or vectors), B sets of N.
    weights : (B, N) float ndarray, optional
        Non-negative weight per pair; 0 leaves a pair out.
    with_scale : bool
        Also fit the scale s (Umeyama's similarity); otherwise ``s = 1``.
    center : bool
        Centre the sets and fit the translation t.

    Returns
    -------
    RigidFit
        ``scale`` (B,), ``rotation`` (B, 3, 3), ``translation`` (B, 3) and ``valid`` (B,).

    Raises
    ------
    ValidationError
        If ``src`` is not (B, N, 3), or ``dst`` or ``weights`` does not match it.

    References
    ----------
    W. Kabsch, "A solution for the best rotation to relate two sets of vectors", Acta Cryst.
    A32 (1976). S. Umeyama, "Least-squares estimation of transformation parameters between two
    point patterns", IEEE TPAMI 13(4) (1991), eqs. (40)-(42).

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> a = rng.normal(size=(1, 10, 3))
    >>> fit = fit_rigid(a, 2.0 * a + [1.0, 2.0, 3.0], with_scale=True)
    >>> round(float(fit.scale[0]), 6), bool(np.allclose(fit.rotation[0], np.eye(3)))
    (2.0, True)
    >>> np.round(fit.translation[0], 6).tolist()
    [1.0, 2.0, 3.0]
    """
    a = check_array("src", src, (None, None, 3), dtype=np.float64)
    b = check_array("dst", dst, a.shape, dtype=np.float64)
    w = None if weights is None else check_array("weights", weights, a.shape[:2], dtype=np.float64)
    B = a.shape[0]
    mu_a = mu_b = np.zeros((B, 1, 3))
    if center:
        if w is None:
            mu_a, mu_b = a.mean(axis=1, keepdims=True), b.mean(axis=1, keepdims=True)  # (B, 1, 3)
        else:
            wsum = np.maximum(w.sum(axis=1), 1e-300)[:, None, None]  # (B, 1, 1)
            mu_a = (a * w[..., None]).sum(axis=1, keepdims=True) / wsum
            mu_b = (b * w[..., None]).sum(axis=1, keepdims=True) / wsum
        a, b = a - mu_a, b - mu_b
    aw = a if w is None else a * w[..., None]
    H = np.swapaxes(aw, 1, 2) @ b  # (B, 3, 3) = Σ w a b^T
    R, S, d = _kabsch(H)
    # Rank below 2 (collinear or coincident points: all-zero source sets included).
    valid = S[:, 1] > 1e-12 * np.maximum(S[:, 0], 1e-300)
    if with_scale:
        # Umeyama's eq. (42): s = tr(S D) / σ²_src (the 1/n of both cancels).
        var_a = np.einsum("bni,bni->b", aw, a)  # (B,) Σ w |a|²
        S[:, 2] *= d
        s = S.sum(axis=1) / np.where(var_a > 0, var_a, 1.0)
    else:
        s = np.ones(B)
    t = np.zeros((B, 3))
    if center:
        t = mu_b[:, 0] - s[:, None] * np.einsum("bij,bj->bi", R, mu_a[:, 0])  # (B, 3)
    return RigidFit(s, R, t, valid)


def _kabsch(H: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The proper rotation maximising ``tr(R H)`` for cross-covariances ``H = Σ w a b^T``.

    Parameters
    ----------
    H : (B, 3, 3) float ndarray

    Returns
    -------
    R : (B, 3, 3) float ndarray
        ``V diag(1, 1, d) U^T`` from ``H = U S V^T`` (Kabsch's determinant sign fix).
    S : (B, 3) float ndarray
        Singular values of ``H``.
    d : (B,) float ndarray
        -1 where the best orthogonal map was a reflection, else 1.
    """
    U, S, Vt = np.linalg.svd(H)
    V = np.swapaxes(Vt, 1, 2)
    Ut = np.swapaxes(U, 1, 2)
    d = np.sign(np.linalg.det(V @ Ut))  # -1 where the best orthogonal map is a reflection
    d[d == 0] = 1.0
    V[:, :, 2] *= d[:, None]
    return V @ Ut, S, d  # (B, 3, 3) = V diag(1, 1, d) U^T


def fit_rigid_groups(
    src: np.ndarray,
    dst: np.ndarray,
    group: np.ndarray,
    num_groups: int,
    weights: np.ndarray | None = None,
) -> RigidFit:
    """Least-squares rigid transforms ``dst ≈ R src + t`` of G ragged point groups at once.

    The same fit as :func:`fit_rigid` (centred, weighted Kabsch with the determinant sign
    fix), for points given as one flat list with a group index each rather than as a padded
    (B, N, 3) batch: the sums run by ``numpy.bincount``, so memory is O(N + G) however unequal
    the groups are.

    Parameters
    ----------
    src, dst : (N, 3) float ndarray
        Corresponding points.
    group : (N,) int ndarray
        Group of each pair, in ``[0, num_groups)``.
    num_groups : int
        G.
    weights : (N,) float ndarray, optional
        Non-negative weight per pair; 0 leaves a pair out.

    Returns
    -------
    RigidFit
        ``scale`` (G,) ones, ``rotation`` (G, 3, 3), ``translation`` (G, 3), ``valid`` (G,):
        False for a group with fewer than 3 weighted pairs or collinear points.

    Raises
    ------
    ValidationError
        If the shapes do not match.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> a = rng.normal(size=(8, 3))
    >>> fit = fit_rigid_groups(a, a + [1.0, 0.0, 0.0], np.array([0] * 4 + [1] * 4), 2)
    >>> (np.round(fit.translation, 6) + 0.0).tolist(), fit.valid.tolist()
    ([[1.0, 0.0, 0.0], [1.0, 0.0, 0.0]], [True, True])
    """
    a = check_array("src", src, (None, 3), dtype=np.float64)
    b = check_array("dst", dst, a.shape, dtype=np.float64)
    g = check_array("group", group, a.shape[:1], dtype=np.int64)
    w = np.ones(len(a)) if weights is None else check_array("weights", weights, g.shape)
    w = np.asarray(w, dtype=np.float64)
    G = int(num_groups)
    wsum = np.bincount(g, weights=w, minlength=G)  # (G,)
    npos = np.bincount(g, weights=(w > 0).astype(np.float64), minlength=G)
    safe = np.where(wsum > 0, wsum, 1.0)
    mu_a = np.stack([np.bincount(g, weights=w * a[:, k], minlength=G) for k in range(3)], 1)
    mu_b = np.stack([np.bincount(g, weights=w * b[:, k], minlength=G) for k in range(3)], 1)
    mu_a, mu_b = mu_a / safe[:, None], mu_b / safe[:, None]  # (G, 3)
    ac, bc = a - mu_a[g], b - mu_b[g]  # (N, 3)
    H = np.empty((G, 3, 3))
    for i in range(3):
        for j in range(3):
            H[:, i, j] = np.bincount(g, weights=w * ac[:, i] * bc[:, j], minlength=G)
    R, S, _ = _kabsch(H)
    valid = (npos >= 3) & (S[:, 1] > 1e-12 * np.maximum(S[:, 0], 1e-300))
    t = mu_b - np.einsum("gij,gj->gi", R, mu_a)  # (G, 3)
    return RigidFit(np.ones(G), R, t, valid)


class RansacFit(NamedTuple):
    """Robust rigid transforms of point groups from :func:`ransac_rigid_groups`.

    Attributes
    ----------
    rotation : (G, 3, 3) float64 ndarray
        NaN where ``valid`` is False.
    translation : (G, 3) float64 ndarray
        NaN where ``valid`` is False.
    valid : (G,) bool ndarray
        A transform was found (at least ``min_inliers`` inliers, non-degenerate).
    inlier : (N,) bool ndarray
        Pairs within the threshold of their group's final transform.
    inliers : (G,) int64 ndarray
        Inlier count per group.
    residual : (G,) float64 ndarray
        Root mean square residual ``‖dst - (R src + t)‖`` over the inliers (NaN without).
    """

    rotation: np.ndarray
    translation: np.ndarray
    valid: np.ndarray
    inlier: np.ndarray
    inliers: np.ndarray
    residual: np.ndarray


def ransac_rigid_groups(
    src: np.ndarray,
    dst: np.ndarray,
    group: np.ndarray,
    num_groups: int,
    *,
    threshold: float,
    iterations: int,
    rng: np.random.Generator,
    min_inliers: int = 3,
    refinements: int = 2,
    score_points: int | None = 2000,
) -> RansacFit:
    """RANSAC rigid fits ``dst ≈ R src + t`` of G ragged point groups, vectorised over groups.

    A hypothesis per group is the rigid map of a random 3-point sample (the closed-form TRIAD
    alignment :func:`rotation_from_triads`, as the affinity's local fits use); hypotheses are
    scored by MSAC (the sum of ``min(r², threshold²)`` over the group), the best is refitted on
    its inliers by :func:`fit_rigid_groups`, and the inliers are re-selected and refitted
    ``refinements`` times. Points are scored one hypothesis at a time, so memory is O(N + G H),
    and on at most ``score_points`` per group, so time is O(G H score_points + N).

    Parameters
    ----------
    src, dst : (N, 3) float ndarray
        Corresponding points.
    group : (N,) int ndarray
        Group of each pair, in ``[0, num_groups)``.
    num_groups : int
        G.
    threshold : float
        Inlier distance, in the points' units.
    iterations : int
        Hypotheses per group, H.
    rng : numpy.random.Generator
        Draws the samples.
    min_inliers : int
        Fewest inliers (and pairs) a group needs for a transform (at least 3).
    refinements : int
        Inlier re-selections after the first refit.
    score_points : int or None
        Score the hypotheses on at most this many random members of each group (None: all);
        the refits use every member.

    Returns
    -------
    RansacFit

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> a = rng.normal(size=(40, 3))
    >>> b = a @ rotation_from_rodrigues([0.0, 0.0, 0.5]).T + 1.0
    >>> b[:5] += 3.0  # five outliers
    >>> fit = ransac_rigid_groups(a, b, np.zeros(40, int), 1, threshold=0.01, iterations=32, rng=rng)
    >>> int(fit.inliers[0]), bool(np.allclose(fit.translation[0], 1.0))
    (35, True)
    """
    a = check_array("src", src, (None, 3), dtype=np.float64)
    b = check_array("dst", dst, a.shape, dtype=np.float64)
    g = check_array("group", group, a.shape[:1], dtype=np.int64)
    G, H, N = int(num_groups), int(iterations), len(a)
    thr2 = float(threshold) ** 2
    min_inliers = max(3, int(min_inliers))
    order = np.argsort(g, kind="stable")
    counts = np.bincount(g, minlength=G)  # (G,)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])  # (G,)
    n = np.maximum(counts, 1)[:, None]  # (G, 1)
    # three distinct members per hypothesis (distinct where the group has three)
    k1 = (rng.random((G, H)) * n).astype(np.int64)
    k2 = (k1 + 1 + (rng.random((G, H)) * np.maximum(n - 1, 1)).astype(np.int64)) % n
    k3 = (rng.random((G, H)) * n).astype(np.int64)
    k3 = np.where((k3 == k1) | (k3 == k2), (np.maximum(k1, k2) + 1) % n, k3)
    if N == 0:
        return RansacFit(
            np.full((G, 3, 3), np.nan),
            np.full((G, 3), np.nan),
            np.zeros(G, dtype=bool),
            np.zeros(0, dtype=bool),
            np.zeros(G, dtype=np.int64),
            np.full(G, np.nan),
        )
    # (G, H) point indices; an empty group's samples point anywhere (it gets no transform)
    i1, i2, i3 = (order[np.minimum(starts[:, None] + k, N - 1)] for k in (k1, k2, k3))
    Rh = rotation_from_triads(a[i2] - a[i1], a[i3] - a[i1], b[i2] - b[i1], b[i3] - b[i1])
    th = b[i1] - np.einsum("ghij,ghj->ghi", Rh, a[i1])  # (G, H, 3)
    # hypotheses are scored on at most score_points random members of each group
    sub = np.arange(N)
    if score_points is not None and counts.max() > score_points:
        pos = np.empty(N, dtype=np.int64)
        shuffled = order[np.lexsort((rng.random(N), g[order]))]  # by group, random within
        pos[shuffled] = np.arange(N) - starts[g[shuffled]]  # rank within its group
        sub = np.flatnonzero(pos < score_points)
    a_s, b_s, g_s = a[sub], b[sub], g[sub]
    cost = np.zeros((G, H))
    for h in range(H):  # one hypothesis at a time over all points: O(N) memory
        r = b_s - np.einsum("nij,nj->ni", Rh[g_s, h], a_s) - th[g_s, h]  # (N', 3)
        cost[:, h] = np.bincount(g_s, weights=np.minimum(squared_norm(r), thr2), minlength=G)
    best = cost.argmin(axis=1)  # (G,)
    gi = np.arange(G)
    R, t = Rh[gi, best], th[gi, best]  # (G, 3, 3), (G, 3)
    inlier = np.zeros(N, dtype=bool)
    for _ in range(1 + max(0, int(refinements))):
        r2 = squared_norm(b - np.einsum("nij,nj->ni", R[g], a) - t[g])  # (N,)
        inlier = r2 < thr2
        fit = fit_rigid_groups(a, b, g, G, inlier.astype(np.float64))
        R, t = fit.rotation, fit.translation
    r2 = squared_norm(b - np.einsum("nij,nj->ni", R[g], a) - t[g])
    inlier = r2 < thr2
    inliers = np.bincount(g, weights=inlier, minlength=G).astype(np.int64)
    with np.errstate(invalid="ignore", divide="ignore"):
        rms = np.sqrt(np.bincount(g, weights=np.where(inlier, r2, 0.0), minlength=G) / inliers)
    valid = fit.valid & (inliers >= min_inliers) & (counts >= min_inliers)
    R = np.where(valid[:, None, None], R, np.nan)
    t = np.where(valid[:, None], t, np.nan)
    return RansacFit(
        R, t, valid, inlier & valid[g], np.where(valid, inliers, 0), np.where(valid, rms, np.nan)
    )


def squared_norm(v: np.ndarray) -> np.ndarray:
    """Squared norm over the last axis of length 3 (faster than a strided sum).

    Parameters
    ----------
    v : (..., 3) float ndarray

    Returns
    -------
    (...) float ndarray
    """
    return v[..., 0] * v[..., 0] + v[..., 1] * v[..., 1] + v[..., 2] * v[..., 2]


def pixel_distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distances between pixels over the last axis of length 2: ``np.linalg.norm(a - b,
    axis=-1)``'s values, at a third of its cost (no reduction over a short axis).

    Parameters
    ----------
    a, b : (..., 2) float ndarrays

    Returns
    -------
    (...) float ndarray
        NaN where either pixel is.
    """
    d = np.subtract(a, b)
    return np.sqrt(d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1])


def observed_first(observed: np.ndarray, k: int | None = None) -> np.ndarray:
    """Each column's True rows first, in index order: the cameras observing each point.

    Where a column has fewer than ``k`` True rows the rest of it is 0 (a valid index that the
    caller masks, e.g. by ``np.arange(k)[:, None] < observed.sum(axis=0)``). On the True rows
    this is ``np.argsort(~observed, axis=0, kind="stable")[:k]``, without sorting: a strided
    sort of a (69, 80,000) mask took most of a second.

    Parameters
    ----------
    observed : (C, N) bool ndarray
    k : int, optional
        Rows to return (default C).

    Returns
    -------
    (k, N) intp ndarray
    """
    observed = np.asarray(observed, bool)
    k = observed.shape[0] if k is None else int(k)
    rank = np.cumsum(observed, axis=0, dtype=np.intp) - 1  # (C, N): place among the True rows
    out = np.zeros((k, observed.shape[1]), np.intp)
    c, n = np.nonzero(observed & (rank < k))
    out[rank[c, n], n] = c
    return out


def finite_rows(a: np.ndarray) -> np.ndarray:
    """Where every entry of the last axis is finite: ``np.all(np.isfinite(a), axis=-1)``.

    The same values, at a seventh of the time for pixels (C, N, 2): numpy reduces over a
    short last axis slowly, so the columns are tested one by one (an observed pixel of a
    camera, a valid point).

    Parameters
    ----------
    a : (..., K) float ndarray
        K small (2 for pixels, 3 for points).

    Returns
    -------
    (...) bool ndarray
    """
    a = np.asarray(a)
    if a.shape[-1] == 0:
        return np.ones(a.shape[:-1], bool)
    out = np.isfinite(a[..., 0])
    for k in range(1, a.shape[-1]):
        out &= np.isfinite(a[..., k])
    return out


def rotation_from_triads(
    a1: np.ndarray, a2: np.ndarray, b1: np.ndarray, b2: np.ndarray
) -> np.ndarray:
    """Proper rotation mapping the frame of the vector pair (a1, a2) onto that of (b1, b2).

    The TRIAD alignment: each pair spans an orthonormal frame (``e1`` along the first vector,
    ``e3`` normal to both); ``R = F_b F_a^T``. A closed-form rigid hypothesis from two
    displacement vectors, cheap enough for many RANSAC samples at once.

    Parameters
    ----------
    a1, a2, b1, b2 : (..., 3) float ndarray
        Broadcast against each other.

    Returns
    -------
    (..., 3, 3) float ndarray
        Degenerate (collinear or zero) pairs give a matrix that is not a rotation; RANSAC
        scores such a hypothesis low.
    """

    def frame(u, v):
        e1 = u / (np.linalg.norm(u, axis=-1, keepdims=True) + 1e-12)
        e3 = np.cross(u, v)
        e3 /= np.linalg.norm(e3, axis=-1, keepdims=True) + 1e-12
        e2 = np.cross(e3, e1)
        return np.stack([e1, e2, e3], axis=-1)  # (..., 3, 3) columns

    Fa, Fb = frame(a1, a2), frame(b1, b2)
    return Fb @ np.swapaxes(Fa, -1, -2)


# -- rotations -----------------------------------------------------------------------------------
def rotation_from_rodrigues(rvec: object) -> np.ndarray:
    """Rotation matrix from a Rodrigues (axis-angle) vector.

    Parameters
    ----------
    rvec : (3,) array-like
        Axis times angle in radians.

    Returns
    -------
    (3, 3) float ndarray

    Examples
    --------
    >>> np.round(rotation_from_rodrigues([0, 0, np.pi / 2]), 6) + 0.0
    array([[ 0., -1.,  0.],
           [ 1.,  0.,  0.],
           [ 0.,  0.,  1.]])
    """
    from scipy.spatial.transform import Rotation

    return Rotation.from_rotvec(check_array("rvec", rvec, (3,), finite=True)).as_matrix()


def rodrigues_from_rotation(R: object) -> np.ndarray:
    """Rodrigues vector of a rotation matrix (inverse of :func:`rotation_from_rodrigues`).

    Parameters
    ----------
    R : (3, 3) array-like
        A rotation matrix.

    Returns
    -------
    (3,) float ndarray
        Axis times angle, the angle in [0, pi].
    """
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(check_array("R", R, (3, 3), finite=True)).as_rotvec()


def mean_rotation(Rs: np.ndarray) -> np.ndarray:
    """Chordal L2 mean of rotations: the rotation nearest their sum in Frobenius norm.

    Parameters
    ----------
    Rs : (N, 3, 3) float ndarray

    Returns
    -------
    (3, 3) float ndarray
    """
    U, _, Vt = np.linalg.svd(Rs.sum(axis=0))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


def rotation_angle_deg(Ra: np.ndarray, Rb: np.ndarray) -> np.ndarray:
    """Angles in degrees of ``Ra^T Rb`` for stacked rotations.

    Parameters
    ----------
    Ra, Rb : (..., 3, 3) float ndarray
        Broadcast against each other.

    Returns
    -------
    (...) float ndarray
    """
    tr = np.einsum("...ij,...ij->...", Ra, Rb)  # trace(Ra^T Rb)
    return np.degrees(np.arccos(np.clip((tr - 1) / 2, -1.0, 1.0)))


def axis_angles(rig: CameraRig) -> np.ndarray:
    """Angles between the cameras' optical axes.

    Parameters
    ----------
    rig : CameraRig
        C cameras (``rig.R`` (C, 3, 3), world to camera).

    Returns
    -------
    (C, C) float ndarray
        Degrees, in [0, 180]; 0 on the diagonal.
    """
    axes = rig.R[:, 2]  # (C, 3) third rows: the optical axes in world coordinates
    return np.degrees(np.arccos(np.clip(axes @ axes.T, -1.0, 1.0)))


# -- the up axis ---------------------------------------------------------------------------------
#: The axis names :func:`parse_up` accepts, besides ``"auto"`` and 3 numbers.
UP_CHOICES = ("+x", "-x", "+y", "-y", "+z", "-z")

#: Cameras whose mean image-up vector is shorter than this disagree (portrait and landscape
#: cameras mixed, or cameras rolled every way): their mean is not an up direction.
_UP_AGREEMENT = 0.5


def parse_up(value: object, where: str = "up") -> np.ndarray | None:
    """An up setting as a unit vector, or None for ``"auto"``.

    Parameters
    ----------
    value : str or (3,) array-like
        ``"auto"``, one of :data:`UP_CHOICES` (``"+z"``, ``"-y"``, ...; ``"z"`` is ``"+z"``), or
        3 numbers (a direction, normalised here).
    where : str
        Named in the error message (the setting and its file).

    Returns
    -------
    (3,) float ndarray or None

    Raises
    ------
    ValidationError
        For any other value (the message lists the valid ones).

    Examples
    --------
    >>> parse_up("-y").tolist(), parse_up("auto")
    ([0.0, -1.0, 0.0], None)
    """
    from .errors import ValidationError

    if isinstance(value, str):
        text = value.strip().lower()
        if text == "auto":
            return None
        if text in ("x", "y", "z"):
            text = "+" + text
        if text in UP_CHOICES:
            out = np.zeros(3)
            out["xyz".index(text[1])] = 1.0 if text[0] == "+" else -1.0
            return out
    elif not isinstance(value, bool):
        try:
            v = np.asarray(value, dtype=float)
        except (TypeError, ValueError):
            v = None
        if v is not None and v.shape == (3,) and np.all(np.isfinite(v)) and np.linalg.norm(v) > 0:
            return v / np.linalg.norm(v)
    raise ValidationError(
        f"{where}: expected 'auto', one of {', '.join(UP_CHOICES)} or 3 numbers (a direction), "
        f"got {value!r}"
    )


def _normal_of(vectors: np.ndarray) -> np.ndarray | None:
    """The direction perpendicular to unit ``vectors`` (C, 3) that span a plane, or None when
    they do not (all nearly parallel: second eigenvalue of their scatter under 0.05, about a
    13 degree spread; or not in one plane: smallest eigenvalue over 10 % of the second)."""
    w, v = np.linalg.eigh(vectors.T @ vectors / len(vectors))  # ascending
    if w[1] < 0.05 or w[0] > 0.1 * w[1]:
        return None
    return v[:, 0]


def _signed(
    n: np.ndarray, mean_up: np.ndarray, axes: np.ndarray, what: str
) -> tuple[np.ndarray, str]:
    """``n`` or ``-n``, whichever the cameras' mean image-up points along; where that is
    ambiguous (cameras on their side), the side the optical axes tilt away from (cameras look
    down a little); if they are level too, the side of world +z, and the reason says so."""
    along = float(mean_up @ n)
    if abs(along) >= 0.2:
        return (n if along > 0 else -n), what
    tilt = float(axes.mean(axis=0) @ n)
    if abs(tilt) > 0.05:
        return (n if tilt < 0 else -n), f"{what}, sign from the cameras looking down"
    return (n if n[2] >= 0 else -n), (
        f"{what} (sign ambiguous: the cameras are on their side and level; set up to choose)"
    )


def detect_up(rig: CameraRig) -> tuple[np.ndarray, str]:
    """The world's up direction, guessed from where the cameras are and how they are held.

    Cameras are usually mounted level (image rows horizontal, whatever their pitch) and stand
    around the scene, not above or below it. So, in order:

    1. If the camera centres lie near a plane with a 2-D spread (a ring or an arc around the
       scene: the smallest singular value of the centred positions is under 25 % of the
       middle one, which is over 20 % of the largest) and the cameras look across that plane
       (mean ``|n . d|`` under 0.7 for optical axes ``d``), up is the plane's normal ``n``.
    2. Else, if the cameras' image x axes ``R[0]`` span a plane (cameras facing different
       ways), up is its normal: exact for level cameras at any pitch.
    3. Else, if the cameras' image-up vectors ``-R[1]`` agree (their mean has a length of at
       least 0.5), up is their mean (tilted by the cameras' mean pitch).
    4. Else world +z, and the reason says the guess failed.

    In 1 and 2 the sign is that of the cameras' mean image-up vector along the normal; where
    that is ambiguous (cameras on their side, portrait-mounted), the cameras are taken to
    look down a little; if they are level too, the side of world +z is taken and the reason
    says the sign is ambiguous.

    Parameters
    ----------
    rig : CameraRig
        C cameras (``rig.R`` (C, 3, 3) world to camera, ``rig.C`` (C, 3) centres).

    Returns
    -------
    up : (3,) float ndarray
        Unit vector.
    how : str
        How it was found, for the log (``"plane of the 8 camera centres"``, ...).
    """
    R, C = np.asarray(rig.R, float), np.asarray(rig.C, float)
    mean_up = -R[:, 1, :].mean(axis=0)  # (3,) the cameras' mean image-up direction
    axes = R[:, 2, :]  # (C, 3) optical axes
    if len(C) >= 3:
        _, s, vt = np.linalg.svd(C - C.mean(axis=0), full_matrices=False)
        n = vt[2]
        planar = s[1] > 0.2 * s[0] and s[2] < 0.25 * s[1]
        if planar and float(np.abs(axes @ n).mean()) < 0.7:
            return _signed(n, mean_up, axes, f"plane of the {len(C)} camera centres")
    n = _normal_of(R[:, 0, :])
    if n is not None:
        return _signed(n, mean_up, axes, f"normal of the {len(C)} cameras' image rows (level)")
    if np.linalg.norm(mean_up) >= _UP_AGREEMENT:
        return mean_up / np.linalg.norm(mean_up), f"mean image-up of the {len(C)} cameras"
    return np.array([0.0, 0.0, 1.0]), (
        f"world +z: the {len(C)} cameras give no up direction (facing one way and held "
        "differently); set up to choose"
    )


def resolve_up(value: object, rig: CameraRig | None, where: str = "up") -> tuple[np.ndarray, str]:
    """The up direction of a setting: the value itself, or :func:`detect_up` for ``"auto"``.

    Parameters
    ----------
    value : str or (3,) array-like
        As for :func:`parse_up`.
    rig : CameraRig or None
        The cameras, for ``"auto"`` (world +z without them).
    where : str
        Named in the error message.

    Returns
    -------
    up : (3,) float ndarray
        Unit vector.
    how : str
        Where it came from, for the log.
    """
    up = parse_up(value, where)
    if up is not None:
        return up, f"{where} = {value!r}"
    if rig is None or len(rig) == 0:
        return np.array([0.0, 0.0, 1.0]), "world +z (no cameras)"
    return detect_up(rig)


# -- lens distortion -----------------------------------------------------------------------------
def distort_normalized(xy: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """Apply OpenCV lens distortion to normalised image coordinates.

    Parameters
    ----------
    xy : (..., N, 2) float ndarray
        Undistorted normalised coordinates ``(X/Z, Y/Z)``.
    dist : (..., 8) float ndarray
        ``(k1, k2, p1, p2, k3, k4, k5, k6)``, broadcast against the leading axes of ``xy``
        (one row per camera for ``xy`` of shape (C, N, 2)).

    Returns
    -------
    (..., N, 2) float ndarray
        Distorted normalised coordinates.
    """
    d = np.asarray(dist, dtype=float)[..., None, :]  # (..., 1, 8)
    x, y = xy[..., 0], xy[..., 1]
    r2 = x * x + y * y
    if not np.any(d):
        return _no_distortion(xy, r2)
    return _distort(x, y, r2, d)


def _distort(x: np.ndarray, y: np.ndarray, r2: np.ndarray, d: np.ndarray) -> np.ndarray:
    """The distortion model of :func:`distort_normalized` (``d`` (..., 1, 8) or (8,))."""
    k1, k2, p1, p2, k3, k4, k5, k6 = (d[..., i] for i in range(N_DIST))
    radial = (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return np.stack([xd, yd], axis=-1)


def _no_distortion(xy: np.ndarray, r2: np.ndarray) -> np.ndarray:
    """:func:`distort_normalized` with all coefficients zero, without its arithmetic.

    The model's terms are then ``x * 1 + 0``: a copy of ``xy``, bit for bit (up to the sign of
    a zero), wherever they are finite. Where ``r2 = x^2 + y^2`` is NaN or large enough that a
    term may overflow (``0 * inf`` is NaN), the model itself is evaluated.

    Parameters
    ----------
    xy : (..., N, 2) float ndarray
    r2 : (..., N) float ndarray
        ``x * x + y * y``.

    Returns
    -------
    (..., N, 2) float ndarray
    """
    xd, yd = _no_distortion_xy(xy[..., 0], xy[..., 1], r2)
    return np.stack([xd, yd], axis=-1)


def _no_distortion_xy(
    x: np.ndarray, y: np.ndarray, r2: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_no_distortion` on separate coordinates ``x``, ``y`` (...,); new arrays."""
    xd, yd = np.array(x, dtype=float), np.array(y, dtype=float)
    with np.errstate(invalid="ignore"):
        odd = ~(r2 < 1e300)  # NaN, inf, or near overflow in r2 + 2 x^2
    if np.any(odd):
        with np.errstate(invalid="ignore", over="ignore"):
            model = _distort(x[odd], y[odd], r2[odd], np.zeros(N_DIST))
        xd[odd], yd[odd] = model[:, 0], model[:, 1]
    return xd, yd


def undistort_normalized(xy_d: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """Invert :func:`distort_normalized`: fixed-point start, then Newton's method.

    Three steps of OpenCV's fixed-point scheme give the start; three Newton steps with the
    analytic Jacobian of the distortion refine it. Entries whose last Newton step is still above
    1e-9 (strong distortion far from the image centre) are solved again from 30 fixed-point
    steps. Vectorised over cameras and points.

    Parameters
    ----------
    xy_d : (..., N, 2) float ndarray
        Distorted normalised coordinates; NaN rows stay NaN.
    dist : (..., 8) float ndarray
        Distortion coefficients, broadcast as in :func:`distort_normalized`.

    Returns
    -------
    (..., N, 2) float ndarray
        Undistorted normalised coordinates; ``distort_normalized`` of them returns ``xy_d`` to
        about 1e-15 wherever the iteration reaches the solution: everywhere inside the image for
        the lenses of ``benchmarks/bench_undistort.py``, not always far outside it, where
        polynomial lens models fold back.

    Examples
    --------
    >>> xy = np.array([[0.3, -0.2]])
    >>> d = [-0.3, 0.1, 0.001, -0.002, 0, 0, 0, 0]
    >>> bool(np.allclose(undistort_normalized(distort_normalized(xy, d), d), xy, atol=1e-12))
    True
    """
    xy_d = np.asarray(xy_d, dtype=float)
    d = np.asarray(dist, dtype=float)
    if not np.any(d):
        return xy_d.copy()
    coef = [d[..., None, i] for i in range(N_DIST)]  # each (..., 1)
    xd, yd = xy_d[..., 0], xy_d[..., 1]
    x, y, sx, sy = _undistort_steps(xd, yd, coef, _UNDISTORT_FIXED_POINT)
    slow = ~((np.abs(sx) < _UNDISTORT_CONVERGED) & (np.abs(sy) < _UNDISTORT_CONVERGED))
    slow &= np.isfinite(xd) & np.isfinite(yd)
    if np.any(slow):  # not converged: start again from more fixed-point steps
        coef_slow = [np.broadcast_to(k, slow.shape)[slow] for k in coef]  # each (M,)
        x[slow], y[slow], _, _ = _undistort_steps(
            xd[slow], yd[slow], coef_slow, _UNDISTORT_FIXED_POINT_SLOW
        )
    return np.stack([x, y], axis=-1)


def _undistort_steps(
    xd: np.ndarray, yd: np.ndarray, coef: list[np.ndarray], fixed_point: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``fixed_point`` fixed-point steps, then Newton steps with the analytic Jacobian.

    Parameters
    ----------
    xd, yd : (..., N) float ndarrays
        Distorted normalised coordinates.
    coef : list of 8 float ndarrays
        ``k1 k2 p1 p2 k3 k4 k5 k6``, each broadcastable against ``xd``.
    fixed_point : int

    Returns
    -------
    x, y : (..., N) float ndarrays
        Undistorted coordinates.
    sx, sy : (..., N) float ndarrays
        The last Newton step (its size tells convergence).
    """
    k1, k2, p1, p2, k3, k4, k5, k6 = coef
    rational = bool(np.any(k4 != 0) or np.any(k5 != 0) or np.any(k6 != 0))
    tangential = bool(np.any(p1 != 0) or np.any(p2 != 0))  # skip the terms that are all zero
    x, y = xd.copy(), yd.copy()
    for _ in range(fixed_point):  # OpenCV's fixed-point scheme
        r2 = x * x + y * y
        icdist = 1 / (1 + r2 * (k1 + r2 * (k2 + r2 * k3)))
        if rational:
            icdist *= 1 + r2 * (k4 + r2 * (k5 + r2 * k6))
        if tangential:
            x, y = (
                (xd - 2 * p1 * x * y - p2 * (r2 + 2 * x * x)) * icdist,
                (yd - p1 * (r2 + 2 * y * y) - 2 * p2 * x * y) * icdist,
            )
        else:
            x, y = xd * icdist, yd * icdist
    sx = sy = np.zeros_like(x)
    for _ in range(_UNDISTORT_NEWTON):
        xx, yy, xy = x * x, y * y, x * y
        r2 = xx + yy
        num = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        dnum = k1 + r2 * (2 * k2 + 3 * k3 * r2)
        if rational:
            den = 1 + r2 * (k4 + r2 * (k5 + r2 * k6))
            rad = num / den
            drad = (dnum * den - num * (k4 + r2 * (2 * k5 + 3 * k6 * r2))) / (den * den)
        else:
            rad, drad = num, dnum  # d rad / d r2
        fx = x * rad - xd
        fy = y * rad - yd
        a = rad + 2 * xx * drad  # Jacobian [[a, b], [b, e]]
        b = 2 * xy * drad
        e = rad + 2 * yy * drad
        if tangential:
            fx += 2 * p1 * xy + p2 * (r2 + 2 * xx)
            fy += p1 * (r2 + 2 * yy) + 2 * p2 * xy
            a += 2 * p1 * y + 6 * p2 * x
            b += 2 * p1 * x + 2 * p2 * y
            e += 6 * p1 * y + 2 * p2 * x
        det = a * e - b * b
        det = np.where(np.abs(det) > 1e-12, det, np.inf)  # no step where singular
        sx = (e * fx - b * fy) / det
        sy = (a * fy - b * fx) / det
        x = x - sx
        y = y - sy
    return x, y, sx, sy
