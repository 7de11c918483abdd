"""Re-acquiring a view that the flow lost, from the same camera's last image of the point.

A two-view point dies when Lucas-Kanade loses it in one camera (the forward-backward check, a
limb passing in front, motion blur). One-view survival (:mod:`~.survive`) carries it on its
remaining view for a few frames, and view discovery (:mod:`~.views`) searches the lost camera
with a patch from another camera, which at the wide baselines of 4-8 camera rigs rarely
matches. The lost camera's own image of the point, a few frames old, is a better template: the
same viewpoint, the same lighting.

When a carried point loses a view, a patch of 7 x 7 samples (at view discovery's patch
spacing, blurred) is cut from that camera's previous image around the last tracked pixel, with
the pixel's offset from the point's projection there (the calibration's and the
triangulation's error at that point, which the next frames share). While the point goes on
with one view, the patch is searched by NCC within ``radius`` pixels of the carried point's
projection plus that offset. An interior peak of NCC >= ``min_ncc``, clear of every other peak
by ``margin``, is the view's pixel, and the tracker triangulates the point again; the view
comes back only where RANSAC keeps both views.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import check_array
from .densify import _zscore

__all__ = ["LostViews", "LOST_FIELDS", "PATCH_SIDE", "cut_patches", "search_patches"]

#: Samples on a side of a patch.
PATCH_SIDE = 7
#: Elements of the (points, positions, samples) work array of one block of a search.
_BLOCK = 1 << 22
#: The arrays of :class:`LostViews`, in order (``state/live.npz`` keeps them as ``lost_<name>``).
LOST_FIELDS = ("ids", "camera", "offset", "frac", "patch")
#: Patches whose samples' standard deviation is at most this are flat: nothing to compare.
_FLAT_STD = 1e-3


@dataclass(frozen=True)
class LostViews:
    """The lost views that carried points may get back, one per trajectory.

    Attributes
    ----------
    ids : (L,) int64 ndarray
        Trajectory ids.
    camera : (L,) int64 ndarray
        The camera that lost the view.
    offset : (L, 2) float32 ndarray
        The patch centre's pixel minus the point's projection there, at the last frame the
        camera tracked it (pixels).
    frac : (L, 2) float32 ndarray
        The tracked pixel minus the patch centre (the patch is cut at whole pixels).
    patch : (L, P) float32 ndarray
        The patch's samples, centred and scaled to unit RMS (``P = PATCH_SIDE ** 2``).
    """

    ids: np.ndarray
    camera: np.ndarray
    offset: np.ndarray
    frac: np.ndarray
    patch: np.ndarray

    @classmethod
    def empty(cls) -> LostViews:
        """No lost views."""
        P = PATCH_SIDE * PATCH_SIDE
        return cls(
            np.zeros(0, np.int64),
            np.zeros(0, np.int64),
            np.zeros((0, 2), np.float32),
            np.zeros((0, 2), np.float32),
            np.zeros((0, P), np.float32),
        )

    def __len__(self) -> int:
        return int(self.ids.shape[0])

    def take(self, rows: np.ndarray) -> LostViews:
        """The entries at ``rows`` (indices or a boolean mask)."""
        return LostViews(*(getattr(self, f)[rows] for f in LOST_FIELDS))

    def kept(self, ids: np.ndarray) -> LostViews:
        """The entries of the trajectories in ``ids`` ((K,) int64)."""
        return self.take(np.isin(self.ids, ids))

    @staticmethod
    def concat(parts: list[LostViews]) -> LostViews:
        """The entries of ``parts``, in order."""
        if not parts:
            return LostViews.empty()
        return LostViews(*(np.concatenate([getattr(p, f) for p in parts]) for f in LOST_FIELDS))

    def lookup(self, ids: np.ndarray) -> np.ndarray:
        """(K,) int64: each id's entry, -1 where it has none."""
        ids = np.asarray(ids, np.int64)
        out = np.full(ids.shape, -1, np.int64)
        if len(self) == 0 or ids.size == 0:
            return out
        order = np.argsort(self.ids, kind="stable")
        pos = np.searchsorted(self.ids[order], ids)
        pos = np.minimum(pos, len(self) - 1)
        hit = self.ids[order][pos] == ids
        out[hit] = order[pos[hit]]
        return out


def blur_sigma(spacing: float) -> float:
    """The Gaussian blur (pixels) of the images patches are sampled from, for a spacing."""
    return max(1.0, 0.5 * float(spacing))


