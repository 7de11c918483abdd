"""One-view survival: points carried by their neighbours' rigid motion while they have one view,
re-triangulated when a second view returns; and the occlusion test's per-point tolerance."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from helpers.rigs import plane_rig
from helpers.scenes import plane_frames
from scipy.spatial.transform import Rotation

from pointtraj.config import from_mapping
from pointtraj.errors import ValidationError
from pointtraj.reconstruct.config import ReconstructConfig
from pointtraj.reconstruct.matching import MatchingConfig
from pointtraj.reconstruct.occlusion import occlusion_test
from pointtraj.reconstruct.survive import SurviveConfig, carry_one_view, predict_rigid
from pointtraj.reconstruct.track import Tracker, occlusion_tolerance


def test_rigid_prediction_follows_the_neighbours_motion():
    rng = np.random.default_rng(0)
    before = rng.uniform(-0.05, 0.05, (200, 3))
    R = Rotation.from_rotvec([0.05, -0.1, 0.2]).as_matrix()
    t = np.array([0.02, -0.01, 0.03])
    after = before @ R.T + t
    points = rng.uniform(-0.04, 0.04, (30, 3))
    pred, ok = predict_rigid(before, after, points, SurviveConfig(radius_m=0.05))
    assert ok.all()
    np.testing.assert_allclose(pred, points @ R.T + t, atol=1e-9)
    # neighbours that do not move rigidly carry nothing
    shaken = after + rng.normal(0, 0.02, after.shape)
    _, ok = predict_rigid(before, shaken, points, SurviveConfig(max_fit_m=0.01))
    assert not ok.any()
    # nor do too few neighbours within the radius
    far = points + 1.0
    pred, ok = predict_rigid(before, after, far)
    assert not ok.any() and np.isnan(pred).all()


def test_a_carried_point_lies_on_the_ray_of_the_view_that_agrees(wide_rig):
    rig = wide_rig
    X = np.array([[0.0, 0.0, 0.0], [0.1, 0.05, 0.0], [-0.1, 0.1, 0.0]])
    obs = rig.project(X).pixels.copy()
    obs[1:] = np.nan  # each point keeps only camera 0's view
    obs[0, 2] += 30.0  # the third point's view is far from its prediction
    pred = X + np.array([0.0, 0.0, 0.01])  # the prediction is 1 cm off along z
    points, cam, dist, ok = carry_one_view(rig, pred, obs, max_px=4.0)
    assert ok.tolist() == [True, True, False] and cam.tolist() == [0, 0, -1]
    # on camera 0's ray through the observation: it projects exactly there
    np.testing.assert_allclose(rig.project(points[:2]).pixels[0], obs[0, :2], atol=1e-6)
    assert np.all(np.linalg.norm(points[:2] - pred[:2], axis=1) < 0.01)
    assert np.all(dist[:2] < 4.0) and np.isnan(dist[2])


def test_occlusion_tolerance_per_point():
    """A point is hidden only by a point whose depth interval lies wholly in front of its own;
    one tolerance for all is the same as the same tolerance per point."""
    from pointtraj.camera import Camera, CameraRig

    cam = Camera.look_at("a", [3, 0, 1], [0, 0, 1], (640, 480), 500.0)
    rig = CameraRig([cam])
    X = np.array([[0.0, 0.0, 1.0], [-0.03, 0.0, 1.0], [-0.2, 0.0, 1.0]])  # 3 cm, 20 cm behind
    assert occlusion_test(rig, X, 0.02)[:, 0].tolist() == [False, True, True]
    np.testing.assert_array_equal(
        occlusion_test(rig, X, np.full(3, 0.02)), occlusion_test(rig, X, 0.02)
    )
    # the second point is uncertain (tolerance 8 cm): it may lie on the first one's surface
    tol = np.array([0.02, 0.08, 0.02])
    assert occlusion_test(rig, X, tol)[:, 0].tolist() == [False, False, True]
    with pytest.raises(ValidationError, match="one per point"):
        occlusion_test(rig, X, np.full(2, 0.02))


def test_occlusion_tolerance_follows_the_triangulation_angle():
    rig = plane_rig(angles=(-5.0, 0.0, 5.0, 60.0))
    X = np.zeros((3, 3))
    observed = np.zeros((4, 3), bool)
    observed[[0, 1], 0] = True  # 5 degrees apart: a poor depth
    observed[[0, 3], 1] = True  # 65 degrees apart: a good one
    observed[0, 2] = True  # one view: no depth at all
    cfg = ReconstructConfig(occlusion_sigmas=3.0)
    tol = occlusion_tolerance(cfg, rig, X, observed)
    assert tol[0] == cfg.occlusion_depth_m and tol[2] == cfg.occlusion_depth_m
    # 2 m away at f = 400 px: 5 mm a pixel, over sin(65 deg), times 2 x 3 sigmas
    np.testing.assert_allclose(tol[1], 6 * (2.0 / 400) / np.sin(np.radians(65)), rtol=0.02)
    assert cfg.occlusion_min_m <= tol[1] < tol[0]
    fixed = dataclasses.replace(cfg, occlusion_sigmas=0.0)
    assert occlusion_tolerance(fixed, rig, X, observed) == cfg.occlusion_depth_m


@pytest.fixture(scope="module")
def occluded_frames(wide_rig):
    """A textured plane moving in front of three cameras 35 degrees apart; at frame 2 an
    occluder (a black band 60 px wide) hides part of it from cameras 1 and 2, for one frame."""
    velocity = np.array([0.01, 0.0, 0.005])
    frames = plane_frames(wide_rig, 5, seed=3, velocity=velocity)
    for c in (1, 2):
        frames[2][c][:, 240:300] = 0
    return wide_rig, frames, velocity


def test_trajectories_survive_a_frame_on_one_view(occluded_frames):
    rig, frames, velocity = occluded_frames
    base = ReconstructConfig(
        matching=MatchingConfig(num_features=1500),
        max_angle_deg=130.0,
        min_views_new=2,
        lk_levels=1,  # keeps the black band's effect on the flow local
    )
    recs = {}
    for frames_on_one in (0, 3):
        cfg = dataclasses.replace(base, survive=SurviveConfig(frames=frames_on_one))
        tracker = Tracker(rig, cfg)
        recs[frames_on_one] = [tracker.step(t, imgs) for t, imgs in enumerate(frames)]
        if frames_on_one:
            assert tracker.stops["one-view"] < 10
    # at frame 2, points of frame 1 that lost both other views go on with camera 0's view (and
    # view discovery finds most of them again in camera 2 where the band does not hide them)
    on, off = recs[3], recs[0]
    cont_on = np.intersect1d(on[1].ids, on[2].ids)
    cont_off = np.intersect1d(off[1].ids, off[2].ids)
    assert np.isin(cont_off, cont_on).all()
    carried = np.setdiff1d(cont_on, cont_off)
    assert len(carried) >= 10, len(carried)
    r2 = on[2]
    sel = np.isin(r2.ids, carried)
    assert np.median(np.abs(r2.xyz[sel, 2] - 2 * velocity[2])) < 0.01
    # two frames later they are triangulated from two or more views, on the plane
    r4 = on[4]
    back = np.isin(r4.ids, carried)
    assert back.sum() >= 0.8 * len(carried)
    views4 = np.count_nonzero(r4.visibility[back] > 0.05 * 255, axis=1)
    assert np.mean(views4 >= 2) >= 0.9
    assert np.median(np.abs(r4.xyz[back, 2] - 4 * velocity[2])) < 0.004
    # without survival, every live point has two views or more
    assert all(np.all(np.count_nonzero(r.visibility > 0.05 * 255, axis=1) >= 2) for r in off)


def test_survive_config_from_toml_and_validation():
    cfg = from_mapping(ReconstructConfig, {"survive": {"frames": 5, "radius_m": 0.04}})
    assert cfg.survive == SurviveConfig(frames=5, radius_m=0.04)
    with pytest.raises(ValidationError, match="min_neighbors"):
        SurviveConfig(min_neighbors=2)
    with pytest.raises(ValidationError, match="occlusion_sigmas"):
        ReconstructConfig(occlusion_sigmas=-1.0)


def test_one_view_tails_are_trimmed_and_bridges_kept():
    from pointtraj.reconstruct.survive import trim_one_view_tails
    from pointtraj.trajectories import Trajectories

    T, C = 6, 3
    xyz = np.zeros((3, T, 3))
    vis = np.zeros((3, T, C))
    vis[:, :, :2] = 1.0  # two views everywhere
    vis[0, 4:, 1] = 0.0  # trajectory 0: one view in its last two frames -> trimmed to 4
    vis[1, 2, 1] = 0.0  # trajectory 1: one view at frame 2, two again after -> kept whole
    xyz[2, :2] = np.nan  # trajectory 2 starts at frame 2 ...
    vis[2, 5, :] = 0.0  # ... and has no view in its last frame -> trimmed to 3
    traj = Trajectories.from_dense(xyz, vis, camera_names=["a", "b", "c"])
    out, dropped = trim_one_view_tails(traj)
    assert dropped == 3
    assert out.lengths.tolist() == [4, 6, 3]
    assert out.first_frame.tolist() == traj.first_frame.tolist()
    np.testing.assert_array_equal(
        out.visibility[out.rows_of(np.array([1]))], traj.visibility[traj.rows_of(np.array([1]))]
    )
    # nothing to trim: the same store
    same, none = trim_one_view_tails(out)
    assert same is out and none == 0


def test_a_tracker_state_with_a_wrong_lone_count_is_refused(tmp_path):
    from pointtraj.errors import FileFormatError
    from pointtraj.reconstruct.framestore import FrameStore
    from pointtraj.reconstruct.track import TrackState

    C = 3
    st = TrackState(
        4,
        np.arange(2),
        np.zeros((2, 3)),
        np.ones((2, C), np.float32),
        np.zeros((C, 2, 2), np.float32),
        2,
        np.array([0, 1]),
    )
    store = FrameStore(tmp_path, C)
    store.write_live(st)
    assert store.read_live().lone.tolist() == [0, 1]
    d = dict(np.load(store.live_path))
    d["lone"] = np.zeros(5, np.int64)
    np.savez(store.live_path, **d)
    with pytest.raises(FileFormatError, match="live_lone"):
        store.read_live()
