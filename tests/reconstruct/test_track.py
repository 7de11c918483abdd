"""Tracking by multi-view optical flow, coverage of new points, assembly of the store."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from helpers.rigs import ring_rig
from helpers.scenes import make_texture, plane_frames

from pointtraj.config import from_mapping
from pointtraj.errors import ValidationError
from pointtraj.reconstruct.config import ReconstructConfig
from pointtraj.reconstruct.flow import expand_views, track_flow
from pointtraj.reconstruct.matching import MatchingConfig
from pointtraj.reconstruct.stage import assemble_trajectories
from pointtraj.reconstruct.track import (
    FrameRecord,
    Tracker,
    covered_by,
    sample_colors,
    select_edges,
)
from pointtraj.trajectories import Trajectories

EDGES3 = np.array([[0, 1], [1, 2], [0, 2]])


#: Per-frame motion of the textured plane (metres).
VELOCITY = np.array([0.01, 0.005, 0.02])


@pytest.fixture(scope="module")
def moving_plane(narrow_rig):
    return narrow_rig, plane_frames(narrow_rig, 5, seed=1, velocity=VELOCITY)


def test_track_flow_recovers_a_shift_and_drops_lost_points():
    import cv2

    tex = make_texture(np.random.default_rng(0), 256)
    a = cv2.cvtColor(tex, cv2.COLOR_RGB2GRAY)
    shift = np.array([2.6, -1.3])
    b = cv2.warpAffine(a, np.array([[1, 0, shift[0]], [0, 1, shift[1]]]), (256, 256))
    rng = np.random.default_rng(1)
    pts = rng.uniform(40, 210, (200, 2))
    pts[0] = np.nan  # skipped
    pts[1] = [254.0, 100.0]  # leaves the image
    out = track_flow(a, b, pts, fb_max_px=1.0)
    assert out.shape == (200, 2) and out.dtype == np.float32
    assert np.all(np.isnan(out[:2]))
    ok = np.all(np.isfinite(out), axis=1)
    assert ok[2:].mean() > 0.95
    np.testing.assert_allclose(np.median(out[ok] - pts[ok], axis=0), shift, atol=0.05)
    # an unrelated image: the forward-backward check rejects most points
    c = cv2.cvtColor(make_texture(np.random.default_rng(9), 256), cv2.COLOR_RGB2GRAY)
    assert np.isfinite(track_flow(a, c, pts[2:], fb_max_px=0.5)[:, 0]).mean() < 0.3


def test_covered_by_counts_views():
    live = np.full((3, 2, 2), np.nan)
    live[0, 0], live[1, 0], live[2, 0] = [10, 10], [20, 20], [30, 30]
    live[0, 1] = [100, 100]
    new = np.full((3, 3, 2), np.nan)
    new[:, 0] = [[11, 10], [20, 22], [90, 90]]  # near in two cameras
    new[:, 1] = [[100, 101], [50, 50], [30, 31]]  # near in cams 0 and 2, different live points
    new[:2, 2] = [[10, 10], [200, 200]]  # near in one camera only
    np.testing.assert_array_equal(covered_by(live, new, 3.0, 2), [True, True, False])
    np.testing.assert_array_equal(covered_by(live, new, 3.0, 1), [True, True, True])
    assert covered_by(np.zeros((3, 0, 2)), new, 3.0, 2).tolist() == [False] * 3
    with pytest.raises(ValidationError, match="new_pixels"):
        covered_by(live, new[:2], 3.0, 2)


def test_sample_colors_uses_the_most_visible_observed_camera():
    red = np.zeros((4, 5, 3), np.uint8)
    red[..., 0] = 200
    blue = np.zeros((4, 5, 3), np.uint8)
    blue[..., 2] = 90
    pix = np.array([[[1.2, 2.0], [np.nan, np.nan], [0, 0]], [[3.0, 3.0], [4, 1], [np.nan, np.nan]]])
    vis = np.array([[0.3, 0.9], [0.8, 0.1], [0.0, 0.0]], np.float32)
    col = sample_colors([red, blue], pix, vis)
    assert col.dtype == np.uint8 and col.shape == (3, 3)
    np.testing.assert_array_equal(col, [[0, 0, 90], [0, 0, 90], [200, 0, 0]])


def test_config_from_mapping_and_validation():
    cfg = from_mapping(
        ReconstructConfig, {"sigma_px": 2, "matching": {"num_features": 500}}, where="x"
    )
    assert cfg.sigma_px == 2.0 and cfg.matching.num_features == 500
    assert cfg.triangulation().sigma_px == 2.0
    with pytest.raises(ValueError, match="unknown key 'sigma'"):
        from_mapping(ReconstructConfig, {"sigma": 2})
    with pytest.raises(ValueError, match="unknown key 'nfeatures'"):
        from_mapping(ReconstructConfig, {"matching": {"nfeatures": 2}})
    with pytest.raises(ValidationError, match="min_views"):
        ReconstructConfig(min_views=1)
    with pytest.raises(ValidationError, match="lk_start"):
        ReconstructConfig(lk_start="flow")  # type: ignore[arg-type]


def test_select_edges_thins_per_camera():
    rig = ring_rig(
        angles=np.linspace(0, 2 * np.pi, 8, endpoint=False),
        size=(320, 240),
        focal=300.0,
        names="r{i}",
    )
    all_edges = select_edges(rig, 90.0)
    assert all_edges.shape[1] == 2 and np.all(all_edges[:, 0] < all_edges[:, 1])
    # 45 degrees apart: neighbours and second neighbours are within 90 degrees
    assert len(all_edges) == 16
    thin = select_edges(rig, 90.0, max_pairs_per_camera=1)
    assert 4 <= len(thin) <= 8
    assert set(map(tuple, thin)) <= set(map(tuple, all_edges))
    deg = np.bincount(thin.ravel(), minlength=8)
    assert deg.min() >= 1


def _record(t, ids, C=2):
    n = len(ids)
    return FrameRecord(
        t,
        np.asarray(ids, np.int64),
        np.full((n, 3), t, np.float32),
        np.full((n, C), 255, np.uint8),
        np.zeros(n, np.float32),
        np.zeros((n, 3), np.uint8),
    )


def test_assemble_trajectories_round_trip():
    recs = [_record(3, [0, 1]), _record(4, [1, 2, 0]), _record(5, [2, 3])]
    traj = assemble_trajectories(recs, ["a", "b"], 25.0, 10)
    assert isinstance(traj, Trajectories)
    np.testing.assert_array_equal(traj.first_frame, [3, 3, 4, 5])
    np.testing.assert_array_equal(traj.lengths, [2, 2, 2, 1])
    np.testing.assert_array_equal(traj.track(2)[:, 0], [4, 5])  # xyz holds the frame
    np.testing.assert_array_equal(traj.frame(4).track_id, [0, 1, 2])
    assert traj.num_frames == 10 and traj.fps == 25.0
    empty = assemble_trajectories([], ["a", "b"], 25.0, 10)
    assert empty.num_trajectories == 0
    with pytest.raises(ValidationError, match="skips a frame"):
        assemble_trajectories([_record(3, [0]), _record(5, [0])], ["a", "b"], 25.0, 10)
    with pytest.raises(ValidationError, match="0 .. M-1"):
        assemble_trajectories([_record(3, [0, 2])], ["a", "b"], 25.0, 10)


def test_tracker_follows_a_moving_plane(moving_plane):
    rig, frames = moving_plane
    cfg = ReconstructConfig(matching=MatchingConfig(num_features=1500), occlusion_depth_m=0.05)
    tracker = Tracker(rig, cfg, edges=EDGES3)
    records = [tracker.step(t, imgs) for t, imgs in enumerate(frames)]
    traj = assemble_trajectories(records, rig.names, 30.0, len(frames))
    assert records[0].num_new == len(records[0]) > 300
    # most first-frame trajectories survive to the end; new ones fill in uncovered areas
    full = np.flatnonzero(traj.lengths == len(frames))
    assert len(full) > 0.8 * len(records[0])
    assert traj.first_frame.max() > 0
    # each point-frame lies on the moving plane z = t * vz
    z_err = traj.xyz[:, 2] - traj.row_frame * VELOCITY[2]
    assert np.median(np.abs(z_err)) < 0.01
    # a trajectory moves with the plane: its displacement matches the plane's (drift)
    d = traj.dense_positions(full)
    disp = d[:, -1] - d[:, 0]
    drift = np.linalg.norm(disp - (len(frames) - 1) * VELOCITY, axis=1)
    assert np.median(drift) < 0.003
    # visibility is quantised, colours come from the images, ids are unique per frame
    assert traj.visibility.dtype == np.uint8 and traj.visibility.max() > 200
    assert traj.color.std() > 10
    for r in records:
        assert len(np.unique(r.ids)) == len(r)
    assert np.all(traj.reprojection_error <= cfg.max_mean_error_px)


def test_tracker_restarts_on_a_frame_gap(moving_plane):
    rig, frames = moving_plane
    cfg = ReconstructConfig(
        matching=MatchingConfig(num_features=800), match_every=2, match_moving=False
    )
    tracker = Tracker(rig, cfg, edges=EDGES3)
    r0 = tracker.step(0, frames[0])
    r1 = tracker.step(1, frames[1])  # no matching at odd frames: only tracked points
    assert r1.num_new == 0 and 0 < len(r1) <= len(r0)
    assert set(r1.ids.tolist()) <= set(r0.ids.tolist())
    r3 = tracker.step(3, frames[3])  # a gap: every trajectory ends, new ones start
    assert r3.num_new == len(r3) > 0
    assert r3.ids.min() > r0.ids.max()
    with pytest.raises(ValidationError, match="expected 3 images"):
        tracker.step(4, frames[4][:2])


def test_densification_grows_from_moving_points_between_matched_frames(moving_plane):
    """With ``match_every = 2`` (and ``match_moving`` off) the odd frames match nothing.
    Densification still grows there from the tracked points that moved by more than
    ``between_motion_px`` (``seeds = "moving"``): with 0, from every point that moved; with a
    motion larger than the plane's, or ``inf``, from none. From new matches alone (``seeds =
    "new"``) it has no seed there."""
    from pointtraj.reconstruct.densify import DensifyConfig

    rig, frames = moving_plane
    counts = {}
    cases = (("moving", 0.0), ("new", 0.0), ("moving", 1000.0), ("moving", float("inf")))
    for seeds, between in cases:
        cfg = ReconstructConfig(
            matching=MatchingConfig(num_features=300),
            match_every=2,
            match_moving=False,
            densify=DensifyConfig(enabled=True, seeds=seeds, between_motion_px=between),
        )
        tracker = Tracker(rig, cfg, edges=EDGES3)
        r0 = tracker.step(0, frames[0])
        assert not tracker.state.densify_backlog  # the frame's densification was not cut
        r1 = tracker.step(1, frames[1])
        counts[seeds, between] = r1.num_new
        assert r1.num_new == len(r1) - np.isin(r1.ids, r0.ids).sum()
        assert r1.ids[~np.isin(r1.ids, r0.ids)].min(initial=r0.ids.max() + 1) > r0.ids.max()
    assert counts["new", 0.0] == 0
    assert counts["moving", 0.0] > 100  # the plane moves: every tracked point seeds
    assert counts["moving", 1000.0] == counts["moving", float("inf")] == 0


def test_densification_cut_at_max_points_goes_on_at_the_next_frame(moving_plane, tmp_path):
    """A frame whose densification stops at ``max_points`` leaves a backlog: the next frame
    densifies although it lies between whole-image matchings, and the backlog is part of the
    tracker state that a resumed run reads back."""
    from pointtraj.reconstruct.densify import DensifyConfig
    from pointtraj.reconstruct.framestore import FrameStore

    rig, frames = moving_plane
    cfg = ReconstructConfig(
        matching=MatchingConfig(num_features=300),
        match_every=2,
        match_moving=False,
        densify=DensifyConfig(enabled=True, max_points=20, between_motion_px=float("inf")),
    )
    tracker = Tracker(rig, cfg, edges=EDGES3)
    tracker.step(0, frames[0])
    assert tracker.state.densify_backlog
    store = FrameStore(tmp_path, len(rig))
    store.write_live(tracker.state)
    assert store.read_live().densify_backlog
    r1 = tracker.step(1, frames[1])
    assert r1.num_new > 0  # densified from the moving points, no matching at this frame
    assert tracker.state.densify_backlog == (r1.num_new >= 20)


def test_frames_between_match_where_points_move(moving_plane):
    """With ``match_every = 2`` and ``match_moving`` (the default), an odd frame matches
    around the moving points: the moving plane gets new points there, a still one none."""
    rig, frames = moving_plane
    cfg = ReconstructConfig(matching=MatchingConfig(num_features=800), match_every=2)
    tracker = Tracker(rig, cfg, edges=EDGES3)
    tracker.step(0, frames[0])
    r1 = tracker.step(1, frames[1])
    assert r1.num_new > 0
    still = Tracker(rig, cfg, edges=EDGES3)
    s0 = still.step(0, frames[0])
    s1 = still.step(1, frames[0])  # the same images: nothing moves, nothing is matched
    assert s1.num_new == 0 and len(s1) > 0.9 * len(s0)


def test_tracker_can_start_flow_at_the_previous_observations(moving_plane):
    rig, frames = moving_plane
    cfg = ReconstructConfig(matching=MatchingConfig(num_features=800), lk_start="observation")
    tracker = Tracker(rig, cfg, edges=EDGES3)
    records = [tracker.step(t, imgs) for t, imgs in enumerate(frames[:3])]
    traj = assemble_trajectories(records, rig.names, 30.0, 3)
    full = np.flatnonzero(traj.lengths == 3)
    assert len(full) > 0.8 * len(records[0])
    d = traj.dense_positions(full)
    drift = np.linalg.norm(d[:, -1] - d[:, 0] - 2 * VELOCITY, axis=1)
    assert np.median(drift) < 0.003


def test_expand_views_finds_points_in_the_cameras_that_miss_them(moving_plane):
    """Points observed in cameras 0 and 1 only are found in camera 2 at their true pixels."""
    rig, frames = moving_plane
    grey = [np.ascontiguousarray(im[..., 0]) for im in frames[0]]
    rng = np.random.default_rng(2)
    X = np.column_stack([rng.uniform(-0.5, 0.5, (300, 2)), np.zeros(300)])  # on the plane z = 0
    true = rig.project(X).pixels  # (3, N, 2)
    pix = true.copy()
    pix[2] = np.nan
    pix[0, :100] = np.nan  # 100 points seen only by camera 1
    cand = np.ones((3, 300), bool)
    # a wrong 3D point (15 cm in front of the plane) projects off its patch in camera 2
    X_bad = X.copy()
    X_bad[200:] += [0.0, 0.0, 0.15]
    out = expand_views(rig, grey, X_bad, pix, cand, max_angle_deg=40.0, max_px=2.0)
    seen = np.isfinite(pix)
    np.testing.assert_array_equal(out[seen], pix[seen])  # observed views unchanged
    found = np.all(np.isfinite(out[2]), axis=1)
    assert found[:200].mean() > 0.9
    err = np.linalg.norm(out[2, :200][found[:200]] - true[2, :200][found[:200]], axis=1)
    assert np.median(err) < 0.2 and np.percentile(err, 95) < 0.5
    assert found[200:].mean() < 0.1  # the flow lands on the true patch, far from the projection
    # points seen by camera 1 alone are found in camera 0 as well
    back = np.all(np.isfinite(out[0, :100]), axis=1)
    assert back.mean() > 0.9
    assert np.median(np.linalg.norm(out[0, :100][back] - true[0, :100][back], axis=1)) < 0.2
    # no camera within the angle: nothing is searched
    none = expand_views(rig, grey, X, pix, cand, max_angle_deg=1.0)
    assert not np.isfinite(none[2]).any()


def test_flow_starts_at_the_projection_the_last_step_kept(moving_plane):
    """The live points' projection kept from the last step is the projection of the state's
    points: a tracker that projects them afresh every frame gives the same records."""
    rig, frames = moving_plane
    cfg = ReconstructConfig(matching=MatchingConfig(num_features=800), occlusion_depth_m=0.05)
    kept, fresh = Tracker(rig, cfg, edges=EDGES3), Tracker(rig, cfg, edges=EDGES3)
    for t, imgs in enumerate(frames[:4]):
        a = kept.step(t, imgs)
        st, pixels = kept._projected
        assert st is kept.state
        np.testing.assert_array_equal(pixels, rig.project(kept.state.xyz).pixels)
        fresh._projected = None  # projected afresh at its next step
        b = fresh.step(t, imgs)
        for name in ("ids", "xyz", "visibility", "error", "color"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert len(a) > 100
    # a state set from outside (a resumed run) is projected afresh
    kept.state = dataclasses.replace(kept.state)
    assert kept._projected[0] is not kept.state
