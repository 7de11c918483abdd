"""Re-acquiring lost views: a patch from the lost camera's last image of a point, searched by
NCC around the carried point's projection; the tracker gets the view back and keeps it in its
saved state."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from pointtraj.errors import FileFormatError
from pointtraj.reconstruct.config import ReconstructConfig
from pointtraj.reconstruct.framestore import FrameStore
from pointtraj.reconstruct.matching import MatchingConfig
from pointtraj.reconstruct.reacquire import LostViews, cut_patches, search_patches
from pointtraj.reconstruct.survive import SurviveConfig
from pointtraj.reconstruct.track import Tracker
from pointtraj.reconstruct.views import ViewsConfig


def _texture(shape=(240, 320), seed=0, sigma=1.5) -> np.ndarray:
    rng = np.random.default_rng(seed)
    im = gaussian_filter(rng.normal(0, 1, shape), sigma)
    return np.clip(128 + 60 * im / im.std(), 0, 255).astype(np.uint8)


def _shifted(image: np.ndarray, shift: tuple[float, float]) -> np.ndarray:
    M = np.float32([[1, 0, shift[0]], [0, 1, shift[1]]])
    return cv2.warpAffine(image, M, image.shape[::-1], flags=cv2.INTER_LINEAR)


@pytest.mark.parametrize("spacing", [1.0, 2.0, 4.0])
def test_a_patch_is_found_where_its_image_moved(spacing):
    a = _texture(sigma=spacing / 2)
    shift = (3.4, -2.3)
    b = _shifted(a, shift)
    rng = np.random.default_rng(1)
    pts = rng.uniform(50, [270, 190], (40, 2))
    patch, frac, ok = cut_patches(a, pts, spacing)
    assert ok.all() and np.all(np.abs(frac) <= 0.5)
    np.testing.assert_allclose(patch.mean(axis=1), 0, atol=1e-4)
    guess = pts - frac + np.array(shift) + rng.uniform(-2, 2, pts.shape)  # centres, roughly
    found, ncc = search_patches(b, patch, guess, spacing, 5, 0.8, 0.05)
    assert np.isfinite(found).all(axis=1).mean() >= 0.9
    err = np.linalg.norm(found + frac - (pts + shift), axis=1)
    assert np.nanmedian(err) < 0.2 and np.nanmax(err) < 0.6
    assert np.nanmin(ncc) > 0.8


def test_no_view_is_found_where_the_search_cannot_tell():
    a = _texture()
    pts = np.array([[100.0, 100.0], [160.0, 120.0], [3.0, 100.0], [np.nan, np.nan]])
    patch, frac, ok = cut_patches(a, pts, 2.0)
    assert ok.tolist() == [True, True, False, False]  # the third leaves the image
    # a flat image has nothing to compare
    flat = np.full_like(a, 90)
    found, _ = search_patches(flat, patch[:2], pts[:2], 2.0, 5, 0.8, 0.05)
    assert np.isnan(found).all()
    _, _, flat_ok = cut_patches(flat, pts[:2], 2.0)
    assert not flat_ok.any()
    # stripes 4 px apart repeat within the search: every peak has a rival as good
    x = np.arange(320)
    stripes = np.tile((128 + 80 * np.sin(2 * np.pi * x / 4.0)).astype(np.uint8), (240, 1))
    sp, _, sok = cut_patches(stripes, pts[:2], 1.0)
    assert sok.all()
    found, ncc = search_patches(stripes, sp, pts[:2] + 0.4, 1.0, 6, 0.8, 0.05)
    assert np.isnan(found).all() and np.all(ncc > 0.9)
    # a patch whose image is not within the radius is not found
    far, _ = search_patches(a, patch[:2], pts[:2] + 30.0, 2.0, 5, 0.8, 0.05)
    assert np.isnan(far).all()


def test_lost_views_by_trajectory_id():
    P = 49
    lv = LostViews(
        np.array([7, 3, 12]),
        np.array([0, 2, 1]),
        np.zeros((3, 2), np.float32),
        np.zeros((3, 2), np.float32),
        np.arange(3 * P, dtype=np.float32).reshape(3, P),
    )
    assert lv.lookup(np.array([3, 5, 12, 7])).tolist() == [1, -1, 2, 0]
    assert LostViews.empty().lookup(np.array([1])).tolist() == [-1]
    kept = lv.kept(np.array([12, 99]))
    assert kept.ids.tolist() == [12] and kept.camera.tolist() == [1]
    both = LostViews.concat([kept, lv.take(np.array([1]))])
    assert both.ids.tolist() == [12, 3] and both.patch.shape == (2, P)


@pytest.fixture(scope="module")
def banded(wide_rig):
    """The plane of test_survive's ``occluded_frames``: at frame 2 a black band hides part of
    it from cameras 1 and 2, for one frame."""
    from helpers.scenes import plane_frames

    frames = plane_frames(wide_rig, 5, seed=3, velocity=np.array([0.01, 0.0, 0.005]))
    for c in (1, 2):
        frames[2][c][:, 240:300] = 0
    return wide_rig, frames


def _without_discovery() -> ReconstructConfig:
    """The settings of test_survive's plane, without view discovery: only re-acquisition gives
    a carried point its view back."""
    return ReconstructConfig(
        matching=MatchingConfig(num_features=1500),
        max_angle_deg=130.0,
        min_views_new=2,
        lk_levels=1,  # keeps the black band's effect on the flow local
        views=ViewsConfig(enabled=False),
    )


def test_the_tracker_gets_a_lost_view_back_from_its_own_camera(banded, tmp_path):
    """Without view discovery, points that lost their second view under the band get it back
    the frame after from the patch of their lost camera; without re-acquisition they go on
    with one view until survival runs out."""
    rig, frames = banded
    base = _without_discovery()
    recs, states = {}, {}
    for on in (False, True):
        cfg = dataclasses.replace(base, survive=SurviveConfig(frames=3, reacquire=on))
        tracker = Tracker(rig, cfg)
        recs[on] = []
        for t, imgs in enumerate(frames):
            recs[on].append(tracker.step(t, imgs))
            if t == 2:
                states[on] = tracker.state
    # the points carried on one view at frame 2
    st = states[True]
    carried = st.ids[st.lone > 0]
    assert carried.size >= 10, carried.size
    # they keep the lost view's patch, one per point, and it survives the state file
    assert sorted(st.lost.ids.tolist()) == sorted(carried.tolist())
    assert set(st.lost.camera.tolist()) <= {1, 2}
    store = FrameStore(tmp_path, len(rig))
    store.write_live(st)
    back = store.read_live()
    for f in ("ids", "camera", "offset", "frac", "patch"):
        np.testing.assert_array_equal(getattr(back.lost, f), getattr(st.lost, f))
    # a state file whose lost views are malformed is refused, naming the file and the array
    good = dict(np.load(store.live_path))
    for key, value, what in (
        ("lost_patch", good["lost_patch"][:, :25], "live_lost_patch"),
        ("lost_camera", np.full_like(good["lost_camera"], len(rig)), "live_lost_camera"),
    ):
        np.savez(store.live_path, **{**good, key: value})
        with pytest.raises(FileFormatError, match=f"live.npz.*{what}"):
            store.read_live()

    def views_at(on: bool, t: int) -> np.ndarray:
        r = recs[on][t]
        sel = np.isin(r.ids, carried)
        return np.count_nonzero(r.visibility[sel] > 0.05 * 255, axis=1)

    with_it, without = views_at(True, 3), views_at(False, 3)
    assert np.mean(with_it >= 2) >= 0.8, np.mean(with_it >= 2)
    assert np.mean(without >= 2) == 0.0
    # back on the plane, where the point is at frame 3
    r3 = recs[True][3]
    sel = np.isin(r3.ids, carried) & (np.count_nonzero(r3.visibility > 0.05 * 255, axis=1) >= 2)
    assert np.median(np.abs(r3.xyz[sel, 2] - 3 * 0.005)) < 0.004


def test_the_ncc_map_is_the_ncc_of_every_patch():
    """The shifted-add NCC equals the NCC of each patch cut out and compared on its own."""
    from pointtraj.reconstruct.reacquire import PATCH_SIDE, _ncc_map

    rng = np.random.default_rng(4)
    s, G, k = 3, 5, PATCH_SIDE
    h = s * (k // 2)
    win = rng.uniform(0, 255, (3, G + 2 * h, G + 2 * h)).astype(np.float32)
    win[2] = 17.0  # flat: no NCC
    tmpl = rng.normal(0, 1, (3, k * k))
    tmpl = (tmpl - tmpl.mean(axis=1, keepdims=True)) / tmpl.std(axis=1, keepdims=True)
    got = _ncc_map(win, tmpl.reshape(3, k, k).astype(np.float32), s, G)
    for n in range(2):
        for y in range(G):
            for x in range(G):
                patch = win[n, y : y + 2 * h + 1 : s, x : x + 2 * h + 1 : s].ravel()
                want = np.corrcoef(patch, tmpl[n])[0, 1]
                assert got[n, y, x] == pytest.approx(want, abs=1e-4)
    assert np.all(got[2] == -1.0)


def test_a_tracker_resumed_with_lost_views_continues_as_one_run(banded, tmp_path):
    """A tracker resumed from the saved state of a frame with carried points gets the same
    views back, and the same records, as the tracker that went on."""
    rig, frames = banded
    cfg = _without_discovery()
    whole = Tracker(rig, cfg)
    recs = [whole.step(t, imgs) for t, imgs in enumerate(frames[:3])]
    assert len(whole.state.lost) >= 10
    store = FrameStore(tmp_path, len(rig))
    store.write_live(whole.state)
    resumed = Tracker(rig, cfg, state=store.read_live(), first_frame=0)
    resumed.set_previous_images(frames[2])
    after = {}
    for t in (3, 4):
        a, b = whole.step(t, frames[t]), resumed.step(t, frames[t])
        for f in ("ids", "xyz", "visibility", "error"):
            np.testing.assert_array_equal(getattr(a, f), getattr(b, f))
        after[t] = a
    # without the saved patches the resumed tracker does not get the views back
    bare = store.read_live()
    carried = bare.ids[bare.lone > 0]
    bare.lost = LostViews.empty()
    blind = Tracker(rig, cfg, state=bare, first_frame=0)
    blind.set_previous_images(frames[2])

    def two_views(rec) -> int:
        sel = np.isin(rec.ids, carried)
        return int(np.sum(np.count_nonzero(rec.visibility[sel] > 0.05 * 255, axis=1) >= 2))

    assert two_views(after[3]) >= 10
    assert two_views(blind.step(3, frames[3])) == 0
    assert len(recs) == 3
