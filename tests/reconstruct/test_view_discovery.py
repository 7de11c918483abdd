"""View discovery: points found, by a plane sweep, in cameras 60 degrees and more from the ones
that observe them, where flow between views finds nothing."""

from __future__ import annotations

import dataclasses
import logging

import numpy as np
import pytest
from helpers.rigs import plane_rig
from helpers.scenes import plane_frames, plane_images

from pointtraj.camera import Camera, CameraRig
from pointtraj.config import from_mapping
from pointtraj.errors import ValidationError
from pointtraj.reconstruct.config import ReconstructConfig
from pointtraj.reconstruct.densify import prepare_images
from pointtraj.reconstruct.flow import expand_views
from pointtraj.reconstruct.matching import MatchingConfig
from pointtraj.reconstruct.track import Tracker
from pointtraj.reconstruct.views import ViewsConfig, depth_uncertainty, discover_views


@pytest.fixture(scope="module")
def sixty():
    """Three cameras at -60, 0 and +60 degrees around the plane z = 0 (60 and 120 apart)."""
    rig = plane_rig(angles=(-60.0, 0.0, 60.0))
    return rig, plane_images(rig, seed=3)


def plane_points(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(-0.3, 0.3, n), rng.uniform(-0.3, 0.3, n), np.zeros(n)])


def two_view_observations(rig: CameraRig, X: np.ndarray, noise_px: float = 0.0) -> np.ndarray:
    """Observations of X in cameras 0 and 1 (60 degrees apart), none in camera 2."""
    pix = rig.project(X).pixels.copy()
    pix += np.random.default_rng(1).normal(0, noise_px, pix.shape)
    pix[2] = np.nan
    return pix


def test_discovery_finds_points_at_a_60_degree_baseline_where_flow_finds_none(sixty):
    rig, images = sixty
    X = plane_points(200)
    pix = two_view_observations(rig, X)
    cand = rig.project(X).in_image
    grey = [im[..., 0] for im in images]
    # flow between views reaches 40 degrees at most: nothing
    flow = expand_views(rig, grey, X, pix, cand, max_angle_deg=40.0)
    assert not np.isfinite(flow[2]).any()
    out, searched = discover_views(rig, prepare_images(rig, grey), X, pix, cand)
    found = np.all(np.isfinite(out[2]), axis=1)
    assert searched[2].mean() > 0.9
    assert found.mean() > 0.8, found.mean()
    truth = rig.project(X).pixels[2]
    err = np.linalg.norm(out[2, found] - truth[found], axis=1)
    assert np.median(err) < 0.3 and np.percentile(err, 95) < 1.0
    # the observed views are left as they were
    np.testing.assert_array_equal(out[:2], pix[:2])


def test_discovery_follows_the_depth_uncertainty_of_noisy_points(sixty):
    """Points triangulated from noisy two-view observations lie off the plane; the sweep over
    their depth uncertainty still finds where the third camera sees them."""
    rig, images = sixty
    X = plane_points(150, seed=2)
    pix = two_view_observations(rig, X, noise_px=0.7)
    from pointtraj.reconstruct.triangulate import triangulate_points

    Xn = triangulate_points(rig, pix)
    assert np.percentile(np.abs(Xn[:, 2]), 90) > 0.002  # noticeably off the surface
    sigma = depth_uncertainty(rig, Xn, np.all(np.isfinite(pix), axis=2), 1.0)
    assert np.all((sigma > 0.001) & (sigma < 0.02))
    grey = [im[..., 0] for im in images]
    out, _ = discover_views(rig, prepare_images(rig, grey), Xn, pix, rig.project(Xn).in_image)
    found = np.all(np.isfinite(out[2]), axis=1)
    assert found.mean() > 0.7
    # the found pixel is where camera 2 sees the surface point of camera 1's observation
    o, d = rig[1].rays(pix[1, found])
    on_plane = o + (-o[:, 2] / d[:, 2])[:, None] * d
    err = np.linalg.norm(out[2, found] - rig.project(on_plane).pixels[2], axis=1)
    assert np.median(err) < 0.5


