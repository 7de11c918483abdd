"""Tests of pointtraj.semantics.sampling: bilinear sampling of coarse confidence maps."""

from __future__ import annotations

import numpy as np
import pytest

from pointtraj.errors import ValidationError
from pointtraj.semantics.sampling import map_coordinates, sample_confidences


def test_full_resolution_integer_pixels_are_exact():
    rng = np.random.default_rng(0)
    L = rng.random((12, 16, 3), dtype=np.float32)
    v, u = np.mgrid[0:12, 0:16]
    pixels = np.stack([u.ravel(), v.ravel()], axis=1).astype(float)
    out = sample_confidences(L, pixels, (16, 12))
    np.testing.assert_array_equal(out, L.reshape(-1, 3))


def test_linear_map_is_reproduced_at_the_documented_scale():
    """A map linear in its own coordinates samples to that function of the scaled pixel."""
    h, w, W, H = 16, 20, 160, 128
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    L = np.stack([x, y, 2 * x - y + 1], axis=2)  # (h, w, 3)
    rng = np.random.default_rng(1)
    # Stay where the map coordinates lie within [0, w-1] x [0, h-1] (no border clamping).
    pixels = rng.uniform([4.0, 4.0], [W - 5.0, H - 5.0], size=(500, 2))
    out = sample_confidences(L, pixels, (W, H))
    xy = map_coordinates(pixels, (W, H), (w, h))
    np.testing.assert_allclose(out[:, 0], xy[:, 0], atol=1e-4)
    np.testing.assert_allclose(out[:, 1], xy[:, 1], atol=1e-4)
    np.testing.assert_allclose(out[:, 2], 2 * xy[:, 0] - xy[:, 1] + 1, atol=1e-4)


def test_agrees_with_cv2_remap():
    import cv2

    rng = np.random.default_rng(2)
    L = rng.random((32, 40, 4), dtype=np.float32)
    pixels = rng.uniform(-0.5, [319.4, 255.4], size=(1000, 2))
    xy = map_coordinates(pixels, (320, 256), (40, 32))
    ref = cv2.remap(
        L,
        xy[:, 0].reshape(-1, 1),
        xy[:, 1].reshape(-1, 1),
        interpolation=cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_REPLICATE,
    ).reshape(-1, 4)
    out = sample_confidences(L, pixels, (320, 256))
    np.testing.assert_allclose(out, ref, atol=2e-3)  # cv2 uses 5-bit interpolation weights


def test_outside_and_nan_sample_zero():
    L = np.ones((4, 4, 2), np.float16)
    pixels = np.array(
        [[np.nan, 3.0], [-0.6, 1.0], [32.0, 1.0], [1.0, 31.6], [0.0, 0.0], [31.4, 31.4]]
    )
    out = sample_confidences(L, pixels, (32, 32))
    assert out.dtype == np.float32 and out.shape == (6, 2)
    np.testing.assert_array_equal(out[:, 0], [0, 0, 0, 0, 1, 1])


def test_single_cell_map():
    L = np.full((1, 1, 2), 0.25, np.float32)
    out = sample_confidences(L, np.array([[0.0, 0.0], [9.0, 9.0]]), (10, 10))
    np.testing.assert_allclose(out, 0.25)


def test_empty_pixels():
    out = sample_confidences(np.zeros((2, 2, 3), np.float32), np.zeros((0, 2)), (4, 4))
    assert out.shape == (0, 3)


def test_shape_errors():
    with pytest.raises(ValidationError, match="L2D"):
        sample_confidences(np.zeros((4, 4)), np.zeros((1, 2)), (4, 4))
    with pytest.raises(ValidationError, match=r"pixels: expected shape \(N, 2\)"):
        sample_confidences(np.zeros((4, 4, 1)), np.zeros((3,)), (4, 4))
    with pytest.raises(ValidationError, match="image_size"):
        sample_confidences(np.zeros((4, 4, 1)), np.zeros((1, 2)), (0, 4))


def test_fast_path_is_close_to_exact_for_many_channels():
    """cv2.remap rounds positions to 1/32 cell for > 4 channels; the error stays below 1/32."""
    rng = np.random.default_rng(5)
    L = rng.random((13, 17, 20), dtype=np.float32)
    pixels = rng.uniform(-1, [137, 105], size=(3000, 2))
    pixels[::50] = np.nan
    fast = sample_confidences(L, pixels, (136, 104))
    exact = sample_confidences(L, pixels, (136, 104), exact=True)
    assert np.abs(fast - exact).max() < 1 / 32
    np.testing.assert_array_equal(fast == 0, exact == 0)
    assert (exact[::50] == 0).all()
