"""Points that view discovery refutes (issue #20): they float off the surface and hide
nothing in the occlusion test."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from helpers.rigs import plane_rig
from helpers.scenes import plane_frames

from pointtraj.errors import ValidationError
from pointtraj.reconstruct.config import ReconstructConfig
from pointtraj.reconstruct.matching import MatchingConfig
from pointtraj.reconstruct.occlusion import occlusion_test
from pointtraj.reconstruct.track import Tracker, TrackState
from pointtraj.reconstruct.views import ViewsConfig, refuted


def test_refuted_needs_many_failed_cameras_against_few_observing_ones():
    misses = np.zeros((4, 20), np.uint8)
    misses[0, :8] = 1  # 8 failed cameras, 2 observing: refuted
    misses[1, :8] = 3  # the same with more failures in a row: the count of cameras matters
    misses[2, :7] = 1  # 7 failed cameras: too few
    misses[3, :12] = 1  # 12 failed, 4 observing: 3 times, below the ratio of 4
    observed = np.array([2, 2, 1, 4])
    np.testing.assert_array_equal(refuted(misses, observed, ViewsConfig()), [1, 1, 0, 0])
    ratio3 = ViewsConfig(refute_fail_ratio=3.0)
    np.testing.assert_array_equal(refuted(misses, observed, ratio3), [1, 1, 0, 1])
    assert not refuted(misses, observed, ViewsConfig(refute_fail_ratio=0.0)).any()  # off
    with pytest.raises(ValidationError, match="refute_min_fails"):
        ViewsConfig(refute_min_fails=0)


def test_a_point_that_hides_nothing_is_still_tested():
    """The occluders mask: a point left out of it hides nothing but can itself be hidden."""
    from pointtraj.camera import Camera, CameraRig

    rig = CameraRig([Camera.look_at("a", [3, 0, 1], [0, 0, 1], (640, 480), 500.0)])
    X = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 1.0], [-2.0, 0.0, 1.0]])  # one behind the other
    assert occlusion_test(rig, X, 0.05)[:, 0].tolist() == [False, True, True]
    some = occlusion_test(rig, X, 0.05, occluders=np.array([False, True, True]))
    # the nearest hides nothing: the middle one is visible, the last still behind the middle
    assert some[:, 0].tolist() == [False, False, True]
    with pytest.raises(ValidationError, match="occluders"):
        occlusion_test(rig, X, 0.05, occluders=np.ones(2, bool))


@pytest.fixture(scope="module")
def ten_cameras():
    """Ten cameras 2 m from a still textured plane, 80 degrees between the outermost."""
    rig = plane_rig(angles=np.linspace(-40.0, 40.0, 10))
    return rig, plane_frames(rig, 2, seed=3)


def test_floating_points_that_discovery_refutes_hide_nothing(ten_cameras):
    """Points 10 cm in front of the plane, tracked in two cameras and not found in the
    other eight, used to hide the plane's points behind them in those eight (the false
    occlusions that grew over a paper69 run); refuted, they hide nothing, and they stay."""
    rig, frames = ten_cameras
    C = len(rig)
    base = ReconstructConfig(matching=MatchingConfig(num_features=800), max_angle_deg=90.0)
    edges = np.array([[c, c + 1] for c in range(C - 1)])
    rng = np.random.default_rng(0)
    floaters = np.column_stack([rng.uniform(-0.3, 0.3, (60, 2)), np.full(60, 0.1)])
    fpix = rig.project(floaters).pixels  # (C, F, 2)
    kept = {}
    for ratio in (4.0, 0.0):
        # (grazing views kept: the floaters tilt the normals fitted to the plane under them;
        # unconfirmed two-view points kept, which would end the floaters instead: this is
        # about the points that stay)
        views = ViewsConfig(refute_fail_ratio=ratio, drop_grazing=False, unconfirmed_fails=0)
        cfg = dataclasses.replace(base, views=views)
        tracker = Tracker(rig, cfg, edges=edges)
        tracker.step(0, frames[0])
        st = tracker.state
        F = len(floaters)
        vis = np.zeros((F, C), np.float32)
        vis[:, :2] = 1.0  # observed in cameras 0 and 1 ...
        pix = np.full((C, F, 2), np.nan, np.float32)
        pix[:2] = fpix[:2]
        misses = np.zeros((F, C), np.uint8)
        misses[:, 2:] = 1  # ... and searched in vain in the other eight
        tracker.state = TrackState(
            st.frame,
            np.concatenate([st.ids, st.next_id + np.arange(F)]),
            np.vstack([st.xyz, floaters]),
            np.vstack([st.visibility, vis]),
            np.concatenate([st.pixels, pix], axis=1),
            st.next_id + F,
            np.concatenate([st.lone, np.zeros(F, np.int64)]),
            np.vstack([st.misses, misses]),
        )
        rec = tracker.step(1, frames[1])
        plane = np.isin(rec.ids, st.ids)
        # the plane's views in cameras 2-9 that lie behind a floater (within 6 px of one)
        proj = rig.project(rec.xyz[plane]).pixels  # (C, P, 2)
        gap = np.linalg.norm(proj[2:, :, None] - fpix[2:, None], axis=3).min(axis=2)  # (8, P)
        before = st.visibility[np.isin(st.ids, rec.ids[plane])][:, 2:].T > 0.05
        behind = (gap < 6.0) & before
        now = rec.visibility[plane][:, 2:].T > 0.05
        kept[ratio] = (now & behind).sum() / behind.sum()
        assert behind.sum() > 50
        assert np.isin(st.next_id + np.arange(F), rec.ids).mean() > 0.9  # the floaters stay
    assert kept[0.0] < 0.5  # hidden by the floaters
    assert kept[4.0] > 0.9


def test_views_beyond_the_incidence_limit_are_dropped_where_three_remain():
    """A plane seen from three cameras near its normal and one at 85 degrees: the grazing
    view goes where three others remain, and stays on a point that would keep two."""
    from pointtraj.reconstruct.views import grazing_views

    rig = plane_rig(angles=(-20.0, 0.0, 20.0, 85.0))
    g = np.linspace(-0.2, 0.2, 10)
    xyz = np.column_stack([np.repeat(g, 10), np.tile(g, 10), np.zeros(100)])  # z = 0
    observed = np.ones((4, 100), bool)
    observed[0, 50:] = False  # the second half: two views besides the grazing one
    drop = grazing_views(rig, xyz, observed, ViewsConfig())
    assert drop[3, :50].all() and not drop[:3].any()
    assert not drop[3, 50:].any()
    assert not grazing_views(rig, xyz, observed, ViewsConfig(max_incidence_deg=89.0)).any()
    assert not (drop & ~observed).any()


def test_normals_from_the_observed_views_alone_are_those_from_every_camera():
    """point_normals without the (C, N, 3) directions of every camera (as grazing_views calls
    it) gives the normals it gives with them, bit for bit: the fallback facing direction is
    summed from the observed views, camera by camera, in the same order."""
    from pointtraj.reconstruct.views import _directions, point_normals

    rig = plane_rig(angles=(-60.0, -20.0, 0.0, 20.0, 60.0, 85.0))
    rng = np.random.default_rng(4)
    xyz = np.column_stack([rng.uniform(-0.3, 0.3, (400, 2)), rng.normal(0, 0.01, 400)])
    xyz[:3] += 5.0  # far from the others: a plane through a bad neighbourhood
    observed = rng.random((len(rig), 400)) < 0.5
    observed[:, 10] = False  # a point with no view: facing nowhere
    sparse = point_normals(rig, xyz, observed, 12)
    dense = point_normals(rig, xyz, observed, 12, directions=_directions(rig, xyz))
    assert np.array_equal(sparse, dense)
    few = point_normals(rig, xyz[:2], observed[:, :2])  # too few for a plane: the facing
    assert np.array_equal(
        few, point_normals(rig, xyz[:2], observed[:, :2], 12, _directions(rig, xyz[:2]))
    )
    assert np.allclose(np.linalg.norm(few, axis=1), 1.0)
