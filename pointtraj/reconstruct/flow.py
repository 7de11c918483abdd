"""Pyramidal Lucas-Kanade optical flow (paper Section 5, step 2).

Batched flow of many points with a forward-backward check (:func:`track_flow`), its shortcut
for windows that barely move (:func:`still_flow`), and view expansion by flow from an
observing camera to the cameras that should see a point (:func:`expand_views`).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

import numpy as np

from ..camera import CameraRig
from ..errors import check_array
from ..geometry import axis_angles, finite_rows

__all__ = ["track_flow", "still_flow", "expand_views", "to_grey"]

#: OpenCV's default ``minEigThreshold`` of ``calcOpticalFlowPyrLK``: the smallest eigenvalue
#: of the window's gradient matrix per pixel (grey levels^2 / px^2) below which it fails a
#: point. :func:`still_flow` leaves such windows to it.
LK_MIN_EIG = 1e-4

#: :func:`still_flow` pays where a camera tracks at least this many views a pixel: its box sums
#: cost about 40 ns a pixel of the image, the pyramidal flow 16 us a view forward and 31 us
#: with its backward check (paper69, 1280x1024), so at 1/256 the step pays once about 64 % of
#: the views are still (33 % where the flow is checked). Sparser cameras (the demo's, about
#: 200 views on 640x512; Pose2Sim's, about 5,000 on 1920x1080) keep the pyramidal flow alone.
STILL_VIEWS_PER_PIXEL = 1.0 / 256.0

logger = logging.getLogger(__name__)


def _flow_fb(
    img0: np.ndarray,
    img1: np.ndarray,
    p0: np.ndarray,
    lk: dict,
    fb_max_px: float,
    guess: np.ndarray | None = None,
    check: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Lucas-Kanade flow ``img0`` -> ``img1`` and back, with the forward-backward check.

    Parameters
    ----------
    img0, img1 : (H, W) uint8 ndarray
    p0 : (K, 2) float ndarray
        Positions in ``img0``.
    lk : dict
        ``calcOpticalFlowPyrLK`` keyword arguments (window, levels, criteria).
    fb_max_px : float
        Maximum forward-backward error.
    guess : (K, 2) float ndarray, optional
        Start of the forward flow in ``img1`` (the backward flow then starts at ``p0``);
        default: both start where they come from.
    check : (K,) bool ndarray, optional
        Which points get the backward flow and its check (default: all); the others need only
        converge forward inside ``img1``.

    Returns
    -------
    p1 : (K, 2) float32 ndarray
        Positions in ``img1``.
    good : (K,) bool ndarray
        Converged both ways, back within ``fb_max_px`` and inside ``img1`` (forward only where
        ``check`` is False).
    """
    import cv2

    a = np.ascontiguousarray(p0, dtype=np.float32).reshape(-1, 1, 2)
    fwd, back = None, None
    if guess is not None:
        lk = {**lk, "flags": cv2.OPTFLOW_USE_INITIAL_FLOW}
        fwd = np.ascontiguousarray(guess, dtype=np.float32).reshape(-1, 1, 2)
        back = a.copy()
    p1, st1, _ = cv2.calcOpticalFlowPyrLK(img0, img1, a, fwd, **lk)
    p1 = p1.reshape(-1, 2)
    h, w = img1.shape[:2]
    good = (
        (st1.ravel() == 1)
        & (p1[:, 0] >= -0.5)
        & (p1[:, 0] < w - 0.5)
        & (p1[:, 1] >= -0.5)
        & (p1[:, 1] < h - 0.5)
    )
    # back only from where the forward flow converged inside img1 (the rest fails anyway;
    # Lucas-Kanade tracks each point on its own, so the others' results are the same)
    idx = np.flatnonzero(good if check is None else good & check)
    if idx.size:
        fwd_ok = np.ascontiguousarray(p1[idx]).reshape(-1, 1, 2)
        back_ok = None if back is None else np.ascontiguousarray(back[idx])
        p0b, st2, _ = cv2.calcOpticalFlowPyrLK(img1, img0, fwd_ok, back_ok, **lk)
        fb = np.linalg.norm(p0b.reshape(-1, 2) - a[idx].reshape(-1, 2), axis=1)
        good[idx] = (st2.ravel() == 1) & (fb <= fb_max_px)
    return p1, good


