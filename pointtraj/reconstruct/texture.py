"""The scale of the images' texture, and the patch spacing chosen from it (densification's and
view discovery's).

Densification compares 7 x 7 patches of samples ``patch_spacing_px`` apart, view discovery
5 x 5 ones. How wide a patch must be to hold enough texture depends on the images, not only
on the rig:

- rendered texture (the synthetic captures) is fine-grained to the pixel: a patch 12 px across
  (2 px apart) already holds 85-95 % of the contrast of one twice as wide;
- real video of people (natural images, whose contrast keeps growing with scale; optics,
  demosaicing and compression take the finest detail) holds under half of it at 12 px: on
  skin and clothing such a patch is nearly flat, and what it matches are edges, often
  the silhouette against the background behind.

:func:`texture_patch_spacing` measures that on a frame's images and takes the smallest
spacing whose 7 x 7 patch holds :data:`TEXTURE_HELD` of the contrast of a patch twice as
wide; the reconstruction (:func:`~.stage.with_texture_choices`) gives it to both patches.
``docs/real_captures.md``, "Densification's patch from the images' texture", has the
figures on every capture at hand.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..errors import check_array

logger = logging.getLogger(__name__)

#: The patch spacings (px) the choice is made among; the first is the default for images
#: too small to measure.
PATCH_SPACINGS = (2.0, 3.0, 4.0, 5.0, 6.0)
#: The share of the contrast of a patch twice as wide that the chosen patch holds (the
#: samples' standard deviation; medians over the textured half of each image, then over
#: cameras). Rendered captures hold 0.84-0.95 at 2 px, real video 0.36-0.50; real video
#: reaches 0.7 at 4-6 px (``docs/real_captures.md``).
TEXTURE_HELD = 0.70
#: Spacing (px) of the grid of patch centres sampled in each image.
GRID_PX = 12
#: At most this many cameras (evenly spread over the rig's order) are measured.
MAX_CAMERAS = 6


@dataclass(frozen=True)
class TextureScale:
    """How a frame's texture grows with patch spacing (:func:`measure_texture_scale`).

    Attributes
    ----------
    spacings : (S,) float ndarray
        The candidate spacings (px), :data:`PATCH_SPACINGS`.
    held : (S,) float ndarray
        For each, the median over the measured cameras of the contrast a patch of that spacing
        holds over the contrast of one twice as wide (NaN where no camera could be measured).
    cameras : int
        How many cameras were measured (0: every image too small or flat).
    """

    spacings: np.ndarray
    held: np.ndarray
    cameras: int

    def patch_spacing(self, held: float = TEXTURE_HELD) -> float:
        """The smallest spacing whose patch holds ``held`` (the largest where none does; the
        first where nothing was measured)."""
        if self.cameras == 0:
            return float(self.spacings[0])
        ok = np.flatnonzero(self.held >= held)
        return float(self.spacings[ok[0]] if ok.size else self.spacings[-1])


def patch_contrast(
    grey: np.ndarray, spacings: Sequence[float], patch_size: int = 7, grid_px: int = GRID_PX
) -> np.ndarray | None:
    """The contrast of patches at each spacing, on the textured half of an image.

    Parameters
    ----------
    grey : (H, W) ndarray
        A grey image.
    spacings : sequence of S float
        Sample spacings (px) of a ``patch_size`` x ``patch_size`` patch.
    patch_size : int
    grid_px : int
        Spacing of the grid of patch centres.

    Returns
    -------
    (S,) float ndarray or None
        The median, over the grid's patches whose contrast at the widest spacing is at least
        its median (the textured half), of each spacing's patch standard deviation (grey
        levels). None when the image holds no grid point for the widest patch.
    """
    grey = check_array("grey", grey, (None, None)).astype(np.float32, copy=False)
    s = np.asarray(spacings, float)
    half = (patch_size - 1) // 2
    margin = int(np.ceil(half * s.max()))
    h, w = grey.shape
    if h <= 2 * margin or w <= 2 * margin:
        return None
    ys = np.arange(margin, h - margin, grid_px)
    xs = np.arange(margin, w - margin, grid_px)
    cy, cx = (a.ravel() for a in np.meshgrid(ys, xs, indexing="ij"))  # (G,)
    k = np.arange(-half, half + 1)
    std = np.empty((s.size, cy.size), np.float32)
    for i, sp in enumerate(s):
        off = np.rint(k * sp).astype(np.int64)  # (P,)
        rows = cy[:, None, None] + off[None, :, None]  # (G, P, 1)
        cols = cx[:, None, None] + off[None, None, :]  # (G, 1, P)
        std[i] = grey[rows, cols].reshape(cy.size, -1).std(axis=1)
    textured = std[-1] >= np.median(std[-1])  # (G,)
    return np.median(std[:, textured], axis=1)


def texture_cameras(num_cameras: int) -> np.ndarray:
    """The cameras :func:`measure_texture_scale` is given: at most :data:`MAX_CAMERAS`,
    evenly spread over the rig's order.

    Parameters
    ----------
    num_cameras : int

    Returns
    -------
    (K,) int ndarray
    """
    k = min(MAX_CAMERAS, num_cameras)
    return np.unique(np.linspace(0, num_cameras - 1, k).round().astype(np.int64))


def measure_texture_scale(images: Sequence[np.ndarray], patch_size: int = 7) -> TextureScale:
    """How much of the contrast of a patch twice as wide each candidate spacing holds.

    Parameters
    ----------
    images : sequence of (H, W, 3) RGB or (H, W) uint8 ndarray
        Images of one frame (:func:`texture_cameras` picks which).
    patch_size : int
        Samples per side of the patch.

    Returns
    -------
    TextureScale
    """
    from .flow import to_grey

    spacings = np.asarray(PATCH_SPACINGS, float)
    both = np.concatenate([spacings, 2 * spacings])  # (2S,)
    held = []
    for image in images:
        contrast = patch_contrast(to_grey(image), both, patch_size)
        if contrast is None or not np.all(contrast[spacings.size :] > 0):
            continue
        held.append(contrast[: spacings.size] / contrast[spacings.size :])
    if not held:
        return TextureScale(spacings, np.full(spacings.size, np.nan), 0)
    return TextureScale(spacings, np.median(np.array(held), axis=0), len(held))


def texture_patch_spacing(
    images: Sequence[np.ndarray], patch_size: int = 7, held: float = TEXTURE_HELD
) -> tuple[float, TextureScale]:
    """The patch spacing (densification's and view discovery's) from a frame's texture (see
    the module docstring).

    Parameters
    ----------
    images : sequence of (H, W, 3) RGB or (H, W) uint8 ndarray
        Images of one frame (:func:`texture_cameras` picks which).
    patch_size : int
    held : float
        The share of the contrast of a patch twice as wide that the patch must hold.

    Returns
    -------
    spacing : float
        The smallest of :data:`PATCH_SPACINGS` whose patch holds ``held`` (the largest where
        none does; the first where the images are too small or flat to measure).
    scale : TextureScale
        What was measured.
    """
    scale = measure_texture_scale(images, patch_size)
    return scale.patch_spacing(held), scale


def describe_texture_scale(scale: TextureScale, spacing: float, held: float = TEXTURE_HELD) -> str:
    """One line on the choice, for the log: what each spacing holds, and the one chosen."""
    if scale.cameras == 0:
        return f"{spacing:g} px (the images are too small or flat to measure their texture)"
    each = ", ".join(f"{s:g} px {h:.2f}" for s, h in zip(scale.spacings, scale.held))
    return (
        f"{spacing:g} px from the images' texture (of the contrast of a patch twice as wide, "
        f"a patch holds: {each}; the smallest holding {held:g}; {scale.cameras} cameras)"
    )
