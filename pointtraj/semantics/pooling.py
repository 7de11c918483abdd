"""Pooling the per-camera confidences of a 3D point into one K-vector (the paper's Eq. 2).

Given L_c, the confidences sampled at the projection of a point in camera c, and V_c, its
visibility in that camera, the methods are:

``view`` (the paper's view pooling)
    The visibility-weighted medoid ``c* = argmin_c sum_j V_j ||L_c - L_j||^2``, candidates c and
    the sum over j both restricted to the cameras with ``V > eps_e``; the result is ``L_{c*}``.
    Expanding the square, ``cost_c = S0 ||L_c||^2 - 2 L_c . S1 + S2`` with ``S0 = sum_j V_j``,
    ``S1 = sum_j V_j L_j`` and ``S2 = sum_j V_j ||L_j||^2``, so it is O(C K) per point-frame.
    Ties go to the lowest camera index.
``view_soft`` (ours: view pooling with less single-view noise)
    The mean of the cameras that agree with the view-pooling medoid ``L_{c*}``, each weighted
    by ``V_j exp(-||L_j - L_{c*}||^2 / w^2)`` (``w`` = :data:`VIEW_SOFT_WIDTH`), over the cameras
    with ``V > eps_e``. The medoid keeps view pooling's robustness to outlying views; the mean
    removes the noise of the one view it picks (its blur, its confidence level), which makes
    the pooled confidences steadier over time (``docs/semantics.md``). O(C K) per point-frame.
``average`` (the paper's average pooling: all cameras in whose image the point falls)
    The unweighted mean over every camera in whose image the point projects (in front of the
    camera and inside the image), occluded or not; visibility is not used. When no ``in_image``
    mask is given, the cameras with ``V > 0`` are used instead. An occluded point's projection
    lies on its occluder, so this mean mixes the occluder's class in (the paper's baseline, as
    its text defines it: "across all cameras").
``average_visible`` (a stronger baseline: the visible cameras only)
    The unweighted mean over the cameras with ``V > eps_e`` (those view pooling chooses from);
    occluded cameras are left out.
``weighted``
    The visibility-weighted mean over the cameras with ``V > eps_e``.
``max``
    The element-wise maximum over the cameras with ``V > eps_e``.
``product``
    A product of experts over the cameras with ``V > eps_e``:
    ``prod_c (L_c + floor)``, normalised to sum to 1 over the K classes (computed in log space).

A point with no usable camera gets a row of NaN; :func:`build_semantic_map` skips such rows in
the time average. Cameras whose sample contains NaN are treated as unusable.
"""

from __future__ import annotations

import numpy as np

from ..errors import ValidationError, check_array

__all__ = ["POOLINGS", "POOLING_DESCRIPTIONS", "pool_views", "view_pooling_costs"]

#: Valid pooling method names.
POOLINGS: tuple[str, ...] = (
    "view",
    "view_soft",
    "average",
    "average_visible",
    "weighted",
    "max",
    "product",
)

#: One line per method, for reports: what it pools over.
POOLING_DESCRIPTIONS: dict[str, str] = {
    "view": "view pooling (the paper's method): the visibility-weighted medoid of the visible "
    "cameras",
    "view_soft": "view_soft (ours): the mean of the visible cameras that agree with the medoid",
    "average": "average over all cameras in whose image the point falls, occluded or not (the "
    "paper's average pooling)",
    "average_visible": "average over the visible cameras only (a stronger baseline than the "
    "paper's)",
    "weighted": "visibility-weighted mean of the visible cameras",
    "max": "element-wise maximum over the visible cameras",
    "product": "product of experts over the visible cameras",
}

#: Width w of the agreement kernel of ``view_soft`` pooling, in confidence units (the norm of a
#: difference of K-vectors). 0.5 was the best of 0.2-0.8 on the synthetic study (accuracy and
#: temporal consistency; ``docs/semantics.md``).
VIEW_SOFT_WIDTH = 0.5

#: Added to confidences before taking logs in ``product`` pooling.
PRODUCT_FLOOR = 1e-3


