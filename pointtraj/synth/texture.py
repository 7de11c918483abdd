"""Procedural solid textures: high-frequency, non-repetitive colour as a function of position.

A texture is a function of a point's coordinates in its part's LOCAL frame, so the pattern moves
with the part: a pixel's colour and a ground-truth point's track agree, which is what optical flow
and feature matching need. The pattern (multi-octave value noise, blobs and warped stripes) is
baked once into an RGB voxel volume covering the part's bounding box and looked up with trilinear
interpolation, which makes shading tens of millions of hits per frame cheap.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from ..errors import check_array

__all__ = ["SolidTexture", "make_solid_texture", "value_noise"]

logger = logging.getLogger(__name__)

# cv2.remap needs source images and maps smaller than 32767 pixels a side.
_REMAP_MAX = 32767
_REMAP_WIDTH = 1024


def value_noise(
    shape: tuple[int, ...], cell: float, voxel: float, rng: np.random.Generator
) -> np.ndarray:
    """Smooth random field on a voxel grid: value noise with smoothstep interpolation.

    Random values on a coarse lattice of spacing ``cell`` are interpolated separably, axis by
    axis, with smoothstep weights (the tensor-product form of classic value noise).

    Parameters
    ----------
    shape : tuple of int
        Grid shape (one entry per axis).
    cell : float
        Lattice spacing in metres (feature size).
    voxel : float
        Voxel size in metres.
    rng : numpy.random.Generator

    Returns
    -------
    shape float32 ndarray
        Values in [0, 1] (mean 0.5), not periodic.
    """
    ratio = max(cell / voxel, 1.0)
    coarse_shape = tuple(int(np.floor((n - 1) / ratio)) + 2 for n in shape)
    out = rng.random(coarse_shape, dtype=np.float32)
    for axis, n in enumerate(shape):
        x = np.arange(n, dtype=np.float32) / np.float32(ratio)
        i0 = np.floor(x).astype(np.intp)
        s = x - i0
        s = s * s * (3 - 2 * s)  # smoothstep
        a = np.take(out, i0, axis=axis)
        b = np.take(out, i0 + 1, axis=axis)
        w = s.reshape((-1,) + (1,) * (len(shape) - axis - 1))
        out = a + (b - a) * w
    return out.astype(np.float32, copy=False)


@dataclass(eq=False)
class SolidTexture:
    """An RGB voxel volume over an axis-aligned box of a part's local frame.

    Attributes
    ----------
    origin : (3,) float ndarray
        Local coordinates of voxel (0, 0, 0)'s centre.
    voxel : float
        Voxel size in metres.
    volume : (3, X, Y, Z) float32 ndarray
        Albedo per channel in [0, 1].
    """

    origin: np.ndarray
    voxel: float
    volume: np.ndarray = field(repr=False)

    @cached_property
    def _atlas(self) -> np.ndarray | None:
        """(X, Z * Y, 3) float32: the z slices side by side, for ``cv2.remap`` (None if too big)."""
        _, X, Y, Z = self.volume.shape
        if X >= _REMAP_MAX or Y * Z >= _REMAP_MAX:
            return None
        return np.ascontiguousarray(self.volume.transpose(1, 3, 2, 0).reshape(X, Z * Y, 3))

    def sample(self, points: np.ndarray) -> np.ndarray:
        """Albedo at local points, trilinearly interpolated (clamped outside the box).

        Bilinear lookups in the slices below and above each point (``cv2.remap`` on an atlas of
        the z slices, interpolation weights quantised to 1/32 voxel) are blended linearly in z;
        volumes too large for ``cv2.remap`` use ``scipy.ndimage.map_coordinates``.

        Parameters
        ----------
        points : (N, 3) float ndarray
            Points in the part's local frame.

        Returns
        -------
        (N, 3) float32 ndarray
            RGB albedo in [0, 1].
        """
        pts = check_array("points", points, (None, 3), dtype=np.float32)
        inv = np.float32(1.0 / self.voxel)
        org = self.origin.astype(np.float32)
        idx = np.empty((3, pts.shape[0]), np.float32)
        for ax in range(3):
            np.subtract(pts[:, ax], org[ax], out=idx[ax])
            idx[ax] *= inv
        atlas = self._atlas
        if atlas is None or pts.shape[0] == 0:
            return self._sample_ndimage(idx)
        import cv2

        _, X, Y, Z = self.volume.shape
        x, y, z = idx
        np.clip(y, 0, Y - 1, out=y)
        np.clip(z, 0, Z - 1, out=z)
        z0 = np.minimum(np.floor(z), max(Z - 2, 0))
        col = z0 * np.float32(Y) + y
        n = len(x)
        rows = -(-n // _REMAP_WIDTH)
        pad = rows * _REMAP_WIDTH - n
        map_y = np.pad(x, (0, pad)).reshape(rows, _REMAP_WIDTH)

        def lookup(cols: np.ndarray) -> np.ndarray:
            map_x = np.pad(cols, (0, pad)).reshape(rows, _REMAP_WIDTH)
            out = cv2.remap(atlas, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
            return out.reshape(-1, 3)[:n]

        lo = lookup(col)
        if Z == 1:
            return lo
        hi = lookup(col + np.float32(Y))
        hi -= lo
        hi *= (z - z0)[:, None]
        lo += hi
        return lo

    def _sample_ndimage(self, idx: np.ndarray) -> np.ndarray:
        from scipy import ndimage

        out = np.empty((idx.shape[1], 3), np.float32)
        for ch in range(3):
            out[:, ch] = ndimage.map_coordinates(
                self.volume[ch], idx, order=1, mode="nearest", output=np.float32, prefilter=False
            )
        return out


def make_solid_texture(
    lo: np.ndarray,
    hi: np.ndarray,
    base_color: tuple[float, float, float],
    rng: np.random.Generator,
    *,
    voxel: float = 0.004,
    scale: float = 1.0,
) -> SolidTexture:
    """Bake a procedural clothing/skin-like pattern into a :class:`SolidTexture`.

    The albedo is ``base * (0.35 + 0.9 * fbm)`` (four octaves of value noise, cells from
    ``8 cm`` down to ``1 cm`` times ``scale``), mixed with a random second colour inside blobs
    (thresholded noise) and darkened along noise-warped stripes. Contrast is strong at
    centimetre scale, so FAST/ORB corners and Lucas-Kanade flow have something to lock on to.

    Parameters
    ----------
    lo, hi : (3,) float ndarray
        Local bounding box to cover (padded by two voxels).
    base_color : (3,) tuple of float
        Base albedo in [0, 1].
    rng : numpy.random.Generator
        Source of all randomness (so a scene is deterministic for a seed).
    voxel : float
        Voxel size in metres.
    scale : float
        Multiplies every feature size (use > 1 for large background surfaces).

    Returns
    -------
    SolidTexture
    """
    lo = np.asarray(lo, float) - 2 * voxel
    hi = np.asarray(hi, float) + 2 * voxel
    shape = tuple(int(n) for n in np.maximum(np.ceil((hi - lo) / voxel).astype(int) + 1, 1))
    fbm = np.zeros(shape, np.float32)
    amp, total = 1.0, 0.0
    for cell in (0.08, 0.04, 0.02, 0.01):
        fbm += amp * (value_noise(shape, cell * scale, voxel, rng) - 0.5)
        total += amp
        amp *= 0.7
    fbm = np.clip(0.5 + 1.6 * fbm / total, 0.0, 1.0)  # contrast-stretched
    blobs = value_noise(shape, 0.03 * scale, voxel, rng)
    blobs = np.clip((blobs - 0.56) / 0.06, 0.0, 1.0)  # sharp-edged spots
    # Warped stripes along a random direction.
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    axes = np.meshgrid(*[lo[i] + voxel * np.arange(shape[i]) for i in range(3)], indexing="ij")
    phase = sum(direction[i] * axes[i] for i in range(3)) / (0.035 * scale)
    warp = value_noise(shape, 0.06 * scale, voxel, rng)
    stripes = 0.5 + 0.5 * np.sin(2 * np.pi * phase + 8.0 * warp)
    stripes = np.clip((stripes - 0.7) / 0.15, 0.0, 1.0).astype(np.float32)
    base = np.asarray(base_color, np.float32)
    accent = rng.random(3).astype(np.float32)
    accent = np.where(np.abs(accent - base) < 0.3, 1.0 - accent, accent).astype(np.float32)
    lum = 0.35 + 0.9 * fbm  # (X, Y, Z)
    vol = np.empty((3,) + shape, np.float32)
    for ch in range(3):
        c = base[ch] * lum
        c = c * (1.0 - blobs) + accent[ch] * (0.6 + 0.6 * fbm) * blobs
        vol[ch] = np.clip(c * (1.0 - 0.55 * stripes), 0.0, 1.0)
    return SolidTexture(origin=lo, voxel=float(voxel), volume=vol)
