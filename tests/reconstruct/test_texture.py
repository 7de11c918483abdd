"""Densification's patch spacing chosen from the images' texture (``pointtraj.reconstruct.texture``)."""

from __future__ import annotations

import logging
from pathlib import Path

import cv2
import numpy as np
import pytest

from pointtraj.errors import ValidationError
from pointtraj.reconstruct.config import ReconstructConfig
from pointtraj.reconstruct.densify import DensifyConfig
from pointtraj.reconstruct.stage import with_texture_choices
from pointtraj.reconstruct.texture import (
    MAX_CAMERAS,
    PATCH_SPACINGS,
    patch_contrast,
    texture_cameras,
    texture_patch_spacing,
)
from pointtraj.reconstruct.views import ViewsConfig
from pointtraj.session import Capture

SHARED = Path(__file__).resolve().parents[2].parent / "shared"
CALISCOPE = SHARED / "data" / "caliscope_board_4cam"


def _fine_texture(rng: np.random.Generator, shape=(360, 480)) -> np.ndarray:
    """Texture fine-grained to the pixel, as the synthetic captures render it."""
    img = rng.normal(128, 30, shape)
    return np.clip(cv2.GaussianBlur(img, (0, 0), 0.8), 0, 255).astype(np.uint8)


def _natural_texture(rng: np.random.Generator, shape=(360, 480)) -> np.ndarray:
    """Texture whose contrast grows with scale (amplitude falling as 1/f^1.5 with spatial
    frequency f), its finest detail blurred away as by a lens and compression."""
    h, w = shape
    f = np.hypot(*np.meshgrid(np.fft.fftfreq(h), np.fft.rfftfreq(w), indexing="ij"))
    spectrum = rng.normal(size=f.shape) + 1j * rng.normal(size=f.shape)
    spectrum /= np.maximum(f, 1.0 / max(h, w)) ** 1.5
    img = np.fft.irfft2(spectrum, s=shape)
    img = cv2.GaussianBlur(img, (0, 0), 2.0)
    img = 128 + 40 * (img - img.mean()) / img.std()
    return np.clip(img, 0, 255).astype(np.uint8)


def test_patch_contrast_shape_and_small_images():
    rng = np.random.default_rng(0)
    img = _fine_texture(rng)
    c = patch_contrast(img, [2.0, 4.0, 8.0])
    assert c.shape == (3,) and np.all(c > 0)
    # white-ish noise: as much contrast at any spacing
    assert c[0] == pytest.approx(c[2], rel=0.2)
    assert patch_contrast(img[:40, :40], [2.0, 12.0]) is None  # no room for the widest patch
    with pytest.raises(ValidationError, match="grey"):
        patch_contrast(np.zeros((4, 4, 3)), [2.0])


def test_rendered_texture_keeps_the_small_patch():
    rng = np.random.default_rng(1)
    spacing, scale = texture_patch_spacing([_fine_texture(rng) for _ in range(3)])
    assert spacing == PATCH_SPACINGS[0] == 2.0
    assert scale.cameras == 3 and scale.held[0] > 0.8


def test_natural_texture_takes_a_wider_patch():
    rng = np.random.default_rng(2)
    images = [_natural_texture(rng) for _ in range(3)]
    spacing, scale = texture_patch_spacing(images)
    assert spacing >= 4.0
    assert scale.held[0] < 0.65
    assert np.all(np.diff(scale.held) > 0)  # contrast keeps growing with scale
    # the share asked for decides: a lower one takes a smaller patch
    assert scale.patch_spacing(held=scale.held[0] - 0.01) == 2.0
    assert scale.patch_spacing(held=1.1) == PATCH_SPACINGS[-1]


def test_unmeasurable_images_fall_back_to_the_default():
    flat = [np.full((300, 300), 90, np.uint8), np.zeros((30, 30, 3), np.uint8)]
    spacing, scale = texture_patch_spacing(flat)
    assert spacing == 2.0 and scale.cameras == 0 and np.isnan(scale.held).all()


def test_texture_cameras_spread_over_the_rig():
    assert texture_cameras(4).tolist() == [0, 1, 2, 3]
    picked = texture_cameras(69)
    assert len(picked) == MAX_CAMERAS and picked[0] == 0 and picked[-1] == 68
    assert np.all(np.diff(picked) > 0)


def test_densify_config_spacing():
    assert DensifyConfig().patch_spacing_px is None
    assert DensifyConfig().spacing_px == 2.0
    assert DensifyConfig(patch_spacing_px=5.0).spacing_px == 5.0
    with pytest.raises(ValidationError, match="patch_spacing_px"):
        DensifyConfig(patch_spacing_px=0.0)


class _Frames:
    """A capture's ``camera_names`` and ``read`` over fixed images."""

    def __init__(self, images):
        self.images = images
        self.camera_names = [f"cam{c}" for c in range(len(images))]

    def read(self, camera, frame):
        return self.images[self.camera_names.index(camera)]


def test_stage_chooses_only_what_is_left_out(caplog):
    rng = np.random.default_rng(3)
    real = _Frames([_natural_texture(rng) for _ in range(2)])
    with caplog.at_level(logging.INFO, logger="pointtraj.reconstruct.stage"):
        chosen = with_texture_choices(ReconstructConfig(), real, 0)
    # one spacing for both patches
    assert chosen.densify.patch_spacing_px == chosen.views.patch_spacing_px >= 4.0
    assert "from the images' texture" in caplog.text and "2 cameras" in caplog.text
    set_both = ReconstructConfig(
        densify=DensifyConfig(patch_spacing_px=3.0), views=ViewsConfig(patch_spacing_px=2.5)
    )
    assert with_texture_choices(set_both, real, 0) is set_both
    one = with_texture_choices(ReconstructConfig(views=ViewsConfig(patch_spacing_px=2.5)), real, 0)
    assert one.views.patch_spacing_px == 2.5 and one.densify.patch_spacing_px >= 4.0
    off = ReconstructConfig(densify=DensifyConfig(enabled=False), views=ViewsConfig(enabled=False))
    assert with_texture_choices(off, real, 0) is off


def test_views_config_spacing():
    assert ViewsConfig().patch_spacing_px is None and ViewsConfig().spacing_px == 2.0
    assert ViewsConfig(patch_spacing_px=5.0).spacing_px == 5.0
    with pytest.raises(ValidationError, match="patch_spacing_px"):
        ViewsConfig(patch_spacing_px=-1.0)


@pytest.mark.shared
@pytest.mark.skipif(
    not CALISCOPE.is_dir(), reason=f"needs the shared caliscope capture at {CALISCOPE}"
)
def test_real_webcams_take_a_wider_patch(tmp_path):
    """caliscope's four webcams (real video, 1280x720): a patch 12 px across holds under
    half the contrast of one twice as wide, so densification takes a wider one."""
    from pointtraj.examples import fetch_caliscope_board

    fetch_caliscope_board(tmp_path / "cap", source=CALISCOPE)
    cap = Capture.open(tmp_path / "cap")
    images = [cap.read(name, 24) for name in cap.camera_names]
    spacing, scale = texture_patch_spacing(images)
    assert scale.cameras == 4
    assert scale.held[0] < 0.55
    assert spacing >= 4.0


def test_synthetic_capture_keeps_the_small_patch(tiny_reference):
    """The tiny synthetic pipeline's rendered images: 2 px, as before the choice existed."""
    cap = Capture.open(tiny_reference / "cap")
    images = [cap.read(name, 0) for name in cap.camera_names]
    spacing, scale = texture_patch_spacing(images)
    assert spacing == 2.0