def _as_cnk(L: np.ndarray, V: np.ndarray, camera_axis: int | None) -> np.ndarray:
    """Return L as (C, N, K) given V (N, C)."""
    N, C = V.shape
    if L.ndim != 3:
        raise ValidationError(f"L: expected shape (C, N, K) or (N, C, K), got {L.shape}")
    if camera_axis is None:
        if L.shape[:2] == (C, N) and C != N:
            camera_axis = 0
        elif L.shape[:2] == (N, C) and C != N:
            camera_axis = 1
        elif L.shape[:2] == (C, N):
            camera_axis = 0  # C == N: the documented default layout
        else:
            raise ValidationError(
                f"L: shape {L.shape} does not match V {V.shape} as (C, N, K) or (N, C, K)"
            )
    if camera_axis == 0:
        if L.shape[:2] != (C, N):
            raise ValidationError(f"L: expected shape ({C}, {N}, K), got {L.shape}")
        return L
    if camera_axis == 1:
        if L.shape[:2] != (N, C):
            raise ValidationError(f"L: expected shape ({N}, {C}, K), got {L.shape}")
        return L.transpose(1, 0, 2)
    raise ValidationError(f"camera_axis: must be 0, 1 or None, got {camera_axis!r}")


def _finite_cameras(L: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(C, N) mask of finite samples and L with non-finite samples zeroed (copied only then)."""
    finite = np.isfinite(np.einsum("cnk->cn", L))  # (C, N); NaN or inf anywhere -> False
    if not finite.all():
        L = np.where(finite[..., None], L, np.float32(0))
    return finite, L


def view_pooling_costs(L: np.ndarray, V: np.ndarray, eps_e: float) -> np.ndarray:
    """The medoid costs ``sum_j V_j ||L_c - L_j||^2`` of every candidate camera.

    Parameters
    ----------
    L : (C, N, K) float32 ndarray
        Per-camera confidences.
    V : (N, C) float ndarray
        Visibility in [0, 1].
    eps_e : float
        Cameras with ``V <= eps_e`` (or a NaN sample) neither vote nor are candidates.

    Returns
    -------
    (C, N) float32 ndarray
        Cost of each candidate; ``inf`` for cameras that are not candidates.
    """
    sq = np.einsum("cnk,cnk->cn", L, L)  # (C, N) ||L_c||^2, NaN/inf if L_c is not finite
    finite = np.isfinite(sq)
    if not finite.all():
        L = np.where(finite[..., None], L, np.float32(0))
        sq = np.where(finite, sq, np.float32(0))
    valid = (V.T > eps_e) & finite  # (C, N)
    Wt = np.where(valid, V.T, 0).astype(np.float32)  # (C, N)
    S0 = Wt.sum(axis=0)  # (N,)
    S1 = np.einsum("cn,cnk->nk", Wt, L)  # (N, K) sum_j V_j L_j
    S2 = np.einsum("cn,cn->n", Wt, sq)  # (N,) sum_j V_j ||L_j||^2
    cost = S0[None] * sq - 2.0 * np.einsum("cnk,nk->cn", L, S1) + S2[None]  # (C, N)
    cost[~valid] = np.inf
    return cost


def pool_views(
    L: np.ndarray,
    V: np.ndarray,
    eps_e: float,
    method: str = "view",
    *,
    in_image: np.ndarray | None = None,
    camera_axis: int | None = None,
) -> np.ndarray:
    """Pool per-camera confidences of N points into one K-vector each.

    Parameters
    ----------
    L : (C, N, K) or (N, C, K) float ndarray
        Confidences sampled at the projections (see :func:`sample_confidences`).
    V : (N, C) float ndarray
        Visibility of each point in each camera, in [0, 1].
    eps_e : float
        Visibility threshold: only cameras with ``V > eps_e`` take part (all methods but
        ``average``).
    method : {"view", "view_soft", "average", "average_visible", "weighted", "max", "product"}
        See the module docstring.
    in_image : (C, N) or (N, C) bool ndarray, optional
        Whether each point projects inside each image; used by ``average`` (same layout as L).
    camera_axis : {0, 1, None}
        Axis of L holding the cameras; ``None`` infers it from V's shape (0 when ambiguous).

    Returns
    -------
    (N, K) float32 ndarray
        Pooled confidences; NaN rows for points without a usable camera.

    Raises
    ------
    ValidationError
        On an unknown method or inconsistent shapes.

    Examples
    --------
    Three cameras see a point; the second is an outlier and the third barely visible:

    >>> L = np.array([[[0.9, 0.1]], [[0.1, 0.9]], [[0.8, 0.2]]], np.float32)  # (C=3, N=1, K=2)
    >>> V = np.array([[1.0, 1.0, 0.05]])  # (N=1, C=3)
    >>> print(pool_views(L, V, eps_e=0.1))  # camera 2 is excluded; a tie goes to camera 0
    [[0.9 0.1]]
    >>> V = np.array([[1.0, 1.0, 1.0]])
    >>> print(pool_views(L, V, eps_e=0.1))  # now camera 2 is the medoid
    [[0.8 0.2]]
    >>> print(pool_views(L, V, eps_e=0.1, method="average").round(3))
    [[0.6 0.4]]
    >>> print(pool_views(L, V, eps_e=0.1, method="view_soft").round(3))  # camera 1 disagrees
    [[0.84 0.16]]

    The point is hidden in camera 1 (V = 0) but falls inside its image:
    the paper's average keeps camera 1, the visible-camera average leaves it out:

    >>> V = np.array([[1.0, 0.0, 1.0]])
    >>> print(pool_views(L, V, eps_e=0.1, method="average", in_image=np.ones((3, 1), bool)).round(3))
    [[0.6 0.4]]
    >>> print(pool_views(L, V, eps_e=0.1, method="average_visible").round(3))
    [[0.85 0.15]]
    """
    if method not in POOLINGS:
        raise ValidationError(f"method: must be one of {', '.join(POOLINGS)}, got {method!r}")
    V = check_array("V", V, (None, None), dtype=np.float32)
    L = _as_cnk(np.asarray(L), V, camera_axis)
    if L.dtype != np.float32:
        L = L.astype(np.float32)
    C, N, K = L.shape
    if method == "average":
        if in_image is None:
            use = V.T > 0  # (C, N)
        else:
            in_image = np.asarray(in_image, dtype=bool)
            if in_image.shape == (C, N):
                use = in_image
            elif in_image.shape == (N, C):
                use = in_image.T
            else:
                raise ValidationError(
                    f"in_image: expected shape ({C}, {N}) or ({N}, {C}), got {in_image.shape}"
                )
        finite, L = _finite_cameras(L)
        use = use & finite
        n = use.sum(axis=0)  # (N,)
        total = np.einsum("cn,cnk->nk", use.astype(np.float32), L)  # (N, K)
        with np.errstate(invalid="ignore", divide="ignore"):
            out = total / n[:, None].astype(np.float32)
        return out.astype(np.float32, copy=False)

    if method in ("view", "view_soft"):
        cost = view_pooling_costs(L, V, eps_e)  # (C, N)
        best = np.argmin(cost, axis=0)  # (N,)
        out = L[best, np.arange(N)]  # (N, K)
        out = np.array(out, dtype=np.float32)
        none = ~np.isfinite(cost[best, np.arange(N)])
        if method == "view_soft":
            candidates = np.isfinite(cost)  # (C, N): V > eps_e and a finite sample
            Lz = np.where(candidates[..., None], L, np.float32(0))
            sq = np.einsum("cnk,cnk->cn", Lz, Lz)  # (C, N)
            d2 = sq - 2 * np.einsum("cnk,nk->cn", Lz, out) + np.einsum("nk,nk->n", out, out)
            w = np.where(candidates, V.T * np.exp(-np.maximum(d2, 0) / VIEW_SOFT_WIDTH**2), 0)
            with np.errstate(invalid="ignore", divide="ignore"):
                out = np.einsum("cn,cnk->nk", w.astype(np.float32), Lz) / w.sum(axis=0)[:, None]
            out = out.astype(np.float32)
        out[none] = np.nan
        return out

    finite, L = _finite_cameras(L)
    valid = (V.T > eps_e) & finite  # (C, N)
    none = ~valid.any(axis=0)  # (N,)
    if method in ("weighted", "average_visible"):
        Wt = np.where(valid, V.T if method == "weighted" else 1, 0).astype(np.float32)
        S1 = np.einsum("cn,cnk->nk", Wt, L)
        with np.errstate(invalid="ignore", divide="ignore"):
            out = S1 / Wt.sum(axis=0)[:, None]
    elif method == "max":
        out = np.where(valid[..., None], L, -np.inf).max(axis=0)
    else:  # product
        logp = np.einsum(
            "cn,cnk->nk",
            valid.astype(np.float32),
            np.log(np.where(valid[..., None], L, 1.0) + np.float32(PRODUCT_FLOOR)),
        )  # (N, K)
        logp -= logp.max(axis=1, keepdims=True)
        out = np.exp(logp)
        out /= out.sum(axis=1, keepdims=True)
    out = np.asarray(out, dtype=np.float32)
    out[none] = np.nan
    return out
