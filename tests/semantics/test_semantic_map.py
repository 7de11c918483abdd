"""Tests of pointtraj.semantics.semantic_map: streaming L3D construction, file format."""

from __future__ import annotations

import numpy as np
import pytest
from helpers.rigs import ring_rig

from pointtraj.errors import FileFormatError, ValidationError
from pointtraj.semantics.pooling import pool_views
from pointtraj.semantics.recognizers.base import ImageContext, Recognizer
from pointtraj.semantics.recognizers.precomputed import (
    PrecomputedRecognizer,
    save_confidence_map,
)
from pointtraj.semantics.sampling import sample_confidences
from pointtraj.semantics.semantic_map import (
    SemanticMap,
    SemanticsConfig,
    build_semantic_map,
    geometric_visibility,
    normalized_correlation,
)
from pointtraj.trajectories import Trajectories

W, H, DS = 160, 128, 4
CLASSES = ("left", "right", "other")


def make_scene(seed=0, M=240, T=7):
    """Points on two spheres (class 0 and 1) drifting in x, seen by a ring of 8 cameras.

    Visibility is 1 where the sphere's surface faces the camera and the point is in the image.
    Some trajectories are fragments (start late or end early); the last frame has no points.
    """
    rng = np.random.default_rng(seed)
    rig = ring_rig(
        angles=np.linspace(0, 2 * np.pi, 8, endpoint=False),
        size=(W, H),
        focal=140.0,
        heights=(1.2,),
        names="cam{i}",
    )
    label = np.arange(M) % 2
    normal = rng.normal(size=(M, 3))
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    centres = np.where(label[:, None] == 0, [-0.45, 0.0, 1.0], [0.45, 0.0, 1.0])
    xyz = np.full((M, T, 3), np.nan)
    vis = np.zeros((M, T, len(rig)))
    first = rng.integers(0, 3, M)
    last = rng.integers(3, T - 1, M)
    for t in range(T):
        X = centres + 0.3 * normal + [0.03 * t, 0, 0]  # (M, 3)
        alive = (first <= t) & (t <= last)
        proj = rig.project(X)
        facing = np.einsum("mi,cmi->cm", normal, rig.C[:, None] - X[None]) > 0  # (C, M)
        v = (facing & proj.in_image).T.astype(float)
        xyz[alive, t] = X[alive]
        vis[alive, t] = v[alive]
    traj = Trajectories.from_dense(xyz, vis, camera_names=rig.names, fps=30.0)
    return rig, traj, label


