"""Segment poses and SCoRE joint centres (pointtraj.segments) on exact synthetic rigid parts."""

from __future__ import annotations

import numpy as np
import pytest

from pointtraj.errors import FileFormatError, ValidationError
from pointtraj.geometry import (
    fit_rigid,
    fit_rigid_groups,
    ransac_rigid_groups,
    rotation_angle_deg,
    rotation_from_rodrigues,
)
from pointtraj.labelset import LabelSet
from pointtraj.segments import (
    JOINT_STATUS,
    Segments,
    SegmentsConfig,
    compute_segments,
    load_segments,
    save_segments,
)
from pointtraj.trajectories import Trajectories

LABELS = LabelSet(
    ["torso", "head", "ball"],
    [[0, 200, 0], [200, 0, 0], [0, 0, 200]],
    kinds=["body", "body", "object"],
    joints=[("neck", "torso", "head")],
)
JOINT = np.array([0.05, -0.02, 0.5])  # the joint in the torso's (and the head's) local frame


def _rot(v) -> np.ndarray:
    return rotation_from_rodrigues(np.asarray(v, float))


def _two_parts(rng, T=40, n=60, relative="ball", split=True, people=1):
    """Exact rigid torso and head joined at :data:`JOINT`, ``people`` of them side by side.

    Returns trajectories, labels, instance, and per person the true torso and head world
    rotations (T, 3, 3) and the world joint (T, 3).
    """
    torso = rng.uniform([-0.15, -0.1, 0.0], [0.15, 0.1, 0.45], size=(n, 3))
    head = JOINT + rng.uniform([-0.08, -0.08, 0.05], [0.08, 0.08, 0.25], size=(n, 3))
    xyz, lab, inst, truth = [], [], [], []
    for p in range(people):
        Ra = np.stack([_rot([0.1 * np.sin(0.1 * t), 0.05 * t, 0.3 + 0.02 * t]) for t in range(T)])
        ta = np.stack([[0.3 * np.sin(0.05 * t) + 2.0 * p, 0.01 * t, 1.0] for t in range(T)])
        if relative == "ball":
            rel = [
                [0.5 * np.sin(0.3 * t), 0.4 * np.cos(0.23 * t), 0.3 * np.sin(0.17 * t)]
                for t in range(T)
            ]
        elif relative == "hinge":
            rel = [[0.6 * np.sin(0.3 * t), 0.0, 0.0] for t in range(T)]
        else:
            rel = [[0.0, 0.0, 0.0]] * T
        Rr = np.stack([_rot(v) for v in rel])
        Rb = Ra @ Rr  # head rotation: torso's, then the neck's
        a = np.einsum("tij,nj->nti", Ra, torso) + ta  # (n, T, 3)
        b = np.einsum("tij,nj->nti", Rb, head - JOINT) + (Ra @ JOINT + ta)[None]
        xyz += [a, b]
        lab += [np.zeros(n, int), np.ones(n, int)]
        inst += [np.full(2 * n, p)]
        truth.append((Ra, Rb, Ra @ JOINT + ta))
    xyz = np.concatenate(xyz)
    lab = np.concatenate(lab)
    inst = np.concatenate(inst)
    if split:  # fragmentary trajectories: each point split into two at a random frame
        cut = rng.integers(5, T - 5, size=len(xyz))
        first = xyz.copy()
        second = xyz.copy()
        for m, c in enumerate(cut):
            first[m, c:] = np.nan
            second[m, :c] = np.nan
        xyz = np.concatenate([first, second])
        lab = np.concatenate([lab, lab])
        inst = np.concatenate([inst, inst])
    return Trajectories.from_dense(xyz, camera_names=["a", "b"]), lab, inst, truth


def _pose_errors(seg: Segments, s: int, R_true: np.ndarray) -> np.ndarray:
    """Rotation error (degrees) of segment s against the truth relative to its reference."""
    r = int(seg.reference_frame[s])
    R_rel = R_true @ R_true[r].T  # (T, 3, 3)
    return rotation_angle_deg(seg.rotation[s], R_rel)