def _windows(grey: np.ndarray, centres: np.ndarray, half: int) -> tuple[np.ndarray, np.ndarray]:
    """(n, 2 half + 1, 2 half + 1) float32 windows of ``grey`` around whole-pixel ``centres``
    ((n, 2) int, x then y), and which lie wholly inside the image (the others are zeros)."""
    H, W = grey.shape[:2]
    n = len(centres)
    x, y = centres[:, 0], centres[:, 1]
    inside = (x - half >= 0) & (y - half >= 0) & (x + half < W) & (y + half < H)
    side = 2 * half + 1
    out = np.zeros((n, side, side), np.float32)
    sel = np.flatnonzero(inside)
    if sel.size:
        r = np.arange(-half, half + 1)
        rows = (y[sel, None] + r)[:, :, None]
        cols = (x[sel, None] + r)[:, None, :]
        out[sel] = grey[rows, cols]
    return out, inside


def _blurred_windows(
    grey: np.ndarray, centres: np.ndarray, half: int, sigma: float
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_windows`, blurred by ``sigma`` (a margin is cut around them and dropped).

    The windows are blurred as one tall image: a row of one window is blurred with rows of
    the next only within the margin, which is dropped.
    """
    import cv2

    m = math.ceil(3.0 * sigma)
    win, inside = _windows(grey, centres, half + m)
    n, side = win.shape[:2]
    if n:
        tall = win.reshape(n * side, side)
        cv2.GaussianBlur(
            tall, (2 * m + 1, 2 * m + 1), sigma, dst=tall, borderType=cv2.BORDER_REPLICATE
        )
    return win[:, m : side - m, m : side - m], inside


def cut_patches(
    grey: np.ndarray, pixels: np.ndarray, spacing: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Patches of 7 x 7 samples, ``spacing`` apart, around pixels of one image.

    Parameters
    ----------
    grey : (H, W) uint8 ndarray
    pixels : (n, 2) float ndarray
        Patch centres (distorted pixels, x then y).
    spacing : float
        Pixels between samples (rounded to a whole number, at least 1).

    Returns
    -------
    patch : (n, P) float32 ndarray
        Centred and scaled to unit RMS (``P = PATCH_SIDE ** 2``).
    frac : (n, 2) float32 ndarray
        ``pixels`` minus the whole pixel each patch is centred on.
    ok : (n,) bool ndarray
        Inside the image and not flat.
    """
    px = check_array("pixels", pixels, (None, 2))
    s = max(1, round(float(spacing)))
    centres = np.rint(np.nan_to_num(px, nan=-1e6)).astype(np.int64)
    h = s * (PATCH_SIDE // 2)
    win, inside = _blurred_windows(grey, centres, h, blur_sigma(spacing))
    patch, std = _zscore(win[:, ::s, ::s].reshape(len(px), -1))
    ok = inside & (std > _FLAT_STD) & np.isfinite(patch).all(axis=1)
    patch = np.where(ok[:, None], patch, 0.0).astype(np.float32)
    return patch, (px - centres).astype(np.float32), ok


def search_patches(
    grey: np.ndarray,
    patches: np.ndarray,
    centres: np.ndarray,
    spacing: float,
    radius: float,
    min_ncc: float,
    margin: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Find patches in an image by NCC, each within a radius of its expected pixel.

    Parameters
    ----------
    grey : (H, W) uint8 ndarray
    patches : (n, P) float ndarray
        From :func:`cut_patches` (the same ``spacing``).
    centres : (n, 2) float ndarray
        Expected pixels of the patches' centres (NaN: not searched).
    spacing : float
    radius : float
        Whole pixels searched each way around a centre (a square, at least 1).
    min_ncc, margin : float
        Accept the best position where its NCC is at least ``min_ncc``, it is not on the
        square's border, and every other local peak of the NCC is at least ``margin`` below it.

    Returns
    -------
    pixels : (n, 2) float64 ndarray
        The patches' centres found (sub-pixel, by a parabola each way), NaN where not found.
    ncc : (n,) float64 ndarray
        The best NCC (NaN where nothing was compared).
    """
    pt = check_array("patches", patches, (None, PATCH_SIDE * PATCH_SIDE)).astype(np.float32)
    n = len(pt)
    ctr = check_array("centres", centres, (n, 2))
    s = max(1, round(float(spacing)))
    R = max(1, math.ceil(float(radius)))
    G = 2 * R + 1
    h = s * (PATCH_SIDE // 2)
    found = np.full((n, 2), np.nan)
    best_ncc = np.full(n, np.nan)
    todo = np.flatnonzero(np.isfinite(ctr).all(axis=1))
    if todo.size == 0:
        return found, best_ncc
    base = np.rint(ctr[todo]).astype(np.int64)
    sigma = blur_sigma(spacing)
    tmpl = pt.reshape(n, PATCH_SIDE, PATCH_SIDE)
    step = max(1, _BLOCK // ((G + 2 * h) ** 2 * 4))
    for a in range(0, todo.size, step):
        idx = todo[a : a + step]
        b = base[a : a + step]
        win, inside = _blurred_windows(grey, b, R + h, sigma)
        ncc = _ncc_map(win, tmpl[idx], s, G)
        ncc[~inside] = -1.0
        flat = ncc.reshape(len(idx), -1)
        best = np.argmax(flat, axis=1)
        ky, kx = np.divmod(best, G)
        peak = flat[np.arange(len(idx)), best]
        # other local peaks (at least their 8 neighbours), outside the best one's 3 x 3
        pad = np.pad(ncc, ((0, 0), (1, 1), (1, 1)), constant_values=-np.inf)
        local = np.ones(ncc.shape, bool)
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                if dy or dx:
                    local &= ncc >= pad[:, 1 + dy : 1 + dy + G, 1 + dx : 1 + dx + G]
        yy, xx = np.arange(G)[None, :, None], np.arange(G)[None, None, :]
        near = (np.abs(yy - ky[:, None, None]) <= 1) & (np.abs(xx - kx[:, None, None]) <= 1)
        rival = np.where(local & ~near, ncc, -1.0).reshape(len(idx), -1).max(axis=1)
        interior = (ky > 0) & (ky < G - 1) & (kx > 0) & (kx < G - 1)
        ok = inside & interior & (peak >= min_ncc) & (peak - rival >= margin)
        best_ncc[idx] = np.where(inside, peak, np.nan)
        if not ok.any():
            continue
        r = np.flatnonzero(ok)
        ky, kx = ky[r], kx[r]
        c0 = ncc[r, ky, kx]
        dx = _parabola(ncc[r, ky, kx - 1], c0, ncc[r, ky, kx + 1])
        dy = _parabola(ncc[r, ky - 1, kx], c0, ncc[r, ky + 1, kx])
        found[idx[r], 0] = b[r, 0] + (kx - R) + dx
        found[idx[r], 1] = b[r, 1] + (ky - R) + dy
    return found, best_ncc


def _ncc_map(win: np.ndarray, tmpl: np.ndarray, s: int, G: int) -> np.ndarray:
    """NCC of each template with the patches of its window at every whole-pixel position.

    ``win`` (n, G + 2h, G + 2h) float32 with ``h = s * (PATCH_SIDE // 2)``; ``tmpl`` (n, k, k)
    centred and unit RMS. Returns (n, G, G) float32 NCC, -1 where a patch is flat. The patches'
    sums and the products with the template are shifted adds of the window (7 x 7 of them),
    not a copy of every patch.
    """
    k = PATCH_SIDE
    n = len(win)
    win = win - win.mean(axis=(1, 2), keepdims=True)  # smaller sums of squares in float32
    dot = np.zeros((n, G, G), np.float32)
    for i in range(k):
        rows = win[:, s * i : s * i + G, :]
        for j in range(k):
            dot += tmpl[:, i, j, None, None] * rows[:, :, s * j : s * j + G]
    cols = sum(win[:, :, s * j : s * j + G] for j in range(k))  # (n, G + 2h, G)
    cols2 = sum(np.square(win[:, :, s * j : s * j + G]) for j in range(k))
    s1 = sum(cols[:, s * i : s * i + G, :] for i in range(k)).astype(np.float64)
    s2 = sum(cols2[:, s * i : s * i + G, :] for i in range(k)).astype(np.float64)
    P = k * k
    var = np.maximum(s2 / P - np.square(s1 / P), 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        ncc = dot / (P * np.sqrt(var))
    return np.where(var > _FLAT_STD**2, ncc, -1.0).astype(np.float32)


def _parabola(left: np.ndarray, mid: np.ndarray, right: np.ndarray) -> np.ndarray:
    """The vertex's offset (within +-0.5) of the parabola through three equally spaced values."""
    den = left - 2.0 * mid + right
    with np.errstate(invalid="ignore", divide="ignore"):
        d = np.where(den < 0, 0.5 * (left - right) / den, 0.0)
    return np.clip(d, -0.5, 0.5)