def track_flow(
    prev_grey: np.ndarray,
    grey: np.ndarray,
    points: np.ndarray,
    *,
    window: int = 21,
    levels: int = 3,
    fb_max_px: float = 1.0,
    check: np.ndarray | None = None,
) -> np.ndarray:
    """Pyramidal Lucas-Kanade flow of many points at once, with a forward-backward check.

    Parameters
    ----------
    prev_grey, grey : (H, W) uint8 ndarray
        Consecutive grey images of one camera.
    points : (K, 2) float ndarray
        Pixel positions in ``prev_grey``; NaN rows are skipped.
    window, levels : int
        Lucas-Kanade window size and pyramid levels.
    fb_max_px : float
        Maximum forward-backward error.
    check : (K,) bool ndarray, optional
        Which points get the forward-backward check (default: all); the others are kept where
        the forward flow converges inside the image.

    Returns
    -------
    (K, 2) float32 ndarray
        Positions in ``grey``; NaN where the flow failed, left the image or the
        forward-backward error exceeds ``fb_max_px``.
    """
    import cv2

    p = check_array("points", points, (None, 2))
    out = np.full(p.shape, np.nan, np.float32)
    idx = np.flatnonzero(finite_rows(p))
    if idx.size == 0:
        return out
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 0.01)
    lk = {"winSize": (window, window), "maxLevel": levels, "criteria": crit}
    chk = None if check is None else check_array("check", check, (len(p),), dtype=bool)[idx]
    p1, good = _flow_fb(prev_grey, grey, p[idx], lk, fb_max_px, check=chk)
    out[idx[good]] = p1[good]
    return out


def still_flow(
    prev_grey: np.ndarray,
    grey: np.ndarray,
    points: np.ndarray,
    *,
    window: int = 21,
    max_px: float = 0.1,
    noise_ratio: float = 6.0,
) -> np.ndarray:
    """The flow of the points whose window barely moves, from one Lucas-Kanade step.

    One Gauss-Newton step of Lucas-Kanade at full resolution from zero motion,
    ``d = -G^-1 sum(grad I (J - I))`` over the ``window`` x ``window`` window at each point
    (``G = sum(grad I grad I^T)``), is exact to first order in ``d``. Where ``d`` is below
    ``max_px`` and the window's residual after it, ``sum((J - I + grad I . d)^2)`` per pixel,
    is no more than ``noise_ratio`` times the image's noise, the point moved by ``d``, as the
    pyramidal flow would find to within its own tolerance: this is the case of most views of
    a capture's static background, 83 % of the tracked views on paper69. The sums are
    box filters of whole images (Scharr gradients), so a view costs a lookup instead of a
    flow. The image's noise is the quietest quarter's mean squared frame difference per
    window (sensor noise and compression; 0 where a video codec repeats a static block,
    which then takes only unchanged windows).

    Parameters
    ----------
    prev_grey, grey : (H, W) uint8 ndarray
        Consecutive grey images of one camera.
    points : (K, 2) float ndarray
        Pixel positions in ``prev_grey``; NaN rows are skipped.
    window : int
        The Lucas-Kanade window size.
    max_px : float
        The largest motion taken from the one step.
    noise_ratio : float
        The largest residual, in units of the image's noise.

    Returns
    -------
    (K, 2) float32 ndarray
        Positions in ``grey``; NaN where the pyramidal flow must decide: motion above
        ``max_px``, a residual above the noise (occlusion, a change of appearance, motion that
        one step does not model), a window without texture (smallest eigenvalue per pixel
        below :data:`LK_MIN_EIG`) or touching the image border.
    """
    import cv2

    p = check_array("points", points, (None, 2))
    out = np.full(p.shape, np.nan, np.float32)
    h, w = prev_grey.shape[:2]
    half = window // 2
    ok = finite_rows(p)
    q = np.rint(np.where(ok[:, None], p, 0.0)).astype(np.int64)
    ok &= (q[:, 0] >= half) & (q[:, 0] < w - half) & (q[:, 1] >= half) & (q[:, 1] < h - half)
    idx = np.flatnonzero(ok)
    if idx.size == 0:
        return out
    i0 = prev_grey.astype(np.float32)
    dt = grey.astype(np.float32) - i0
    ix = cv2.Scharr(i0, cv2.CV_32F, 1, 0, scale=1.0 / 32.0)
    iy = cv2.Scharr(i0, cv2.CV_32F, 0, 1, scale=1.0 / 32.0)
    area = float(window * window)

    def box(a: np.ndarray) -> np.ndarray:
        return cv2.boxFilter(a, -1, (window, window), normalize=False)

    s_tt = box(dt * dt)
    noise = float(np.percentile(s_tt[half : h - half : 8, half : w - half : 8], 25)) / area
    y, x = q[idx, 1], q[idx, 0]
    a = box(ix * ix)[y, x].astype(np.float64)
    b = box(ix * iy)[y, x].astype(np.float64)
    c = box(iy * iy)[y, x].astype(np.float64)
    bx = box(ix * dt)[y, x].astype(np.float64)
    by = box(iy * dt)[y, x].astype(np.float64)
    tt = s_tt[y, x].astype(np.float64)
    min_eig = ((a + c) - np.sqrt((a - c) ** 2 + 4.0 * b * b)) / (2.0 * area)
    det = a * c - b * b
    textured = (min_eig >= LK_MIN_EIG) & (det > 0)
    det = np.where(textured, det, 1.0)
    dx = -(c * bx - b * by) / det
    dy = -(a * by - b * bx) / det
    residual = (tt + dx * bx + dy * by) / area
    still = textured & (np.hypot(dx, dy) <= max_px) & (residual <= noise_ratio * noise)
    k = idx[still]
    out[k, 0] = p[k, 0] + dx[still]
    out[k, 1] = p[k, 1] + dy[still]
    return out