def test_ransac_groups_match_fit_rigid():
    """Noise-free groups: the RANSAC fit equals the batched Kabsch of :func:`fit_rigid`."""
    rng = np.random.default_rng(0)
    src = rng.normal(size=(2, 30, 3))
    R = np.stack([_rot([0.3, -0.2, 0.1]), _rot([0.0, 1.0, 0.5])])
    dst = np.einsum("bij,bnj->bni", R, src) + [[[1.0, 2.0, 3.0]], [[0.0, -1.0, 0.5]]]
    ref = fit_rigid(src, dst)
    g = np.repeat([0, 1], 30)
    flat = fit_rigid_groups(src.reshape(-1, 3), dst.reshape(-1, 3), g, 2)
    np.testing.assert_allclose(flat.rotation, ref.rotation, atol=1e-10)
    np.testing.assert_allclose(flat.translation, ref.translation, atol=1e-10)
    fit = ransac_rigid_groups(
        src.reshape(-1, 3), dst.reshape(-1, 3), g, 3, threshold=1e-3, iterations=8, rng=rng
    )
    np.testing.assert_allclose(fit.rotation[:2], R, atol=1e-9)
    assert fit.valid.tolist() == [True, True, False]  # group 2 is empty
    assert fit.inliers.tolist() == [30, 30, 0]
    assert np.isnan(fit.rotation[2]).all() and np.isnan(fit.residual[2])


def test_noise_free_round_trip():
    """Exact parts, fragmentary trajectories: poses within 1e-4 degrees and the joint within
    1e-6 m (the store keeps float32 positions)."""
    rng = np.random.default_rng(1)
    traj, lab, _, truth = _two_parts(rng)
    seg = compute_segments(traj, lab, LABELS, config=SegmentsConfig(prior_deg=0.0))
    assert seg.num_segments == 2 and seg.rotation.shape == (2, 40, 3, 3)
    Ra, Rb, joint = truth[0]
    assert np.nanmax(_pose_errors(seg, 0, Ra)) < 1e-4
    assert np.nanmax(_pose_errors(seg, 1, Rb)) < 1e-4
    assert np.isfinite(seg.rotation[..., 0, 0]).all()
    assert (seg.inliers == seg.points).all() and np.nanmax(seg.residual) < 1e-6
    assert seg.joint_names == ("neck",)
    assert JOINT_STATUS[seg.joint_status[0]] == "ball"
    np.testing.assert_allclose(seg.joint_positions()[0], joint, atol=1e-6)
    assert seg.joint_frames[0] == 40 and seg.joint_residual[0] < 1e-6
    # centroids carry the origin: at the reference frame they are the mean reference position
    s = 0
    np.testing.assert_allclose(seg.centroids()[s, seg.reference_frame[s]], seg.origin[s])
    # the default pull towards the child's centroid biases a ball joint by well under 1 mm
    seg = compute_segments(traj, lab, LABELS)
    err = np.linalg.norm(seg.joint_positions()[0] - joint, axis=1)
    assert 1e-6 < err.max() < 1e-3