def test_discovery_needs_texture_and_a_facing_surface(sixty):
    rig, images = sixty
    X = plane_points(50)
    pix = two_view_observations(rig, X)
    cand = rig.project(X).in_image
    flat = [np.full_like(im[..., 0], 128) for im in images]
    out, searched = discover_views(rig, prepare_images(rig, flat), X, pix, cand)
    assert not np.isfinite(out[2]).any() and not searched[2].any()
    # a camera behind the plane sees its back: not searched
    back = Camera.look_at("b", [0.0, 0.3, -2.0], [0, 0, 0], (480, 360), 400.0, up=[0, -1, 0])
    rig4 = CameraRig([*rig, back])
    grey4 = [im[..., 0] for im in images] + [images[1][..., 0]]
    pix4 = np.concatenate([pix, np.full((1, len(X), 2), np.nan)])
    cand4 = rig4.project(X).in_image
    assert cand4[3].all()
    out4, searched4 = discover_views(rig4, prepare_images(rig4, grey4), X, pix4, cand4)
    assert not searched4[3].any() and not np.isfinite(out4[3]).any()


def test_new_two_view_points_are_searched_again_facing_their_cameras():
    """A two-view point whose fitted normal rules out every other camera is searched once more,
    facing its observing cameras (``confirm``): a right point is found there, a wrong match
    (two views that agree along the epipolar line) is searched and not found, so that
    ``confirm_new`` can drop it. Tracked points are not searched again."""
    rig = plane_rig(angles=(-20.0, 20.0, 60.0))
    grey = [im[..., 0] for im in plane_images(rig, seed=5)]
    prepared = prepare_images(rig, grey)
    X = plane_points(120, seed=6)
    pix = two_view_observations(rig, X)  # cameras at -20 and 20 degrees, none at 60
    cand = rig.project(X).in_image
    cfg = ViewsConfig(max_incidence_deg=50.0)  # the plane's normal is 60 degrees from camera 2
    out, searched = discover_views(rig, prepared, X, pix, cand, cfg)
    assert not searched[2].any() and not np.isfinite(out[2]).any()
    # confirmed: the facing direction (0 degrees) is 60 degrees from camera 2
    new = np.arange(len(X)) >= 20  # the first 20 are tracked points
    out, searched = discover_views(rig, prepared, X, pix, cand, cfg, confirm=new)
    found = np.all(np.isfinite(out[2]), axis=1)
    assert not searched[2, :20].any() and not found[:20].any()
    assert searched[2, 20:].mean() > 0.9 and found[20:].mean() > 0.4, found[20:].mean()
    err = np.linalg.norm(out[2, found] - rig.project(X).pixels[2, found], axis=1)
    assert np.median(err) < 0.75  # the bisector's plane is 40 degrees off the true one
    # wrong matches: camera 1's view slid 6 px along its epipolar line (the point moves off the
    # plane, both views still agree); camera 2 sees the plane there, not the point
    from pointtraj.reconstruct.triangulate import triangulate_points

    wrong = pix.copy()
    far = X + 0.04 * (X - rig.C[0]) / np.linalg.norm(X - rig.C[0], axis=1, keepdims=True)
    wrong[1] = rig.project(far).pixels[1]  # camera 0's ray, 4 cm deeper
    Xw = triangulate_points(rig, wrong)
    assert np.median(np.abs(Xw[:, 2])) > 0.01
    out, searched = discover_views(
        rig, prepared, Xw, wrong, rig.project(Xw).in_image, cfg, confirm=np.ones(len(X), bool)
    )
    found = np.all(np.isfinite(out[2]), axis=1)
    assert searched[2].mean() > 0.9 and found.mean() < 0.1, found.mean()
    # off: nothing searched
    off = dataclasses.replace(cfg, confirm_incidence_deg=0.0)
    _, searched = discover_views(rig, prepared, X, pix, cand, off, confirm=new)
    assert not searched[2].any()


