"""The ground-truth view audit (issue #20) on a tiny synthetic capture."""

from __future__ import annotations

import numpy as np
import pytest

from pointtraj.evaluate.views import (
    false_occlusion_rate,
    frame_truth,
    true_visibility,
    view_audit,
)
from pointtraj.session import Capture
from pointtraj.stages import SynthConfig, synthesize
from pointtraj.synth.groundtruth import load_ground_truth
from pointtraj.trajectories import Trajectories


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    """A tiny4 dribble capture of 4 frames and its ground-truth trajectories."""
    cap = tmp_path_factory.mktemp("views") / "cap"
    synthesize(cap, SynthConfig(preset="tiny4", frames=4, points_per_part=40))
    gt = load_ground_truth(cap)
    return cap, gt, gt.to_trajectories(min_visible=2)


def _true_views(cap, traj: Trajectories) -> np.ndarray:
    """(P, C) true visibility at each point-frame's own position (GT stores: the samples)."""
    rig = Capture.open(cap).rig.subset(traj.camera_names)
    out = np.zeros((traj.num_point_frames, traj.num_cameras), bool)
    for t in range(traj.num_frames):
        rows = traj.frame_rows(t)
        out[rows] = true_visibility(cap, rig, t, traj.xyz[rows].astype(np.float64))[0]
    return out


def test_the_ground_truth_store_sees_what_the_ground_truth_sees(capture):
    cap, gt, traj = capture
    audit = view_audit(cap, traj)
    # Every GT trajectory is a GT sample: all on the actors, the nearest sample itself.
    assert audit.actor_point_frames == audit.live_point_frames == traj.num_point_frames
    flags = traj.visibility > 0  # the store's visibility is the stored flags (1.0 or 0.0)
    true = _true_views(cap, traj)
    assert audit.observed_views == int(flags.sum())
    assert audit.true_views == int(true.sum())
    assert audit.hit_views == int((flags & true).sum())
    # The stored flags widen the 1 cm depth test to two pixel footprints (about 2.4 cm at this
    # 320x256 rig) and check the part seen at the pixel; the audit's 1 cm test is stricter.
    assert audit.recall > 0.97
    assert audit.precision > 0.8
    loose = view_audit(cap, traj, depth_tol=0.03, errors=False)
    assert loose.precision > 0.97
    # Each GT trajectory is one run of >= 2 flagged views.
    assert np.array_equal(np.sort(audit.flag_runs), np.sort(gt.segments(2)[2]))
    assert np.array_equal(np.sort(audit.actor_lengths), np.sort(traj.lengths))
    assert audit.errors["2"].size + audit.errors["3"].size + audit.errors["4+"].size == (
        int((flags.sum(axis=1) >= 2).sum())
    )
    assert np.median(audit.errors["2"]) < 0.003
    # What the rig allows: the samples' own true views, counted over every sample-frame.
    n_true = np.concatenate(
        [frame_truth(cap, Capture.open(cap).rig, t).visible.sum(axis=1) for t in range(4)]
    )
    assert audit.surface_two == int((n_true >= 2).sum()) > audit.surface_three > 0
    assert audit.surface_three_view_share == pytest.approx(
        (n_true >= 3).sum() / (n_true >= 2).sum()
    )
    assert audit.three_view_truth == int((true.sum(axis=1) >= 3).sum())
    m = audit.to_metrics()
    assert m["gt.views.surface_three_view.support"] == audit.surface_two
    assert m["gt.views.three_view_truth"] == pytest.approx(
        audit.three_view_truth / audit.actor_point_frames
    )
    assert m["gt.views.recall"] == audit.recall
    assert m["gt.views.recall.support"] == audit.true_views
    assert m["gt.views.two_view_share.support"] == traj.num_point_frames


def test_removing_views_lowers_recall_by_exactly_the_removed_hits(capture):
    cap, _, traj = capture
    base = view_audit(cap, traj, errors=False)
    true = _true_views(cap, traj)
    rng = np.random.default_rng(0)
    drop = rng.random(traj.visibility.shape) < 0.3  # (P, C)
    vis = traj.visibility.copy()
    vis[drop] = 0
    cut = Trajectories(
        traj.first_frame,
        traj.offsets,
        traj.xyz,
        vis,
        traj.reprojection_error,
        traj.color,
        traj.camera_names,
        traj.fps,
        traj.num_frames,
    )
    lost = int((drop & (traj.visibility > 0) & true).sum())
    assert lost > 0
    audit = view_audit(cap, cut, errors=False)
    assert audit.true_views == base.true_views
    assert audit.hit_views == base.hit_views - lost
    assert audit.recall == pytest.approx((base.hit_views - lost) / base.true_views, abs=1e-12)
    assert audit.observed_views == int((vis > 0).sum())
    assert audit.recall < base.recall - 0.2


def test_false_occlusion_rate_of_trivial_masks(capture):
    cap, _, traj = capture
    rig = Capture.open(cap).rig.subset(traj.camera_names)
    t = 1
    xyz = traj.xyz[traj.frame_rows(t)].astype(np.float64)
    none = false_occlusion_rate(cap, rig, t, xyz, np.zeros((len(xyz), len(rig)), bool))
    assert none.marked == 0 and none.false_rate == 0.0
    assert none.occluded > 0 and none.recall == 0.0
    in_image = rig.project(xyz).in_image.T  # (N, C)
    every = false_occlusion_rate(cap, rig, t, xyz, in_image)
    visible, _ = true_visibility(cap, rig, t, xyz)
    assert every.marked == int(in_image.sum())
    assert every.false_rate == pytest.approx((visible & in_image).sum() / in_image.sum())
    assert every.recall == 1.0 and every.occluded == none.occluded
    # Points far from every actor do not count.
    far = false_occlusion_rate(cap, rig, t, xyz + 10.0, np.ones_like(in_image))
    assert far.marked == 0 and far.occluded == 0


def test_frame_truth_follows_the_rig_order(capture):
    cap, _, traj = capture
    rig = Capture.open(cap).rig.subset(traj.camera_names)
    rev = rig.subset(list(reversed(rig.names)))
    a, b = frame_truth(cap, rig, 0), frame_truth(cap, rev, 0)
    assert np.array_equal(a.visible, b.visible[:, ::-1])
    assert np.array_equal(a.flags, b.flags[:, ::-1])
    assert a.flags.any() and not np.array_equal(a.flags, a.flags[:, ::-1])