def test_ransac_rejects_mislabelled_points():
    """A fifth of the head's trajectories labelled torso: poses and joint still within 1 mm."""
    rng = np.random.default_rng(2)
    traj, lab, _, truth = _two_parts(rng, split=False)
    head = np.flatnonzero(lab == 1)
    wrong = rng.choice(head, size=len(head) // 5, replace=False)
    lab = lab.copy()
    lab[wrong] = 0
    noise = rng.normal(scale=0.001, size=traj.xyz.shape).astype(np.float32)
    traj.xyz = traj.xyz + noise
    seg = compute_segments(traj, lab, LABELS, config=SegmentsConfig(ransac_threshold=0.01))
    Ra, Rb, joint = truth[0]
    assert np.nanmedian(_pose_errors(seg, 0, Ra)) < 0.5
    err = np.linalg.norm(seg.joint_positions()[0] - joint, axis=1)
    assert np.median(err) < 0.003
    # the mislabelled points are outliers of the torso: inliers below the points fitted
    t = (seg.reference_frame[0] + 5) % 40
    assert seg.inliers[0, t] <= seg.points[0, t] - len(wrong) + 2


def test_hinge_and_unobservable_joints():
    """Rotation about one axis: a hinge on the true axis; no relative rotation: NaN + flag."""
    rng = np.random.default_rng(3)
    traj, lab, _, truth = _two_parts(rng, relative="hinge", split=False)
    seg = compute_segments(traj, lab, LABELS)
    assert JOINT_STATUS[seg.joint_status[0]] == "hinge"
    Ra, _, joint = truth[0]
    # the reported centre lies on the hinge axis (world x of the torso) through the joint
    d = seg.joint_positions()[0] - joint  # (T, 3)
    axis = Ra[:, :, 0]  # (T, 3)
    off_axis = d - np.einsum("ti,ti->t", d, axis)[:, None] * axis
    assert np.abs(off_axis).max() < 1e-3  # the pull to the centroid: a fraction of a mm
    off = SegmentsConfig(hinge_centres=False)
    seg = compute_segments(traj, lab, LABELS, config=off)
    assert JOINT_STATUS[seg.joint_status[0]] == "hinge_off"
    assert np.isnan(seg.joint_positions()).all()

    traj, lab, _, _ = _two_parts(rng, relative="none", split=False)
    seg = compute_segments(traj, lab, LABELS)
    assert JOINT_STATUS[seg.joint_status[0]] == "no_rotation"
    assert np.isnan(seg.joint_local).all() and np.isnan(seg.joint_positions()).all()
    assert (seg.joint_rotation_deg[0] < 1e-3).all()


def test_missing_part_and_few_frames():
    """A head without labelled points: the joint is NaN with status missing_part; a joint
    seen in fewer than min_frames frames is few_frames."""
    rng = np.random.default_rng(4)
    traj, lab, _, _ = _two_parts(rng, split=False)
    only_torso = np.where(lab == 1, -1, lab)
    seg = compute_segments(traj, only_torso, LABELS)
    assert seg.num_segments == 1 and JOINT_STATUS[seg.joint_status[0]] == "missing_part"
    assert np.isnan(seg.joint_positions()).all()
    seg = compute_segments(traj, lab, LABELS, config=SegmentsConfig(min_frames=41))
    assert JOINT_STATUS[seg.joint_status[0]] == "few_frames"
    assert np.isnan(seg.joint_positions()).all()


def test_too_few_points_leave_frames_without_pose():
    """A segment with fewer than min_points trajectories has NaN poses (not a guess)."""
    rng = np.random.default_rng(5)
    traj, lab, _, _ = _two_parts(rng, n=6, split=False)
    seg = compute_segments(traj, lab, LABELS, config=SegmentsConfig(min_points=7))
    ref = seg.reference_frame
    posed = np.isfinite(seg.rotation[..., 0, 0])
    # only the reference frames (the identity by definition) have a pose
    assert posed.sum() == 2 and posed[0, ref[0]] and posed[1, ref[1]]
    assert JOINT_STATUS[seg.joint_status[0]] == "few_frames"


def test_per_person_segments_and_joints():
    """Two people: one segment per (part, person), one joint per person, each exact."""
    rng = np.random.default_rng(6)
    traj, lab, inst, truth = _two_parts(rng, split=False, people=2)
    seg = compute_segments(traj, lab, LABELS, inst, SegmentsConfig(prior_deg=0.0))
    assert seg.num_segments == 4
    assert seg.segment_names() == [
        "person0/torso",
        "person1/torso",
        "person0/head",
        "person1/head",
    ] or sorted(seg.segment_names()) == sorted(
        ["person0/torso", "person1/torso", "person0/head", "person1/head"]
    )
    assert seg.joint_labels() == ["person0/neck", "person1/neck"]
    pos = seg.joint_positions()
    for p in range(2):
        np.testing.assert_allclose(pos[p], truth[p][2], atol=1e-6)
    # without instances the two people would be one rigid-fit mess: the joint then differs
    mixed = compute_segments(traj, lab, LABELS)
    assert mixed.num_segments == 2


def test_save_load_round_trip(tmp_path):
    rng = np.random.default_rng(7)
    traj, lab, _, _ = _two_parts(rng, T=15, n=20, split=False)
    seg = compute_segments(traj, lab, LABELS, config=SegmentsConfig(min_frames=5))
    path = tmp_path / "segments.npz"
    save_segments(seg, path)
    back = load_segments(path)
    assert back.class_names == seg.class_names and back.joint_names == seg.joint_names
    for name in ("rotation", "translation", "inliers", "residual", "joint_local", "joint_status"):
        a, b = getattr(seg, name), getattr(back, name)
        assert a.dtype == b.dtype
        np.testing.assert_array_equal(a, b)
    assert back.params["min_frames"] == 5 and back.fps == seg.fps


def test_bad_inputs_name_the_problem(tmp_path):
    rng = np.random.default_rng(8)
    traj, lab, _, _ = _two_parts(rng, T=10, n=10, split=False)
    with pytest.raises(ValidationError, match="labels"):
        compute_segments(traj, lab[:-1], LABELS)
    with pytest.raises(ValidationError, match="instance"):
        compute_segments(traj, lab, LABELS, instance=np.zeros(3, int))
    with pytest.raises(ValidationError, match="min_points"):
        SegmentsConfig(min_points=2)
    bad = tmp_path / "segments.npz"
    bad.write_bytes(b"not a zip")
    with pytest.raises(FileFormatError, match="segments.npz"):
        load_segments(bad)
    with pytest.raises(FileFormatError, match="no such file"):
        load_segments(tmp_path / "missing.npz")
    np.savez(tmp_path / "old.npz", format_version=np.int64(99))
    with pytest.raises(FileFormatError, match="old.npz"):
        load_segments(tmp_path / "old.npz")


def test_draw_segments_marks_joints_and_axes():
    """The overlay draws a yellow disc at the projected joint and the axes in their colours."""
    from pointtraj.render.overlay import AXIS_COLORS, JOINT_COLOR, draw_segments
    from pointtraj.synth.presets import make_rig

    rng = np.random.default_rng(9)
    traj, lab, _, truth = _two_parts(rng, T=20, n=30, split=False)
    traj.xyz = traj.xyz - np.array([0.0, 0.0, -0.2], np.float32)  # in front of the ring's cameras
    seg = compute_segments(traj, lab, LABELS, config=SegmentsConfig(min_frames=5))
    camera = make_rig("tiny4")[0]
    blank = np.full((camera.size[1], camera.size[0], 3), 255, np.uint8)
    t = 7
    out = draw_segments(blank, camera, seg, t, radius=3)
    assert out.shape == blank.shape and (blank == 255).all()  # the input is not modified
    joint = seg.joint_positions()[0, t]
    proj = camera.project(joint[None])
    u, v = np.rint(proj[0][0]).astype(int)
    np.testing.assert_array_equal(out[v, u], JOINT_COLOR)
    for color in AXIS_COLORS:  # every axis colour appears (anti-aliased lines: near it)
        assert (np.abs(out.astype(int) - color).sum(axis=2) < 60).any()
    # a frame without any pose draws nothing
    seg.rotation[:, t] = np.nan
    seg.translation[:, t] = np.nan
    assert (draw_segments(blank, camera, seg, t) == 255).all()


def test_segments_command_needs_labels(tmp_path):
    """``pointtraj segments`` on a work folder without labels.npz: one line naming it."""
    from click.testing import CliRunner

    from pointtraj.cli import main

    rng = np.random.default_rng(10)
    traj, _, _, _ = _two_parts(rng, T=5, n=5, split=False)
    work = tmp_path / "work"
    work.mkdir()
    traj.save(work / "trajectories.npz")
    res = CliRunner().invoke(main, ["segments", str(work)])
    assert res.exit_code == 1 and "Traceback" not in res.output
    assert "labels.npz" in res.output and "pointtraj label" in res.output


def test_parts_never_posed_together():
    """Regression: two parts with poses in disjoint frames made the joint's solve singular
    (LinAlgError in the tiny pipeline); the joint is now few_frames, NaN."""
    rng = np.random.default_rng(11)
    traj, lab, _, _ = _two_parts(rng, T=20, n=10, split=False)
    dense = traj.dense_positions()  # (M, T, 3)
    dense[lab == 0, 10:] = np.nan  # the torso only in frames 0-9
    dense[lab == 1, :10] = np.nan  # the head only in 10-19
    traj = Trajectories.from_dense(dense, camera_names=["a", "b"])
    seg = compute_segments(traj, lab, LABELS)
    assert seg.joint_frames[0] == 0
    assert JOINT_STATUS[seg.joint_status[0]] == "few_frames"
    assert np.isnan(seg.joint_local).all()


def test_uncertain_joint_is_nan():
    """Noisy points and little relative rotation: the centre's standard error is large, and
    above max_uncertainty the joint is NaN with status uncertain."""
    rng = np.random.default_rng(12)
    traj, lab, _, _ = _two_parts(rng, relative="ball", split=False)
    traj.xyz = traj.xyz + rng.normal(scale=0.003, size=traj.xyz.shape).astype(np.float32)
    seg = compute_segments(traj, lab, LABELS)
    assert JOINT_STATUS[seg.joint_status[0]] == "ball"
    err = float(seg.joint_uncertainty[0])
    assert 0 < err < 0.02
    seg = compute_segments(traj, lab, LABELS, config=SegmentsConfig(max_uncertainty=err / 2))
    assert JOINT_STATUS[seg.joint_status[0]] == "uncertain"
    assert np.isnan(seg.joint_positions()).all()
    np.testing.assert_allclose(seg.joint_uncertainty[0], err)  # still reported
