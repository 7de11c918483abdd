"""Bilinear sampling of 2D confidence maps at the projections of 3D points.

A recogniser's map L2D (h, w, K) may be coarser than the image (W x H). As in
:mod:`pointtraj.semantics.recognizers.base`, image pixel (u, v) (OpenCV convention: the origin is
the top-left pixel's centre) maps to ``((u + 0.5) w / W - 0.5, (v + 0.5) h / H - 0.5)`` in the
map. Inside the image the map is clamped at its border (the border cells extend to the image
edge); a projection outside the image (``u < -0.5`` or ``u >= W - 0.5``, likewise v) or a NaN
projection samples to 0.
"""

from __future__ import annotations

import numpy as np

from ..errors import ValidationError, check_array

__all__ = ["sample_confidences", "map_coordinates"]


def map_coordinates(
    pixels: np.ndarray, image_size: tuple[int, int], map_size: tuple[int, int]
) -> np.ndarray:
    """Image pixel coordinates to map coordinates.

    Parameters
    ----------
    pixels : (N, 2) float ndarray
        (u, v) image pixels.
    image_size : (W, H)
        Image width and height.
    map_size : (w, h)
        Map width and height.

    Returns
    -------
    (N, 2) float32 ndarray
        (x, y) in the map's pixel coordinates.

    Examples
    --------
    >>> map_coordinates(np.array([[-0.5, 3.5], [7.5, 7.5]]), (8, 8), (2, 2)).tolist()
    [[-0.5, 0.5], [1.5, 1.5]]
    """
    scale = np.array([map_size[0] / image_size[0], map_size[1] / image_size[1]], dtype=np.float32)
    return (np.asarray(pixels, dtype=np.float32) + np.float32(0.5)) * scale - np.float32(0.5)


def sample_confidences(
    L2D: np.ndarray, pixels: np.ndarray, image_size: tuple[int, int], *, exact: bool = False
) -> np.ndarray:
    """Bilinearly sample a confidence map at image pixels.

    Parameters
    ----------
    L2D : (h, w, K) float ndarray
        Confidence map of one image (float16 or float32), possibly coarser than the image.
    pixels : (N, 2) float ndarray
        (u, v) image pixel coordinates, for example ``CameraRig.project(X).pixels[c]``.
    image_size : (W, H)
        Size of the image the pixels refer to.
    exact : bool
        Interpolate in float32 with numpy. The default uses ``cv2.remap``, several times
        faster, which for more than 4 channels rounds the sample position to 1/32 of a map cell
        (1/4 image pixel at 1/8 scale; a value error of at most 1/64 of the difference between
        neighbouring cells per axis).

    Returns
    -------
    (N, K) float32 ndarray
        Sampled confidences; rows of NaN pixels or pixels outside the image are 0.

    Raises
    ------
    ValidationError
        If the shapes are wrong or the image size is not positive.

    Examples
    --------
    >>> L = np.zeros((2, 2, 1), np.float32); L[0, 1, 0] = 1.0
    >>> sample_confidences(L, np.array([[1.5, 0.0], [3.0, 0.0], [5.5, 0.0]]), (4, 4))[:, 0]
    array([0.5, 1. , 0. ], dtype=float32)
    """
    if not isinstance(L2D, np.ndarray) or L2D.ndim != 3:
        raise ValidationError(
            f"L2D: expected shape (h, w, K), got {getattr(L2D, 'shape', type(L2D))}"
        )
    pixels = check_array("pixels", pixels, (None, 2), dtype=None)
    W, H = (int(s) for s in image_size)
    if W <= 0 or H <= 0:
        raise ValidationError(f"image_size: expected positive (W, H), got {image_size}")
    h, w, K = L2D.shape
    if h == 0 or w == 0:
        raise ValidationError(f"L2D: empty map of shape {L2D.shape}")
    pix = np.asarray(pixels, dtype=np.float32)
    N = pix.shape[0]
    inside = (
        (pix[:, 0] >= -0.5) & (pix[:, 0] < W - 0.5) & (pix[:, 1] >= -0.5) & (pix[:, 1] < H - 0.5)
    )  # (N,) False for NaN
    if not inside.any() or K == 0:
        return np.zeros((N, K), dtype=np.float32)
    # Sample every row (outside and NaN rows at a harmless place), then zero those rows: cheaper
    # than gathering and scattering the inside rows when most are inside.
    xy = map_coordinates(pix, (W, H), (w, h))  # (N, 2)
    all_inside = bool(inside.all())
    if not all_inside:
        xy[~inside] = 0.0
    if exact or K > _CV_MAX_CHANNELS:
        out = _bilinear_numpy(L2D, xy)
    else:
        out = _bilinear_cv2(L2D, xy)
    if not all_inside:
        out[~inside] = 0.0
    return out


_CV_MAX_CHANNELS = 512  # OpenCV's CV_CN_MAX
_CV_MAX_SIDE = 1024  # remap needs maps with fewer than SHRT_MAX rows and columns


def _bilinear_cv2(L2D: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Bilinear samples (n, K) at map coordinates (n, 2), border replicated, with cv2.remap."""
    import cv2

    n = xy.shape[0]
    K = L2D.shape[2]
    cols = min(n, _CV_MAX_SIDE)
    rows = -(-n // cols)
    mx = np.zeros(rows * cols, np.float32)
    my = np.zeros(rows * cols, np.float32)
    mx[:n] = xy[:, 0]
    my[:n] = xy[:, 1]
    src = L2D if L2D.dtype == np.float32 else L2D.astype(np.float32)
    res = cv2.remap(
        src,
        mx.reshape(rows, cols),
        my.reshape(rows, cols),
        interpolation=cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_REPLICATE,
    )
    return res.reshape(rows * cols, K)[:n]


def _bilinear_numpy(L2D: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Bilinear samples (n, K) at map coordinates (n, 2), border replicated, in float32."""
    h, w, K = L2D.shape
    x = np.clip(xy[:, 0], 0.0, w - 1)
    y = np.clip(xy[:, 1], 0.0, h - 1)
    x0 = np.minimum(x.astype(np.int64), max(w - 2, 0))
    y0 = np.minimum(y.astype(np.int64), max(h - 2, 0))
    fx = (x - x0).astype(np.float32)[:, None]  # (n, 1)
    fy = (y - y0).astype(np.float32)[:, None]
    x1 = np.minimum(x0 + 1, w - 1)
    y1 = np.minimum(y0 + 1, h - 1)
    flat = L2D.reshape(h * w, K)
    a = np.take(flat, y0 * w + x0, axis=0).astype(np.float32, copy=False)  # (n, K)
    b = np.take(flat, y0 * w + x1, axis=0).astype(np.float32, copy=False)
    c = np.take(flat, y1 * w + x0, axis=0).astype(np.float32, copy=False)
    d = np.take(flat, y1 * w + x1, axis=0).astype(np.float32, copy=False)
    top = a + (b - a) * fx
    bottom = c + (d - c) * fx
    return top + (bottom - top) * fy