def test_confirm_incidence_is_chosen_from_the_rig(caplog):
    """Left out, the confirmation search runs on rigs of 6 cameras and more whose tolerance
    the search can judge and whose third cameras see a pair's surface within
    max_incidence_deg, and a warning says why where it does not; a set angle is kept."""
    from pointtraj.camera import CameraRig
    from pointtraj.synth.presets import make_rig, ring_cameras

    cfg = ReconstructConfig()
    assert cfg.views.confirm_incidence_deg is None

    def angle(c: ReconstructConfig, preset: str) -> float:
        return c.for_rig(make_rig(preset)).views.confirm_incidence_deg

    with caplog.at_level(logging.INFO, logger="pointtraj.reconstruct.config"):
        assert angle(cfg, "ring8") == 89.0 and angle(cfg, "paper69") == 89.0
    assert "searched again facing their cameras within 89 deg (from the rig)" in caplog.text
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="pointtraj.reconstruct.config"):
        assert angle(cfg, "lab4") == 0.0
    assert "4 cameras" in caplog.text and "confirm_incidence_deg" in caplog.text
    loose = dataclasses.replace(cfg, sigma_px=6.0)  # the Pose2Sim demo's
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="pointtraj.reconstruct.config"):
        assert angle(loose, "ring8") == 0.0
    assert "sigma_px = 6" in caplog.text
    # six cameras 60 degrees apart: a pair's third camera sees its surface at about 90 degrees
    ring6 = CameraRig(ring_cameras(6, 2.6, [1.2, 1.9], (0.0, 0.0, 0.9), (960, 720), 560.0))
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="pointtraj.reconstruct.config"):
        assert cfg.for_rig(ring6).views.confirm_incidence_deg == 0.0
    assert "60 deg apart" in caplog.text and "max_incidence_deg = 80" in caplog.text
    wide = dataclasses.replace(cfg.views, max_incidence_deg=90.0)  # the third camera in reach
    assert dataclasses.replace(cfg, views=wide).for_rig(ring6).views.confirm_incidence_deg == 89
    across = dataclasses.replace(loose.views, search_sigmas=2.0)
    assert angle(dataclasses.replace(loose, views=across), "ring8") == 89.0
    for deg in (60.0, 0.0):  # set: kept, on any rig
        views = dataclasses.replace(cfg.views, confirm_incidence_deg=deg)
        assert angle(dataclasses.replace(cfg, views=views), "lab4") == deg
    with pytest.raises(ValidationError):
        ViewsConfig(confirm_incidence_deg=95.0)


def test_tracker_confirms_new_points_facing_their_cameras():
    """In the tracker, new points whose fitted normal rules out the third camera gain it through
    the confirmation search (on by default); without it, only those matched in both pairs
    have three."""
    rig = plane_rig(angles=(-20.0, 20.0, 60.0))
    frames = plane_frames(rig, 1, seed=3)
    base = ReconstructConfig(
        matching=MatchingConfig(num_features=600), max_angle_deg=45.0, min_views_new=2
    )
    share = {}
    for deg in (0.0, 89.0):
        views = ViewsConfig(max_incidence_deg=50.0, confirm_incidence_deg=deg)
        rec = Tracker(rig, dataclasses.replace(base, views=views)).step(0, frames[0])
        n_views = np.count_nonzero(rec.visibility > 0.05 * 255, axis=1)
        assert len(n_views) > 20
        share[deg] = np.mean(n_views >= 3)
    assert share[0.0] < 0.5 and share[89.0] > share[0.0] + 0.4, share


def test_tracker_points_gain_the_third_view(sixty):
    rig, _ = sixty
    velocity = np.array([0.01, 0.0, 0.005])
    frames = plane_frames(rig, 3, seed=3, velocity=velocity)
    base = ReconstructConfig(
        matching=MatchingConfig(num_features=600), max_angle_deg=130.0, min_views_new=2
    )
    views = {}
    for on in (False, True):
        cfg = dataclasses.replace(base, views=ViewsConfig(enabled=on))
        tracker = Tracker(rig, cfg)
        recs = [tracker.step(t, imgs) for t, imgs in enumerate(frames)]
        n_views = np.count_nonzero(recs[-1].visibility > 0.05 * 255, axis=1)
        views[on] = n_views
        z_err = np.abs(recs[-1].xyz[:, 2] - 2 * velocity[2])
        assert len(n_views) > 20 and np.median(z_err) < 0.004
    assert np.mean(views[True] >= 3) > 0.6
    assert np.mean(views[True] >= 3) > np.mean(views[False] >= 3) + 0.4