def expand_views(
    rig: CameraRig,
    grey: Sequence[np.ndarray],
    points: np.ndarray,
    pixels: np.ndarray,
    candidates: np.ndarray,
    *,
    max_angle_deg: float = 40.0,
    max_px: float = 2.0,
    window: int = 21,
    levels: int = 1,
    fb_max_px: float = 1.0,
    projection=None,
) -> np.ndarray:
    """Find points in more cameras by flow from an observing camera (view expansion).

    For each candidate (camera c, point n), the observing camera r of n whose optical axis is
    nearest c's gives the patch: Lucas-Kanade flow from ``pixels[r, n]`` in image r to image c,
    started at the point's projection into c, then back (forward-backward check). The view is
    accepted where the flow converges, comes back within ``fb_max_px`` and ends within
    ``max_px`` of the projection. One flow call per (r, c) camera pair.

    Parameters
    ----------
    rig : CameraRig
        C cameras.
    grey : list of C (H, W) uint8 ndarrays
        The frame's grey images.
    points : (N, 3) float ndarray
    pixels : (C, N, 2) float ndarray
        The observations so far (NaN where a camera does not observe the point).
    candidates : (C, N) bool ndarray
        Where to search (e.g. in the image, not occluded, not observed).
    max_angle_deg : float
        Largest angle between the optical axes of r and c.
    max_px, window, levels, fb_max_px
        Acceptance distance to the projection, flow window, pyramid levels and the
        forward-backward tolerance.
    projection : Projection, optional
        ``rig.project(points)`` when the caller has it.

    Returns
    -------
    (C, N, 2) float64 ndarray
        ``pixels`` with the accepted new observations filled in.
    """
    import cv2

    C = len(rig)
    pix = check_array("pixels", pixels, (C, None, 2)).astype(np.float64)
    N = pix.shape[1]
    cand = check_array("candidates", candidates, (C, N), dtype=bool)
    out = pix.copy()
    observed = finite_rows(pix)  # (C, N)
    cand = cand & ~observed & observed.any(axis=0)[None, :]
    if not cand.any():
        return out
    proj = rig.project(points) if projection is None else projection
    angle = axis_angles(rig)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 20, 0.01)
    lk = {"winSize": (window, window), "maxLevel": levels, "criteria": crit}
    for c in np.flatnonzero(cand.any(axis=1)):
        n_c = np.flatnonzero(cand[c])
        # nearest observing camera (by optical axis) of each candidate point
        ang = np.where(observed[:, n_c], angle[c][:, None], np.inf)  # (C, n)
        ref = np.argmin(ang, axis=0)
        ok = ang[ref, np.arange(n_c.size)] <= max_angle_deg
        n_c, ref = n_c[ok], ref[ok]
        for r in np.unique(ref):
            n = n_c[ref == r]
            guess = proj.pixels[c, n]
            p1, good = _flow_fb(grey[r], grey[c], pix[r, n], lk, fb_max_px, guess=guess)
            good &= np.linalg.norm(p1 - guess, axis=1) <= max_px
            out[c, n[good]] = p1[good]
    logger.debug(
        "view expansion: %d of %d candidate views accepted",
        int(finite_rows(out).sum() - observed.sum()),
        int(cand.sum()),
    )
    return out


def to_grey(image: np.ndarray) -> np.ndarray:
    """The grey image of an RGB image (a grey image is returned as is).

    Parameters
    ----------
    image : (H, W, 3) RGB or (H, W) uint8 ndarray

    Returns
    -------
    (H, W) uint8 ndarray
    """
    import cv2

    img = np.asarray(image)
    if img.ndim == 2:
        return img
    return cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
