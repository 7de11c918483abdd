"""Bounded density (coverage by visible projections) and view discovery's back-off."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from helpers.rigs import plane_rig
from helpers.scenes import plane_frames

from pointtraj.errors import ValidationError
from pointtraj.reconstruct.config import ReconstructConfig
from pointtraj.reconstruct.densify import DensifyConfig
from pointtraj.reconstruct.matching import MatchingConfig
from pointtraj.reconstruct.track import Tracker, TrackState
from pointtraj.reconstruct.views import (
    MAX_MISSES,
    ViewsConfig,
    record_misses,
    retry_due,
    retry_periods,
)


def test_retry_periods_derive_from_the_rig():
    assert retry_periods(ViewsConfig(), 69) == (4, 16)
    assert retry_periods(ViewsConfig(), 8) == (1, 1)  # small rigs: every frame
    assert retry_periods(ViewsConfig(max_retry_every=4), 8) == (1, 4)
    assert retry_periods(ViewsConfig(retry_every=3, max_retry_every=5), 8) == (3, 5)
    assert retry_periods(ViewsConfig(retry_every=3, max_retry_every=2), 8) == (3, 3)  # no back-off
    with pytest.raises(ValidationError, match="max_retry_every"):
        ViewsConfig(max_retry_every=-1)


def test_a_failed_camera_is_searched_again_later_and_less_often():
    """One point, one camera that never finds it: searched at once, then after 2, 4 and 8
    frames (capped); found, or out of sight, and it is searched at the next frame again."""
    every, max_every = 2, 8
    ids = np.array([5])
    cand = np.ones((1, 1), bool)
    misses = np.zeros((1, 1), np.uint8)
    searched = []
    for t in range(40):
        due = retry_due(misses, ids, t, every, max_every)
        if due[0, 0]:
            searched.append(t)
        misses = record_misses(misses, cand, due, np.zeros((1, 1), bool))
    gaps = np.diff(searched)
    assert searched[0] == 0
    assert gaps.max() == max_every and np.all(gaps[-3:] == max_every)  # the back-off saturates
    assert np.all(np.diff(gaps) >= 0)  # never searched more often after more failures
    assert len(searched) < 40 / every  # fewer searches than a fixed period of `every`
    assert misses[0, 0] <= MAX_MISSES
    # observed, or not a candidate (occluded, out of the image): counted afresh
    assert record_misses(misses, cand, due, np.ones((1, 1), bool))[0, 0] == 0
    gone = record_misses(misses, np.zeros((1, 1), bool), due, np.zeros((1, 1), bool))
    assert gone[0, 0] == 0 and retry_due(gone, ids, 41, every, max_every)[0, 0]
    # a candidate that was not due keeps its count
    kept = record_misses(misses, cand, np.zeros((1, 1), bool), np.zeros((1, 1), bool))
    assert kept[0, 0] == misses[0, 0]
    with pytest.raises(ValidationError, match="ids"):
        retry_due(misses, np.array([1, 2]), 0, every, max_every)


def test_failed_searches_are_staggered_over_points_and_cameras():
    misses = np.full((1000, 6), 3, np.uint8)  # period 4 * 2^2 = 16
    ids = np.arange(1000)
    due = np.stack([retry_due(misses, ids, t, 4, 64) for t in range(16)])  # (T, C, N)
    assert np.all(due.sum(axis=0) == 1)  # each view once in 16 frames
    per_frame = due.sum(axis=(1, 2))
    assert per_frame.max() - per_frame.min() <= 0.05 * per_frame.mean()  # spread evenly


@pytest.fixture(scope="module")
def four_cameras():
    """Four cameras around the plane z = 0 (35 degrees apart and between), which moves."""
    rig = plane_rig(angles=(-35.0, 0.0, 35.0, 20.0))
    return rig, plane_frames(rig, 6, seed=5, velocity=[0.004, 0.0, 0.0])


@pytest.fixture(scope="module")
def blind_camera(four_cameras):
    """The fourth camera sees a different texture: view discovery can never find the plane's
    points there."""
    rig, frames = four_cameras
    other = plane_frames(rig, 6, seed=11, velocity=[0.004, 0.0, 0.0])
    return rig, [[*f[:3], o[3]] for f, o in zip(frames, other, strict=True)]


def test_tracker_backs_off_the_camera_that_never_finds_its_points(blind_camera):
    rig, frames = blind_camera
    cfg = ReconstructConfig(
        matching=MatchingConfig(num_features=400),
        max_angle_deg=80.0,
        views=ViewsConfig(retry_every=1, max_retry_every=4),
    )
    tracker = Tracker(rig, cfg, edges=np.array([[0, 1], [1, 2], [0, 2]]))
    for t, imgs in enumerate(frames):
        tracker.step(t, imgs)
    st = tracker.state
    assert st.misses.shape == (len(st), 4) and st.misses.dtype == np.uint8
    old = st.ids < 200  # points born in the first frame, tracked since
    assert old.sum() > 100
    seen3 = np.all(np.isfinite(st.pixels[3]), axis=1)
    # the blind camera has failed again and again; the observed views have no count
    assert np.median(st.misses[old & ~seen3, 3]) >= 3
    for c in range(3):
        seen = np.all(np.isfinite(st.pixels[c]), axis=1)
        assert np.all(st.misses[seen, c] == 0)
    # a state without the field (an older state file) starts with no failures
    bare = TrackState(st.frame, st.ids, st.xyz, st.visibility, st.pixels, st.next_id, st.lone)
    assert bare.misses.shape == (len(st), 4) and not bare.misses.any()


def test_density_saturates_on_a_still_scene(four_cameras):
    """On a still textured plane, new points are only made where no live point is visible,
    observed there or not: without view discovery (points keep the views they were made in),
    densification from a camera that does not observe the live points duplicated them.
    Densification grows from every point here (``seeds = "all"``), as it did then."""
    rig, frames = four_cameras
    still = [frames[0]] * 6
    base = ReconstructConfig(
        matching=MatchingConfig(num_features=400),
        max_angle_deg=80.0,
        densify=DensifyConfig(enabled=True, max_partners=1, seeds="all"),
        views=ViewsConfig(enabled=False),
    )
    live, new = {}, {}
    for on in (True, False):
        tracker = Tracker(rig, dataclasses.replace(base, cover_visible="on" if on else "off"))
        recs = [tracker.step(t, imgs) for t, imgs in enumerate(still)]
        live[on] = np.array([len(r) for r in recs])
        new[on] = np.array([r.num_new for r in recs])
    np.testing.assert_array_equal(live[True][0], live[False][0])  # frame 0: nothing live yet
    assert new[True][1] < 0.7 * new[False][1]
    assert live[True][-1] < 0.85 * live[False][-1]
    assert new[True][-1] < 0.02 * live[True][-1]  # what grows is the plane's edge, slowly


def test_densification_stops_growing_over_still_surface(four_cameras):
    """Regression (issue #14): densification grew from every tracked point, so a still floor's
    covered area spread by ``rounds * radius_px`` every frame; grown only from new matches and
    moving points (the default), a still scene stops gaining points after its first frames."""
    rig, frames = four_cameras
    still = [frames[0]] * 4
    new = {}
    for seeds in ("all", "moving", "new"):
        cfg = ReconstructConfig(
            matching=MatchingConfig(num_features=400),
            max_angle_deg=80.0,
            densify=DensifyConfig(enabled=True, max_partners=1, seeds=seeds),
            views=ViewsConfig(enabled=False),
            cover_visible="off",
        )
        tracker = Tracker(rig, cfg)
        new[seeds] = np.array([tracker.step(t, imgs).num_new for t, imgs in enumerate(still)])
    assert new["moving"][0] == new["new"][0] == new["all"][0] > 0  # frame 0: all are new
    # nothing moves but tracking's jitter (a few points past 1 px): 2 % of the growth measured
    assert new["moving"][1:].sum() < 0.1 * new["all"][1:].sum()
    assert new["new"][1:].sum() <= new["moving"][1:].sum()


def test_image_motion_is_the_median_over_the_following_cameras():
    from pointtraj.reconstruct.track import _image_motion

    obs = np.full((3, 3, 2), np.nan)
    obs[:, 0] = [[3.0, 4.0], [0.0, 1.0], [0.6, 0.8]]  # point 0 moved 5, 1 and 1 px
    obs[0, 1] = [0.0, 2.0]  # point 1: 2 px in the one camera that follows it
    obs[2, 2] = [np.nan, 1.0]  # point 2: no camera follows it
    previous = np.zeros((3, 3, 2))
    np.testing.assert_allclose(_image_motion(obs, previous), [1.0, 2.0, 0.0])
    # nanmedian's values bit for bit, with odd and even counts of following cameras
    rng = np.random.default_rng(5)
    obs = rng.normal(0, 3, size=(12, 2000, 2))
    obs[rng.random((12, 2000)) < 0.7] = np.nan
    previous = rng.normal(0, 3, size=(12, 2000, 2)).astype(np.float32)
    step = np.linalg.norm(obs - previous, axis=2)
    has = np.isfinite(step).any(axis=0)
    want = np.zeros(2000)
    want[has] = np.nanmedian(step[:, has], axis=0)
    assert len(set(np.isfinite(step).sum(axis=0).tolist())) > 4
    np.testing.assert_array_equal(_image_motion(obs, previous), want)
    with pytest.raises(ValidationError, match="seeds"):
        DensifyConfig(seeds="some")