def test_discovery_searches_across_the_epipolar_line_of_a_miscalibrated_camera(sixty):
    """Camera 2's calibration is off by 8 px (its principal point): the point lies off the
    epipolar line there, and only the search across it (``search_sigmas`` 2 with sigma_px 6,
    as on the Pose2Sim demo; off by default) finds it, where the true image is."""
    rig, images = sixty
    cams = list(rig)
    K = cams[2].K.copy()
    K[0, 2] += 6.0
    K[1, 2] -= 5.0
    bad = CameraRig([*cams[:2], dataclasses.replace(cams[2], K=K)])
    X = plane_points(150, seed=4)
    pix = two_view_observations(rig, X)
    grey = [im[..., 0] for im in images]
    cand = bad.project(X).in_image
    found = {}
    for sigmas in (0.0, 2.0):
        cfg = ViewsConfig(search_sigmas=sigmas)
        out, _ = discover_views(bad, prepare_images(bad, grey), X, pix, cand, cfg, sigma_px=6.0)
        ok = np.all(np.isfinite(out[2]), axis=1)
        err = np.linalg.norm(out[2, ok] - rig.project(X).pixels[2, ok], axis=1)  # true image
        found[sigmas] = (ok.mean(), np.median(err) if ok.any() else np.inf)
    assert found[2.0][0] > 0.45 and found[2.0][1] < 3.0, found
    assert found[2.0][0] > found[0.0][0] + 0.3, found


def test_views_config_from_toml_and_validation():
    cfg = from_mapping(ReconstructConfig, {"views": {"min_ncc": 0.7, "retry_every": 2}})
    assert cfg.views == ViewsConfig(min_ncc=0.7, retry_every=2)
    with pytest.raises(ValidationError, match="ViewsConfig.retry_every"):
        ViewsConfig(retry_every=-1)
    with pytest.raises(ValueError, match="unknown key"):
        from_mapping(ReconstructConfig, {"views": {"min_nc": 0.7}})


def test_two_view_points_that_other_cameras_refute_end_as_unconfirmed():
    """Points 10 cm above a textured plane, tracked in two of five cameras: two views always
    agree, but the three others do not see them. With ``unconfirmed_fails = 3`` they end
    (counted as ``unconfirmed``); with 0 they go on, and at the default 4 too (a rig of five
    cameras never has four others to fail). The plane's own points, confirmed by their other
    views, never end so."""
    from pointtraj.reconstruct.track import TrackState

    rig = plane_rig(angles=(-30.0, -15.0, 0.0, 15.0, 30.0))
    frames = plane_frames(rig, 2, seed=3)
    rng = np.random.default_rng(2)
    fake = np.column_stack([rng.uniform(-0.2, 0.2, (40, 2)), np.full(40, 0.1)])
    base = ReconstructConfig(matching=MatchingConfig(num_features=600), max_angle_deg=130.0)
    ended = {}
    for fails in (0, 3, None):
        views = ViewsConfig() if fails is None else ViewsConfig(unconfirmed_fails=fails)
        cfg = dataclasses.replace(base, views=views)
        tracker = Tracker(rig, cfg)
        first = tracker.step(0, frames[0])
        st = tracker.state
        assert len(st) > 50
        pix = rig.project(fake).pixels.astype(np.float32)  # (C, 40, 2)
        pix[2:] = np.nan  # seen by cameras 0 and 1 only
        vis = np.zeros((40, len(rig)), np.float32)
        vis[:, :2] = 1.0
        tracker.state = TrackState(
            st.frame,
            np.concatenate([st.ids, st.next_id + np.arange(40)]),
            np.concatenate([st.xyz, fake]),
            np.concatenate([st.visibility, vis]),
            np.concatenate([st.pixels, pix], axis=1),
            st.next_id + 40,
            np.concatenate([st.lone, np.zeros(40, np.int64)]),
            np.concatenate([st.misses, np.zeros((40, len(rig)), np.uint8)]),
        )
        rec = tracker.step(1, frames[1])
        alive = np.isin(st.next_id + np.arange(40), rec.ids)
        ended[fails] = (int((~alive).sum()), tracker.stops["unconfirmed"])
        old = np.isin(first.ids, rec.ids)
        assert old.mean() > 0.9  # the plane's points go on
    assert ended[0][1] == 0 and ended[0][0] < 10
    assert ended[None] == ended[0]
    assert ended[3][0] >= 30 and ended[3][1] >= 30
    with pytest.raises(ValidationError, match="unconfirmed_fails"):
        ViewsConfig(unconfirmed_fails=-1)
    with pytest.raises(ValidationError, match="unconfirmed_frames"):
        ViewsConfig(unconfirmed_frames=0)