class RasterRecognizer(Recognizer):
    """Paints each visible point's class into a coarse map (a real, if simple, recogniser).

    Cameras in ``swap`` report class 0 as 1 and 1 as 0 (a confident wrong view).
    """

    name = "raster"

    def __init__(self, rig, traj, label, swap=()):
        self.rig, self.traj, self.label, self.swap = rig, traj, label, set(swap)
        self.class_names = CLASSES
        self.calls = []

    def recognize(self, image, context=None):
        import cv2

        self.calls.append((context.camera, context.frame))
        c = self.rig.index(context.camera)
        fs = self.traj.frame(context.frame)
        lab = self.label[fs.track_id]
        if c in self.swap:
            lab = 1 - lab
        seen = fs.visibility[:, c] > 0.5
        px = self.rig.project(fs.xyz[seen]).pixels[c]
        h, w = H // DS, W // DS
        cell = (np.clip(px[:, 1] // DS, 0, h - 1) * w + np.clip(px[:, 0] // DS, 0, w - 1)).astype(
            int
        )
        counts = np.zeros((h * w, len(CLASSES)), np.float32)
        np.add.at(counts, (cell, lab[seen]), 1.0)
        frac = counts / np.maximum(counts.sum(1, keepdims=True), 1)
        frac = cv2.dilate(frac.reshape(h, w, -1), np.ones((3, 3), np.uint8))
        frac[..., 2] = 0.05
        return frac.astype(np.float16).astype(np.float32)  # exactly representable in files


class FakeCapture:
    """The part of ``pointtraj.session.Capture`` the semantic map uses, with blank images."""

    def __init__(self, rig):
        self.rig = rig
        self.path = None
        self.reads = 0

    def read(self, camera, frame):
        self.reads += 1
        return np.zeros((H, W, 3), np.uint8)


def brute_force(rig, traj, recognizer, pooling, eps=0.1, config=None):
    """L3D and per-point-frame pooled rows, computed point-frame by point-frame."""
    M, K = len(traj), len(CLASSES)
    rows = np.full((traj.num_point_frames, K), np.nan, np.float32)
    for t in range(traj.num_frames):
        fs = traj.frame(t)
        if len(fs.rows) == 0:
            continue
        proj = rig.project(fs.xyz)
        L = np.stack(
            [
                sample_confidences(
                    recognizer.recognize(None, ImageContext(name, t)),
                    np.where(proj.in_image[c][:, None], proj.pixels[c], np.nan),
                    (W, H),
                )
                for c, name in enumerate(rig.names)
            ]
        )
        V = fs.visibility
        if config is not None and config.visibility == "geometric":
            V = geometric_visibility(rig, fs.xyz, V, config)
        rows[fs.rows] = pool_views(L, V, eps, pooling, in_image=proj.in_image)
    L3D = np.zeros((M, K), np.float32)
    count = np.zeros(M, int)
    for m in range(M):
        r = rows[traj.offsets[m] : traj.offsets[m + 1]]
        r = r[np.isfinite(r).all(1)]
        count[m] = len(r)
        if len(r):
            L3D[m] = r.mean(0)
    return L3D, count, rows


@pytest.fixture(scope="module")
def scene():
    return make_scene()


@pytest.mark.parametrize("visibility", ["observed", "geometric"])
def test_streaming_map_equals_brute_force(scene, visibility):
    rig, traj, label = scene
    rec = RasterRecognizer(rig, traj, label)
    cap = FakeCapture(rig)
    cfg = SemanticsConfig(chunk_size=37, visibility=visibility)
    smap = build_semantic_map(cap, traj, rec, config=cfg)
    assert smap.class_names == CLASSES and smap.poolings == ("view", "average")
    assert cap.reads == len(rec.calls)  # one image read per recognition
    frames_with_points = [t for t in range(traj.num_frames) if len(traj.frame_rows(t))]
    assert sorted(rec.calls) == sorted((n, t) for n in rig.names for t in frames_with_points)
    for p in ("view", "average"):
        L3D, count, rows = brute_force(rig, traj, RasterRecognizer(rig, traj, label), p, config=cfg)
        np.testing.assert_array_equal(smap.count[p], count)
        np.testing.assert_allclose(smap.L3D[p], L3D, atol=1e-5)
        # Every trajectory's per-frame samples are kept (they fit the budget).
        np.testing.assert_array_equal(smap.sample_tracks, np.arange(len(traj)))
        np.testing.assert_allclose(smap.samples[p], rows, atol=1e-6)
    seen = smap.count["view"] > 0
    assert seen.mean() > 0.9
    np.testing.assert_array_equal(smap.argmax_labels("view")[seen], label[seen])
    assert (smap.argmax_labels("view")[~seen] == -1).all()


def test_view_pooling_survives_confident_wrong_views(scene):
    rig, traj, label = scene
    rec = RasterRecognizer(rig, traj, label, swap=(0,))
    smap = build_semantic_map(FakeCapture(rig), traj, rec)
    seen = smap.count["view"] > 0
    view_acc = np.mean(smap.argmax_labels("view")[seen] == label[seen])
    assert view_acc > 0.98  # only ties between two visible cameras can go wrong


class BlindRecognizer(RasterRecognizer):
    """Reports no class anywhere in the cameras of ``blind`` (as a camera seeing only background)."""

    def __init__(self, *args, blind=(), **kwargs):
        super().__init__(*args, **kwargs)
        self.blind = set(blind)

    def recognize(self, image, context=None):
        out = super().recognize(image, context)
        return np.zeros_like(out) if self.rig.index(context.camera) in self.blind else out


def test_background_vote_pools_points_most_cameras_see_as_background(scene):
    from pointtraj.semantics.semantic_map import NOTHING_CONFIDENCE

    rig, traj, label = scene
    blind = (0, 1, 2)
    cfg = SemanticsConfig(visibility="observed")
    off = build_semantic_map(
        FakeCapture(rig), traj, BlindRecognizer(rig, traj, label, blind=blind), config=cfg
    )
    vote = SemanticsConfig(visibility="observed", background_vote=0.5)
    on = build_semantic_map(
        FakeCapture(rig), traj, BlindRecognizer(rig, traj, label, blind=blind), config=vote
    )
    # brute force: which point-frames do half or more of their cameras see as background?
    rec = BlindRecognizer(rig, traj, label, blind=blind)
    nothing = np.zeros(traj.num_point_frames, bool)
    for t in range(traj.num_frames):
        fs = traj.frame(t)
        if len(fs.rows) == 0:
            continue
        proj = rig.project(fs.xyz)
        cams = proj.in_image.T & (fs.visibility > cfg.eps_e)  # (n, C)
        top = np.stack(
            [
                sample_confidences(
                    rec.recognize(None, ImageContext(name, t)), proj.pixels[c], (W, H)
                ).max(axis=1)
                for c, name in enumerate(rig.names)
            ],
            axis=1,
        )  # (n, C)
        blank = cams & (top < NOTHING_CONFIDENCE)
        nothing[fs.rows] = (cams.sum(1) > 0) & (blank.sum(1) >= 0.5 * cams.sum(1))
    assert 0.1 < nothing.mean() < 0.9  # both kinds occur
    for p in ("view", "average"):
        expected = np.where(nothing[:, None], 0.0, off.samples[p])
        np.testing.assert_allclose(on.samples[p], expected, atol=1e-6)
        np.testing.assert_array_equal(on.count[p], off.count[p])  # zeros still count
    # the vote lowers L3D exactly where some frames were voted background
    voted = np.bincount(traj.row_track[nothing], minlength=len(traj)) > 0
    for p in ("view", "average"):
        np.testing.assert_allclose(on.L3D[p][~voted], off.L3D[p][~voted], atol=1e-6)
        assert (on.L3D[p].sum(1) <= off.L3D[p].sum(1) + 1e-6).all()
    lower = on.L3D["average"].sum(1) < off.L3D["average"].sum(1) - 1e-6
    assert lower[voted].all()  # the average of a voted frame's cameras was not zero
    with pytest.raises(ValidationError, match="background_vote"):
        SemanticsConfig(background_vote=1.5)


def test_chunking_and_view_only_do_not_change_the_result(scene):
    rig, traj, label = scene
    a = build_semantic_map(FakeCapture(rig), traj, RasterRecognizer(rig, traj, label))
    b = build_semantic_map(
        FakeCapture(rig),
        traj,
        RasterRecognizer(rig, traj, label),
        poolings=("view",),
        config=SemanticsConfig(chunk_size=5),
    )
    np.testing.assert_allclose(b.L3D["view"], a.L3D["view"], atol=1e-6)
    np.testing.assert_array_equal(b.count["view"], a.count["view"])


def test_sample_budget_limits_sampled_trajectories(scene):
    rig, traj, label = scene
    budget_mb = 40 * 4 * len(CLASSES) * 2 / 2**20  # room for about 40 point-frames
    smap = build_semantic_map(
        FakeCapture(rig),
        traj,
        RasterRecognizer(rig, traj, label),
        config=SemanticsConfig(sample_budget_mb=budget_mb, seed=3),
    )
    S = len(smap.sample_tracks)
    assert 0 < S < len(traj) and smap.sample_offsets[-1] <= 40
    assert np.all(np.diff(smap.sample_tracks) > 0)
    np.testing.assert_array_equal(np.diff(smap.sample_offsets), traj.lengths[smap.sample_tracks])
    np.testing.assert_array_equal(smap.sample_first_frame, traj.first_frame[smap.sample_tracks])


def test_temporal_consistency_and_nc(scene):
    rig, traj, label = scene
    smap = build_semantic_map(FakeCapture(rig), traj, RasterRecognizer(rig, traj, label))
    mean, std, n2 = smap.temporal_consistency(2, "view")
    assert n2 > 50 and mean > 0.9
    mean, _, n = smap.temporal_consistency(100, "view")
    assert n == 0 and np.isnan(mean)
    # restricted to a subset of the trajectories: the count follows the mask
    mask = np.zeros(len(traj), bool)
    mask[smap.sample_tracks[::2]] = True
    _, _, n_half = smap.temporal_consistency(2, "view", mask)
    _, _, n_all = smap.temporal_consistency(2, "view", np.ones(len(traj), bool))
    assert n_all == n2 and 0 < n_half < n2
    # the per-trajectory values behind the mean: each trajectory's first sample against lag 2
    tracks, values = smap.first_frame_nc(2, "view")
    assert len(tracks) == n2
    assert values.mean() == pytest.approx(smap.temporal_consistency(2, "view")[0])
    np.testing.assert_array_equal(smap.sample_tracks, np.arange(len(traj)))  # all sampled
    for m, v in zip(tracks[:5], values[:5], strict=True):
        first = smap.sample_offsets[m]
        rows = smap.samples["view"][[first, first + 2]]
        assert v == pytest.approx(normalized_correlation(rows[:1], rows[1:])[0])
    assert smap.temporal_consistency(2, "view", np.zeros(len(traj), bool))[2] == 0
    with pytest.raises(ValidationError, match="trajectories"):
        smap.temporal_consistency(2, "view", mask[:1])
    nc = normalized_correlation(
        np.array([[1.0, 2, 3], [1, 1, 1]]), np.array([[2.0, 4, 6], [1, 2, 3]])
    )
    assert nc[0] == pytest.approx(1.0) and np.isnan(nc[1])


def test_normalized_correlation_properties():
    rng = np.random.default_rng(0)
    a = rng.random((50, 8))
    np.testing.assert_allclose(normalized_correlation(a, a), 1.0)
    np.testing.assert_allclose(normalized_correlation(a, 3 * a + 1), 1.0)
    np.testing.assert_allclose(normalized_correlation(a, -a), -1.0)
    ref = np.array([np.corrcoef(x, y)[0, 1] for x, y in zip(a, a[::-1])])
    np.testing.assert_allclose(normalized_correlation(a, a[::-1]), ref)
    assert np.isnan(normalized_correlation(np.ones((1, 3)), a[:1, :3]))[0]


def test_temporal_consistency_lags():
    """Hand-made samples: NC per lag, a missing sample left out, trajectories too short."""
    # Trajectory 0: constant confidences for 10 frames -> NC 1 at every lag it reaches.
    # Trajectory 1: switches to an anti-correlated vector after 2 frames.
    v = np.array([1.0, 0.0, 0.0, 0.0])
    w = np.array([0.0, 1.0, 1.0, 1.0])
    pooled = np.r_[np.tile(v, (10, 1)), np.tile(v, (2, 1)), np.tile(w, (4, 1))]
    pooled[13] = np.nan  # a missing sample (trajectory 1, lag 3)
    smap = SemanticMap(
        class_names=("a", "b", "c", "d"),
        L3D={"view": np.zeros((2, 4), np.float32)},
        count={"view": np.zeros(2, np.int32)},
        sample_tracks=np.array([0, 1]),
        sample_offsets=np.array([0, 10, 16]),
        sample_first_frame=np.array([0, 3]),
        samples={"view": pooled.astype(np.float32)},
    )
    assert smap.temporal_consistency(2) == pytest.approx((0.0, 1.0, 2))
    assert smap.temporal_consistency(3) == (1.0, 0.0, 1)  # trajectory 1's sample is missing
    assert smap.temporal_consistency(4)[2] == 2
    assert smap.temporal_consistency(8) == (1.0, 0.0, 1)  # only trajectory 0 lives 9 frames
    mean, _, n = smap.temporal_consistency(10)
    assert n == 0 and np.isnan(mean)
    tracks, nc = smap.first_frame_nc(2)
    assert tracks.tolist() == [0, 1]
    np.testing.assert_allclose(nc, [1.0, -1.0])


def test_save_load_round_trip(scene, tmp_path):
    rig, traj, label = scene
    smap = build_semantic_map(FakeCapture(rig), traj, RasterRecognizer(rig, traj, label))
    assert smap.recognizer_options == {}
    smap.recognizer_options = {"noise": "low", "downsample": 2}
    path = tmp_path / "semantic_map.npz"
    smap.save(path)
    back = SemanticMap.load(path)
    assert back.recognizer_options == {"noise": "low", "downsample": 2}
    assert back.class_names == smap.class_names and back.poolings == smap.poolings
    assert back.recognizer == "raster" and back.eps_e == smap.eps_e and back.fps == 30.0
    for p in smap.poolings:
        np.testing.assert_array_equal(back.L3D[p], smap.L3D[p])
        np.testing.assert_array_equal(back.count[p], smap.count[p])
        np.testing.assert_array_equal(back.samples[p], smap.samples[p])
    np.testing.assert_array_equal(back.sample_offsets, smap.sample_offsets)
    np.testing.assert_array_equal(back.confidences, smap.L3D["view"])
    with np.load(path) as data:
        arrays = {k: data[k] for k in data.files if k != "L3D_view"}
    np.savez(tmp_path / "broken.npz", **arrays)
    with pytest.raises(FileFormatError, match="missing array 'L3D_view'"):
        SemanticMap.load(tmp_path / "broken.npz")
    with pytest.raises(FileFormatError, match="no such file"):
        SemanticMap.load(tmp_path / "none.npz")


def test_precomputed_maps_give_the_same_map(scene, tmp_path):
    rig, traj, label = scene
    rec = RasterRecognizer(rig, traj, label)
    for t in range(traj.num_frames):
        for name in rig.names:
            save_confidence_map(tmp_path, name, t, rec.recognize(None, ImageContext(name, t)))
    direct = build_semantic_map(FakeCapture(rig), traj, rec)
    pre = build_semantic_map(FakeCapture(rig), traj, PrecomputedRecognizer(CLASSES, tmp_path))
    for p in direct.poolings:
        np.testing.assert_allclose(pre.L3D[p], direct.L3D[p], atol=2e-3)
    # Errors: missing map, wrong K, missing array.
    with pytest.raises(FileFormatError, match="missing confidence map of camera 'cam0' frame 99"):
        PrecomputedRecognizer(CLASSES, tmp_path).recognize(None, ImageContext("cam0", 99))
    with pytest.raises(FileFormatError, match=r"expected shape \(h, w, 2\)"):
        PrecomputedRecognizer(CLASSES[:2], tmp_path).recognize(None, ImageContext("cam0", 0))
    np.savez(tmp_path / "cam0" / "000050.npz", other=np.zeros((2, 2, 3)))
    with pytest.raises(FileFormatError, match="missing array 'L2D'"):
        PrecomputedRecognizer(CLASSES, tmp_path).recognize(None, ImageContext("cam0", 50))
    np.save(tmp_path / "cam0" / "000051.npy", np.ones((2, 2, 3), np.float32))
    out = PrecomputedRecognizer(CLASSES, tmp_path).recognize(None, ImageContext("cam0", 51))
    assert out.shape == (2, 2, 3) and out.dtype == np.float32
    with pytest.raises(FileFormatError, match="no such folder"):
        PrecomputedRecognizer(CLASSES, tmp_path / "nope")


def test_errors(scene):
    rig, traj, label = scene
    small = rig.subset(rig.names[:4])
    with pytest.raises(ValidationError, match="camera 'cam4' is not in the capture's rig"):
        build_semantic_map(FakeCapture(small), traj, RasterRecognizer(rig, traj, label))

    class Wrong(RasterRecognizer):
        def recognize(self, image, context=None):
            return super().recognize(image, context)[..., :2]

    with pytest.raises(ValidationError, match=r"expected \(h, w, 3\)"):
        build_semantic_map(FakeCapture(rig), traj, Wrong(rig, traj, label))
    with pytest.raises(ValidationError, match="poolings: unknown 'median'"):
        SemanticsConfig(poolings=("median",))
    with pytest.raises(ValidationError, match="eps_e"):
        SemanticsConfig(eps_e=1.5)


def test_frame_subset_and_progress(scene, capsys):
    rig, traj, label = scene
    rec = RasterRecognizer(rig, traj, label)
    calls = []
    smap = build_semantic_map(
        FakeCapture(rig), traj, rec, frames=range(2, 4), progress=lambda *a: calls.append(a)
    )
    assert calls == [("semantic map", 0, 2), ("semantic map", 1, 2), ("semantic map", 2, 2)]
    assert {t for _, t in rec.calls} == {2, 3}
    alive = (traj.first_frame <= 3) & (traj.last_frame >= 2)
    expected = np.minimum(traj.last_frame, 3) - np.maximum(traj.first_frame, 2) + 1
    assert (smap.count["average"][~alive] == 0).all()
    assert (smap.count["average"][alive] <= expected[alive]).all()
    assert smap.count["average"][alive].sum() > 0.9 * expected[alive].sum()


class PeopleRecognizer(RasterRecognizer):
    """Also paints a person-id map: sphere k is person k, numbered the other way round in the
    odd cameras (person ids are per image)."""

    def recognize_people(self, image, context=None):
        L2D = self.recognize(image, context)
        c = self.rig.index(context.camera)
        people = np.where(L2D[..., :2].max(axis=2) > 0, L2D[..., :2].argmax(axis=2), -1)
        if c % 2:
            people = np.where(people >= 0, 1 - people, -1)
        return L2D, people.astype(np.int16)


def test_person_votes_sample_the_person_masks(scene, tmp_path):
    rig, traj, label = scene
    cfg = SemanticsConfig(visibility="observed")
    smap = build_semantic_map(
        FakeCapture(rig), traj, PeopleRecognizer(rig, traj, label), config=cfg
    )
    votes = smap.person_votes
    assert votes.dtype == np.int32 and votes.ndim == 2 and votes.shape[1] == 3 and len(votes)
    track, image, person = votes.T.astype(np.int64)
    frame, cam = image // len(rig), image % len(rig)
    expected = np.where(cam % 2 == 1, 1 - label[track], label[track])
    assert (person == expected).mean() > 0.8  # the spheres overlap in some views
    # exactly the visible point-frames inside the image and a mask, with the nearest cell's id
    rec = PeopleRecognizer(rig, traj, label)
    for t in range(traj.num_frames):
        fs = traj.frame(t)
        if not len(fs.rows):
            continue
        proj = rig.project(fs.xyz)
        for c, name in enumerate(rig.names):
            ids = rec.recognize_people(None, ImageContext(name, t))[1]
            h, w = ids.shape
            px = proj.pixels[c]
            x = np.clip(np.rint((px[:, 0] + 0.5) * w / W - 0.5), 0, w - 1).astype(int)
            y = np.clip(np.rint((px[:, 1] + 0.5) * h / H - 0.5), 0, h - 1).astype(int)
            pid = np.where(proj.in_image[c] & (fs.visibility[:, c] > cfg.eps_e), ids[y, x], -1)
            sel = (frame == t) & (cam == c)
            got = dict(zip(track[sel].tolist(), person[sel].tolist()))
            want = {int(m): int(p) for m, p in zip(fs.track_id, pid) if p >= 0}
            assert got == want
    smap.save(tmp_path / "semantic_map.npz")
    np.testing.assert_array_equal(
        SemanticMap.load(tmp_path / "semantic_map.npz").person_votes, votes
    )
    # a recogniser without person masks, or a zero budget: no votes
    plain = build_semantic_map(FakeCapture(rig), traj, RasterRecognizer(rig, traj, label))
    assert plain.person_votes.shape == (0, 3)
    none = build_semantic_map(
        FakeCapture(rig),
        traj,
        PeopleRecognizer(rig, traj, label),
        config=SemanticsConfig(visibility="observed", person_budget_mb=0),
    )
    assert none.person_votes.shape == (0, 3)
    # a tight budget keeps every s-th frame's votes
    tight = build_semantic_map(
        FakeCapture(rig),
        traj,
        PeopleRecognizer(rig, traj, label),
        config=SemanticsConfig(visibility="observed", person_budget_mb=1e-3),
    )
    stride = int(np.ceil(12.0 * traj.num_point_frames * len(rig) / (1e-3 * 2**20)))
    assert stride > 1
    kept = tight.person_votes[:, 1] // len(rig)
    assert len(tight.person_votes) and (kept % stride == 0).all()


class CameraClassRecognizer(Recognizer):
    """Reports one class over the whole image of each camera: ``classes[camera index]``."""

    name = "camera-class"
    needs_image = False

    def __init__(self, rig, classes):
        self.rig, self.classes = rig, list(classes)
        self.class_names = CLASSES

    def recognize(self, image, context=None):
        out = np.zeros((H // DS, W // DS, len(CLASSES)), np.float32)
        out[..., self.classes[self.rig.index(context.camera)]] = 1.0
        return out


def test_all_camera_average_includes_occluded_cameras_and_visible_average_does_not():
    """The paper's average (``average``) against ours over the visible cameras.

    A point P at (0, 0, 1) is seen by cameras 0 and 3, hidden in camera 1 behind a point Q
    0.4 m in front of it, and falls outside camera 2's image (in front of it, 72 degrees off
    its axis). Each camera reports one class everywhere: 0, 1, 2, 0.
    """
    from pointtraj.camera import Camera, CameraRig

    P, Q = (0.0, 0.0, 1.0), (0.0, 0.4, 1.0)
    cams = [
        Camera.look_at("cam0", (3.0, 0.0, 1.0), P, (W, H), 140.0),
        Camera.look_at("cam1", (0.0, 3.0, 1.0), P, (W, H), 140.0),
        Camera.look_at("cam2", (-3.0, 0.0, 1.0), (-2.0, 3.0, 1.0), (W, H), 140.0),
        Camera.look_at("cam3", (0.0, -3.0, 1.0), P, (W, H), 140.0),
    ]
    rig = CameraRig(cams)
    xyz = np.array([[P, P], [Q, Q]], float)  # (M=2, T=2, 3)
    proj = rig.project(xyz[:, 0])
    assert proj.in_image[:, 0].tolist() == [True, True, False, True]  # P outside camera 2
    vis = np.zeros((2, 2, 4))
    vis[0, :, [0, 3]] = 1.0  # P observed in cameras 0 and 3 only
    vis[1, :, [1, 3]] = 1.0
    traj = Trajectories.from_dense(xyz, vis, camera_names=rig.names, fps=30.0)
    config = SemanticsConfig(poolings=("view", "average", "average_visible"))
    # The occlusion test of geometric visibility finds P hidden in camera 1: V stays 0 there.
    V = geometric_visibility(rig, xyz[:, 0], vis[:, 0], config)
    assert V[0].tolist() == [1.0, 0.0, 0.0, 1.0]
    rec = CameraClassRecognizer(rig, [0, 1, 2, 0])
    smap = build_semantic_map(FakeCapture(rig), traj, rec, config=config)
    # The paper's average: cameras 0, 1 (occluded: it sees Q there) and 3; not camera 2.
    np.testing.assert_allclose(smap.L3D["average"][0], [2 / 3, 1 / 3, 0.0], atol=1e-6)
    # The visible-camera average leaves the occluded camera out: cameras 0 and 3.
    np.testing.assert_allclose(smap.L3D["average_visible"][0], [1.0, 0.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(smap.L3D["view"][0], [1.0, 0.0, 0.0], atol=1e-6)
    # Neither ever uses camera 2, where P is outside the image.
    assert smap.L3D["average"][0, 2] == 0 and smap.L3D["average_visible"][0, 2] == 0
