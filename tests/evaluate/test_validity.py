"""Predictive validity on held-out cameras."""

from __future__ import annotations

import numpy as np
import pytest
from helpers.rigs import ring_rig

from pointtraj.camera import Camera, CameraRig
from pointtraj.evaluate.validity import (
    CameraSamples,
    camera_counts,
    collect_camera_samples,
    predictive_validity,
)
from pointtraj.trajectories import Trajectories, quantize_visibility


def occluded_samples(C=12, M=300, T=4, K=3, occluded_fraction=0.6, seed=0) -> CameraSamples:
    """Each trajectory has a true class in {0, 1}; occluded cameras (V = 0) confidently see class 2."""
    rng = np.random.default_rng(seed)
    truth = rng.integers(0, 2, M)
    track = np.repeat(np.arange(M), T)
    frame = np.tile(np.arange(T), M)
    S = len(track)
    occluded = rng.random((M, C)) < occluded_fraction
    occ = occluded[track]  # (S, C)
    L = np.zeros((S, C, K), np.float32)
    L[np.arange(S)[:, None], np.arange(C)[None], np.where(occ, 2, truth[track][:, None])] = 0.9
    V = np.where(occ, 0.0, 1.0).astype(np.float32)
    observed = L.argmax(axis=2).astype(np.int16)
    return CameraSamples(
        track,
        frame,
        L.astype(np.float16),
        V,
        np.ones((S, C), bool),
        observed,
        [f"c{i}" for i in range(C)],
    )


def test_view_pooling_beats_average_under_occlusion():
    s = occluded_samples()
    res = predictive_validity(s, eps_e=0.1, counts=[1, 5, 11], draws=2)
    # Held-out cameras are evaluated only where the point is visible there, so the truth is
    # observed. The poolings are compared on the samples both label: view pooling labels a
    # track only where some other camera sees it (then rightly), average pooling always.
    held_out = np.unique(np.linspace(0, 11, 8).round().astype(int))
    average_hits = total = unlabelled = 0
    for h in held_out:
        evaluated = s.V[:, h] > 0.1
        seen = np.delete(s.V, h, axis=1) > 0.1  # (S, 11)
        # The unweighted mean is right only where the visible cameras outnumber the occluded.
        average_hits += np.sum(evaluated & (seen.sum(axis=1) > 11 / 2))
        total += np.sum(evaluated & seen.any(axis=1))
        unlabelled += np.sum(evaluated & ~seen.any(axis=1))
    assert unlabelled > 0  # the seed leaves a few tracks occluded everywhere else: left out
    assert res["view"][11] == pytest.approx(1.0)
    assert res["average"][11] == pytest.approx(average_hits / total)
    assert res["average"][11] < 0.3  # the occluder's label wins the unweighted mean


def test_predictive_validity_reports_its_support():
    """Issue #17: a figure computed on a few samples must say so."""
    s = occluded_samples()
    support: dict = {}
    res = predictive_validity(s, eps_e=0.1, counts=[1, 11], draws=2, support=support)
    assert set(support) == {1, 11}
    held_out = np.unique(np.linspace(0, 11, 8).round().astype(int))
    # With all 11 other cameras a sample is compared where the held-out camera sees it and
    # another camera does too (view pooling labels nothing else).
    seen = s.V > 0.1  # (S, C)
    compared = np.zeros(len(s.track), bool)
    comparisons = 0
    for h in held_out:
        ok = seen[:, h] & np.delete(seen, h, axis=1).any(axis=1)
        compared |= ok
        comparisons += int(ok.sum())
    assert support[11]["point_frames"] == compared.sum()
    assert support[11]["trajectories"] == len(np.unique(s.track[compared]))
    assert support[11]["comparisons"] == comparisons
    assert support[1]["point_frames"] <= support[11]["point_frames"]
    # The figures themselves do not change.
    assert res == predictive_validity(s, eps_e=0.1, counts=[1, 11], draws=2)


def test_camera_counts():
    assert camera_counts(2) == [1]
    assert camera_counts(12) == [1, 2, 5, 10, 11]


def test_collect_camera_samples_uses_the_recognizer():
    rig = ring_rig(angles=np.linspace(0, np.pi, 3), radius=2.0, size=(64, 48), focal=60.0)
    rng = np.random.default_rng(0)
    xyz = rng.normal(size=(50, 5, 3)) * 0.05 + [0, 0, 1]
    vis = np.ones((50, 5, 3))
    tr = Trajectories.from_dense(xyz, vis, camera_names=rig.names)
    assert tr.visibility.dtype == np.uint8 and tr.visibility.max() == quantize_visibility(1.0)

    def recognize(c, t):
        L = np.zeros((12, 16, 2), np.float32)
        L[..., c % 2] = 1.0  # camera c recognises class c % 2 everywhere
        return L

    s = collect_camera_samples(tr, rig, recognize, 2, max_tracks=20, frame_stride=2)
    assert len(np.unique(s.track)) == 20 and set(np.unique(s.frame)) == {0, 2, 4}
    assert s.L.shape == (len(s.track), 3, 2)
    np.testing.assert_array_equal(s.observed[:, 1], 1)
    np.testing.assert_array_equal(s.observed[:, 0], 0)
    # A reconstruction of frames 6:9 of a longer capture: frames before 6 hold no points.
    late = np.full((50, 9, 3), np.nan)
    late[:, 6:] = xyz[:, :3]
    cut = Trajectories.from_dense(late, np.ones((50, 9, 3)), camera_names=rig.names)
    assert cut.occupied_frames == range(6, 9) and cut.num_frames == 9
    s = collect_camera_samples(cut, rig, recognize, 2, frame_stride=2)
    assert set(np.unique(s.frame)) == {6, 8}


def test_collect_camera_samples_on_a_frame_cut():
    """Regression: with frames = "24:28" the stride ran over the whole capture from frame 0,
    sampled no frame with points, and the report skipped predictive validity."""
    cam = Camera.look_at("c0", [2, 0, 1], [0, 0, 1], (64, 48), 60.0)
    rig = CameraRig([cam, Camera.look_at("c1", [0, 2, 1], [0, 0, 1], (64, 48), 60.0)])
    xyz = np.full((5, 57, 3), np.nan)
    xyz[:, 24:28] = [0, 0, 1]
    cut = Trajectories.from_dense(xyz, np.ones((5, 57, 2)), camera_names=rig.names)
    assert Trajectories.from_dense(
        np.zeros((0, 3, 3)), camera_names=["a"]
    ).occupied_frames == range(0)
    s = collect_camera_samples(
        cut, rig, lambda c, t: np.ones((4, 4, 1), np.float32), 1, frame_stride=2
    )
    assert set(np.unique(s.frame)) == {24, 26}


def test_the_visible_camera_average_beside_the_papers_average():
    """``average_visible`` leaves the occluded cameras out, the paper's ``average`` keeps them;
    both rest on the same samples as view pooling (the support)."""
    s = occluded_samples()
    support: dict = {}
    both: dict = {}
    pools = ("view", "average", "average_visible")
    res = predictive_validity(
        s, eps_e=0.1, poolings=pools, counts=[1, 11], draws=2, support=support
    )
    paper = predictive_validity(s, eps_e=0.1, counts=[1, 11], draws=2, support=both)
    # Only visible cameras vote, and they all see the true class: always right.
    assert res["average_visible"][11] == pytest.approx(1.0)
    assert res["average"][11] == pytest.approx(paper["average"][11]) and res["average"][11] < 0.3
    # It labels what view pooling labels, so adding it compares the same samples.
    assert support == both and support[11]["comparisons"] > 0
