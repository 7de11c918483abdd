"""The Lucas-Kanade window against the subject's size (ReconstructConfig.lk_window, lk_window_for).

A window wider than the limb it tracks holds part of the static background and lags behind the
limb; the rig-derived window spans a few centimetres of the subject instead.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from pointtraj.reconstruct.config import LK_WINDOW_RANGE, ReconstructConfig, lk_window_for
from pointtraj.reconstruct.flow import track_flow
from pointtraj.synth.presets import make_rig


def _texture(shape: tuple[int, int], seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    noise = rng.random(shape).astype(np.float32)
    return cv2.GaussianBlur(noise, (0, 0), 1.2) * 255.0


def _limb_frames(frames: int, width: int, speed: float) -> tuple[list[np.ndarray], np.ndarray]:
    """Images of a textured vertical bar ``width`` px wide moving right by ``speed`` px a frame
    over a static textured background; and the bar's x offset at each frame."""
    H, W = 96, 160
    back = _texture((H, W), 1)
    bar = _texture((H, W), 2)
    xs = np.arange(W, dtype=np.float32)
    images, offsets = [], speed * np.arange(frames)
    for dx in offsets:
        # the bar's texture moves with it; its edges too (sub-pixel, by linear coverage)
        shifted = cv2.warpAffine(
            bar, np.float32([[1, 0, dx], [0, 1, 0]]), (W, H), flags=cv2.INTER_LINEAR
        )
        left = 70.0 + dx
        cover = np.clip(np.minimum(xs - left + 0.5, left + width - xs + 0.5), 0.0, 1.0)
        im = back * (1 - cover) + shifted * cover
        images.append(np.clip(im, 0, 255).astype(np.uint8))
    return images, offsets


def _lag(window: int, images: list[np.ndarray], offsets: np.ndarray, width: int) -> float:
    """Median distance (px) behind the bar after frame-to-frame tracking of its middle."""
    start = np.stack([np.full(9, 70.0 + width / 2 - 0.5), np.linspace(30, 66, 9)], axis=1)
    p = start.copy()
    for a, b in zip(images[:-1], images[1:], strict=True):
        p = track_flow(a, b, p, window=window, levels=2, fb_max_px=1.0)
    assert np.isfinite(p).all()
    return float(np.median(start[:, 0] + offsets[-1] - p[:, 0]))


def test_a_window_wider_than_the_limb_lags_behind_it():
    width = 12  # a limb on the demo's 640x512 images is 11-16 px across
    images, offsets = _limb_frames(21, width, 0.4)
    wide, fitted = _lag(21, images, offsets, width), _lag(9, images, offsets, width)
    # the static background in the 21 px window holds the track back; 9 px follows the bar
    assert wide > 1.0
    assert abs(fitted) < 0.5 * wide


@pytest.mark.parametrize("preset, window", [("ring8", 7), ("paper69", 15), ("lab4", 13)])
def test_lk_window_for_spans_the_subject(preset, window):
    rig = make_rig(preset)
    got, px_per_m = lk_window_for(rig)
    assert got == window and got % 2 == 1
    assert LK_WINDOW_RANGE[0] <= got <= LK_WINDOW_RANGE[1]
    # the window is the smallest odd size covering 4 cm at the working distance (clamped)
    span = px_per_m * 0.04
    assert got >= span and got - 2 < span or got == LK_WINDOW_RANGE[0] and span < got
    assert ReconstructConfig().for_rig(rig, log=False).lk_window == window
