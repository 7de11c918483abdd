"""Still views (issue #14): the flow of windows that barely move, from one Lucas-Kanade step,
and the tracker that uses it where it holds."""

from __future__ import annotations

import numpy as np
import pytest
from helpers.rigs import plane_rig
from helpers.scenes import make_texture, plane_frames

from pointtraj.errors import ValidationError
from pointtraj.reconstruct.config import ReconstructConfig
from pointtraj.reconstruct.flow import still_flow, track_flow
from pointtraj.reconstruct.matching import MatchingConfig
from pointtraj.reconstruct.track import Tracker


def _grey(seed: int = 0) -> np.ndarray:
    import cv2

    return cv2.cvtColor(make_texture(np.random.default_rng(seed), 256), cv2.COLOR_RGB2GRAY)


def _shifted(img: np.ndarray, dx: float, dy: float) -> np.ndarray:
    import cv2

    m = np.float32([[1, 0, dx], [0, 1, dy]])
    return cv2.warpAffine(
        img, m, img.shape[::-1], flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT
    )


def _noisy(img: np.ndarray, rng: np.random.Generator, sigma: float = 1.5) -> np.ndarray:
    return np.clip(img + rng.normal(0.0, sigma, img.shape), 0, 255).astype(np.uint8)


def test_a_sub_pixel_motion_is_measured_as_the_pyramidal_flow_measures_it():
    rng = np.random.default_rng(1)
    g = _grey()
    pts = rng.uniform(30, 225, (300, 2))
    a, b = _noisy(g, rng), _noisy(_shifted(g, 0.1, -0.05), rng)
    out = still_flow(a, b, pts, window=21, max_px=0.2)
    taken = np.isfinite(out[:, 0])
    assert taken.mean() > 0.95
    lk = track_flow(a, b, pts)
    assert np.median(np.linalg.norm(lk - pts, axis=1)) > 0.1  # not "no motion"
    gap = np.linalg.norm(out[taken] - lk[taken], axis=1)
    assert np.median(gap) < 0.03 and gap.max() < 0.06  # the one step's Scharr gradients: < 15 %


@pytest.mark.parametrize("shift", [0.5, 3.0])
def test_a_motion_beyond_max_px_is_left_to_the_pyramidal_flow(shift):
    rng = np.random.default_rng(2)
    g = _grey()
    pts = rng.uniform(30, 225, (300, 2))
    out = still_flow(_noisy(g, rng), _noisy(_shifted(g, shift, 0.0), rng), pts, max_px=0.1)
    assert np.isnan(out).all()


def test_a_window_that_changes_is_left_to_the_pyramidal_flow():
    """An occluder covering part of the image: the still windows there are not taken, though
    most of their pixels and their motion (none) are as before."""
    rng = np.random.default_rng(3)
    g = _grey()
    b = g.copy()
    b[100:160, 100:160] = _grey(7)[100:160, 100:160]  # an unrelated patch
    pts = np.array([[130.0, 130.0], [105.0, 140.0], [50.0, 50.0], [200.0, 60.0]])
    out = still_flow(_noisy(g, rng), _noisy(b, rng), pts)
    assert np.isnan(out[:2]).all()
    np.testing.assert_allclose(out[2:], pts[2:], atol=0.06)


def test_repeated_frames_keep_their_points_and_flat_or_border_windows_are_not_taken():
    """A codec's repeated static block (no noise at all): exactly no motion. A window without
    texture, one touching the border and NaN rows are left to the pyramidal flow."""
    g = _grey()
    g[:, 180:] = 128  # flat on the right
    pts = np.array([[60.0, 60.0], [120.5, 90.25], [220.0, 100.0], [5.0, 100.0], [np.nan, 1.0]])
    out = still_flow(g, g.copy(), pts, window=21)
    np.testing.assert_array_equal(out[:2], pts[:2].astype(np.float32))
    assert np.isnan(out[2:]).all()
    with pytest.raises(ValidationError, match="points"):
        still_flow(g, g, np.zeros((3, 3)))


def test_config_bounds():
    assert ReconstructConfig().still_px == 0.1
    with pytest.raises(ValidationError, match="still_px"):
        ReconstructConfig(still_px=2.0)
    with pytest.raises(ValidationError, match="still_noise"):
        ReconstructConfig(still_noise=0.0)


def _still_plane_frames(rig, velocity=(0.0, 0.0, 0.0)):
    frames = plane_frames(rig, 3, seed=4, velocity=velocity)
    return [  # sensor noise, independent over time
        [_noisy(im, np.random.default_rng(10 * t + c)) for c, im in enumerate(f)]
        for t, f in enumerate(frames)
    ]


def _track(rig, frames, features: int, still_px: float = 0.1, window: int | None = 21):
    cfg = ReconstructConfig(
        matching=MatchingConfig(num_features=features), still_px=still_px, lk_window=window
    )
    tracker = Tracker(rig, cfg)
    return [tracker.step(t, f) for t, f in enumerate(frames)], tracker.flows


@pytest.mark.parametrize("window, most, p99", [(21, 2e-4, 1e-4), (None, 1e-3, 2e-4)])
def test_the_tracker_takes_still_views_from_one_step_and_moving_ones_from_the_flow(
    window, most, p99
):
    """A still textured plane, then the same plane moving: the still one's views are all
    taken from one step, with the same points as the pyramidal flow gives to within 0.2 mm
    with a 21 px window; with the rig's 9 px window, which averages less of the sensor noise,
    to within 0.2 mm for 99 % of the points and 1 mm for all. The moving one's all get the
    pyramidal flow. The cameras track about 1,000 views on 480x360 images, above one view per
    256 pixels."""
    rig = plane_rig(angles=np.linspace(-20.0, 20.0, 4))
    frames = _still_plane_frames(rig)
    recs0, flows0 = _track(rig, frames, 2000, still_px=0.0, window=window)
    recs1, flows1 = _track(rig, frames, 2000, window=window)
    assert flows0["still"] == 0 and flows0["pyramidal"] > 5000
    assert flows1["still"] > 0.95 * flows0["pyramidal"]
    for r0, r1 in zip(recs0, recs1, strict=True):
        np.testing.assert_array_equal(r0.ids, r1.ids)
        gap = np.abs(r0.xyz - r1.xyz).max(axis=1)
        assert gap.max() < most and np.percentile(gap, 99) < p99
    moving = _track(rig, _still_plane_frames(rig, (0.01, 0.005, 0.0)), 2000)[1]
    assert moving["still"] == 0 and moving["pyramidal"] > 5000


def test_cameras_with_few_views_keep_the_pyramidal_flow():
    """About 400 views on 480x360 images, fewer than one per 256 pixels: the whole-image sums
    would cost more than the flow they save, so every view gets the flow, exactly as with
    ``still_px = 0``."""
    rig = plane_rig(angles=np.linspace(-20.0, 20.0, 4))
    frames = _still_plane_frames(rig)
    recs0, _ = _track(rig, frames, 800, still_px=0.0)
    recs1, flows1 = _track(rig, frames, 800)
    assert flows1["still"] == 0 and flows1["pyramidal"] > 2000
    for r0, r1 in zip(recs0, recs1, strict=True):
        np.testing.assert_array_equal(r0.xyz, r1.xyz)
