"""The forward-backward flow check, skipped for points in many cameras (issue #14): their
re-triangulation's RANSAC drops a view that the flow lost."""

from __future__ import annotations

import numpy as np
import pytest
from helpers.rigs import plane_rig
from helpers.scenes import make_texture, plane_frames

from pointtraj.errors import ValidationError
from pointtraj.reconstruct.config import ReconstructConfig
from pointtraj.reconstruct.flow import track_flow
from pointtraj.reconstruct.matching import MatchingConfig
from pointtraj.reconstruct.track import Tracker, effective_fb_skip


def _grey(seed: int):
    import cv2

    return cv2.cvtColor(make_texture(np.random.default_rng(seed), 256), cv2.COLOR_RGB2GRAY)


def _lost_camera_scene():
    """Six cameras over a textured plane, two frames; camera 2's second image replaced by an
    unrelated texture (its flow is lost). Returns the rig, the frames, the second frame with
    the lost image, and the camera pairs to match."""
    rig = plane_rig(angles=np.linspace(-25.0, 25.0, 6))
    frames = plane_frames(rig, 2, seed=3, velocity=(0.01, 0.005, 0.0))
    lost = [im.copy() for im in frames[1]]
    lost[2] = make_texture(np.random.default_rng(9), max(lost[2].shape))[
        : lost[2].shape[0], : lost[2].shape[1]
    ]
    edges = np.array([[c, c + 1] for c in range(len(rig) - 1)])
    return rig, frames, lost, edges


def test_unchecked_points_keep_the_forward_flow():
    import cv2

    a, c = _grey(0), _grey(9)  # two unrelated images: the backward check rejects most
    pts = np.random.default_rng(1).uniform(40, 210, (200, 2))
    checked = track_flow(a, c, pts, fb_max_px=0.5)
    assert np.array_equal(
        checked, track_flow(a, c, pts, fb_max_px=0.5, check=np.ones(200, bool)), equal_nan=True
    )
    check = np.arange(200) % 2 == 0
    mixed = track_flow(a, c, pts, fb_max_px=0.5, check=check)
    assert np.array_equal(mixed[check], checked[check], equal_nan=True)
    # the unchecked half: the forward flow wherever it converged inside the image
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 0.01)
    p1, st, _ = cv2.calcOpticalFlowPyrLK(
        a, c, pts[~check].astype(np.float32).reshape(-1, 1, 2), None,
        winSize=(21, 21), maxLevel=3, criteria=crit,
    )  # fmt: skip
    p1 = p1.reshape(-1, 2)
    inside = (st.ravel() == 1) & np.all((p1 >= -0.5) & (p1 < 255.5), axis=1)
    np.testing.assert_array_equal(np.isfinite(mixed[~check, 0]), inside)
    np.testing.assert_allclose(mixed[~check][inside], p1[inside])
    assert inside.mean() > 2 * np.isfinite(checked[~check, 0]).mean()
    with pytest.raises(ValidationError, match="check"):
        track_flow(a, c, pts, check=np.ones(3, bool))
    with pytest.raises(ValidationError, match="fb_skip_views"):
        ReconstructConfig(fb_skip_views=2)


def test_ransac_drops_the_lost_view_of_a_point_in_many_cameras():
    """Camera 2's second image is unrelated to its first: its flow is lost. Points in six
    cameras skip the backward check there, and the re-triangulation drops the view; the
    points stay on the plane z = 0 and are tracked as with the check."""
    rig, frames, lost, edges = _lost_camera_scene()
    out = {}
    for skip in (0, 4):
        cfg = ReconstructConfig(matching=MatchingConfig(num_features=800), fb_skip_views=skip)
        tracker = Tracker(rig, cfg, edges=edges)
        tracker.step(0, frames[0])
        before = tracker.state
        many = np.count_nonzero(before.visibility > cfg.visibility_threshold, axis=1) >= 4
        tracker.step(1, lost)
        st = tracker.state
        old = np.isin(st.ids, before.ids[many])
        out[skip] = (old.sum(), st.visibility[old, 2], st.xyz[old])
        assert many.sum() > 100
    n0, _, _ = out[0]
    n4, vis2, xyz = out[4]
    assert n4 >= 0.95 * n0  # tracked as with the check
    assert np.mean(vis2 > 0.05) < 0.02  # the lost camera's views are gone
    # on the plane z = 0 as with the check (the plane's own error: about 5 mm a pixel here)
    z0, z4 = (np.percentile(np.abs(out[k][2][:, 2]), [50, 99]) for k in (0, 4))
    np.testing.assert_allclose(z4, z0, atol=0.001)


def test_a_loose_ransac_keeps_the_check_for_every_point(caplog):
    """Where RANSAC tolerates more than twice the backward check's error, it cannot stand in
    for the check: every point keeps it, as with fb_skip_views = 0, and the tracker says so."""
    assert effective_fb_skip(ReconstructConfig()) == 4  # 2 px against 2 x 1 px
    loose = ReconstructConfig(ransac_threshold_px=12.0, max_mean_error_px=12.0)
    assert effective_fb_skip(loose) == 0
    assert effective_fb_skip(ReconstructConfig(ransac_threshold_px=12.0, fb_max_px=6.0)) == 4
    assert effective_fb_skip(ReconstructConfig(ransac_threshold_px=12.0, fb_skip_views=0)) == 0
    rig, frames, lost, edges = _lost_camera_scene()
    states = []
    for skip in (0, 4):
        cfg = ReconstructConfig(
            matching=MatchingConfig(num_features=800),
            ransac_threshold_px=12.0,
            max_mean_error_px=12.0,
            fb_skip_views=skip,
        )
        with caplog.at_level("INFO", logger="pointtraj.reconstruct.track"):
            caplog.clear()
            tracker = Tracker(rig, cfg, edges=edges)
        logged = "keeps the forward-backward flow check" in caplog.text
        assert logged == bool(skip)
        tracker.step(0, frames[0])
        tracker.step(1, lost)
        states.append(tracker.state)
    assert len(states[1]) > 100
    np.testing.assert_array_equal(states[1].ids, states[0].ids)
    np.testing.assert_array_equal(states[1].xyz, states[0].xyz)
    np.testing.assert_array_equal(states[1].visibility, states[0].visibility)
