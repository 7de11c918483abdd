"""Dense matching: ORB grid features, GMS + epipolar filtering, multi-view tracks."""

from __future__ import annotations

import numpy as np
import pytest
from helpers.rigs import plane_rig
from helpers.scenes import plane_images

from pointtraj.camera import CameraRig
from pointtraj.errors import ValidationError
from pointtraj.reconstruct.matching import (
    Features,
    MatchingConfig,
    MultiViewTracks,
    build_tracks,
    detect_features,
    epipolar_distances,
    hamming_nearest,
    match_frame,
    match_pair,
    near_pixels,
    resolve_ambiguous,
    without_near,
)


def ray_plane_points(rig: CameraRig, obs: np.ndarray, z: float = 0.0) -> np.ndarray:
    """(C, N, 3) intersections of the observations' rays with the plane ``z``."""
    o, d = rig.rays(np.nan_to_num(obs))
    lam = (z - o[..., 2]) / d[..., 2]
    X = o + lam[..., None] * d
    X[np.isnan(obs[..., 0])] = np.nan
    return X


@pytest.fixture(scope="module")
def plane_scene(narrow_rig):
    return narrow_rig, plane_images(narrow_rig, seed=3)


def test_detect_features_spread_and_shapes(plane_scene):
    rig, images = plane_scene
    cfg = MatchingConfig(num_features=1200, grid_cells=(6, 4))
    f = detect_features(images[0], cfg)
    assert isinstance(f, Features)
    assert 0.5 * cfg.num_features < len(f) <= cfg.num_features + 24
    assert f.pixels.shape == (len(f), 2) and f.descriptors.shape == (len(f), 32)
    assert f.descriptors.dtype == np.uint8 and f.size == (480, 360)
    # grid spreading: no cell holds more than its share
    cx = (f.pixels[:, 0] * 6 / 480).astype(int)
    cy = (f.pixels[:, 1] * 4 / 360).astype(int)
    assert np.bincount(cy * 6 + cx).max() <= int(np.ceil(1200 / 24))
    # blank image: no features, right shapes
    blank = detect_features(np.zeros((100, 120, 3), np.uint8), cfg)
    assert len(blank) == 0 and blank.descriptors.shape == (0, 32)


def test_detect_features_rejects_bad_images():
    with pytest.raises(ValidationError, match="uint8"):
        detect_features(np.zeros((10, 10, 3), np.float32))
    with pytest.raises(ValidationError, match="image"):
        detect_features(np.zeros((10, 10, 4), np.uint8))


def test_config_rejects_bad_values():
    with pytest.raises(ValidationError, match="num_features"):
        MatchingConfig(num_features=1)
    with pytest.raises(ValidationError, match="grid_cells"):
        MatchingConfig(grid_cells=(0, 3))


def test_epipolar_distance_zero_for_true_correspondences_with_distortion():
    rng = np.random.default_rng(0)
    rig = plane_rig(2, dist=[-0.2, 0.05, 0.001, -0.001, 0.0])
    X = rng.uniform(-0.5, 0.5, (50, 3))
    pix = rig.project(X).pixels
    d = epipolar_distances(rig, 0, 1, pix[0], pix[1])
    assert d.shape == (50,)
    np.testing.assert_allclose(d, 0.0, atol=1e-6)
    # moving the point in image 1 along y (across the mostly horizontal epipolar lines)
    moved = pix[1] + [0.0, 5.0]
    assert np.all(epipolar_distances(rig, 0, 1, pix[0], moved) > 2.0)
    # symmetric in the camera order
    np.testing.assert_allclose(
        epipolar_distances(rig, 1, 0, moved, pix[0]),
        epipolar_distances(rig, 0, 1, pix[0], moved),
        rtol=1e-9,
    )


def test_match_pair_is_geometrically_correct(plane_scene):
    rig, images = plane_scene
    cfg = MatchingConfig(num_features=2000)
    fa, fb = detect_features(images[0], cfg), detect_features(images[1], cfg)
    pairs = match_pair(rig, 0, 1, fa, fb, cfg)
    assert pairs.ndim == 2 and pairs.shape[1] == 2 and len(pairs) > 300
    obs = np.full((3, len(pairs), 2), np.nan)
    obs[0], obs[1] = fa.pixels[pairs[:, 0]], fb.pixels[pairs[:, 1]]
    X = ray_plane_points(rig, obs)
    gap = np.linalg.norm(X[0] - X[1], axis=1)
    # 1 px is about 5 mm on the plane here; nearly all matches land on the same plane point
    assert np.median(gap) < 0.005
    assert np.mean(gap < 0.02) > 0.97


@pytest.mark.parametrize("cross_check", [False, True])
def test_hamming_nearest_answers_as_opencvs_brute_force_matcher(plane_scene, cross_check):
    """The same pairs and distances as cv2.BFMatcher, the first of equally near ones included."""
    import cv2

    rig, images = plane_scene
    cfg = MatchingConfig(num_features=2000)
    fa, fb = detect_features(images[0], cfg), detect_features(images[1], cfg)
    rng = np.random.default_rng(2)
    # few distinct bits make many ties; repeated rows tie exactly
    coarse = rng.integers(0, 2, (300, 32), dtype=np.uint8) * np.uint8(0x81)
    coarse[100:] = coarse[rng.integers(0, 100, 200)]
    # every bit different (256, which wraps to 0 in the uint8 sums) before a nearer one
    far = np.vstack([~coarse[:1], coarse[1:2], ~coarse[:1]])
    for qa, tb in (
        (fa.descriptors, fb.descriptors),
        (coarse[:150], coarse[150:]),
        (coarse[:5], coarse[5:6]),
        (coarse[:1], far),
        (coarse[:1], far[:1]),
        (fa.descriptors[:, :20], fb.descriptors[:, :20]),  # not a whole number of words
    ):
        want = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=cross_check).match(qa, tb)
        pairs, dist = hamming_nearest(qa, tb, cross_check=cross_check)
        assert pairs.tolist() == [[m.queryIdx, m.trainIdx] for m in want]
        assert dist.tolist() == [m.distance for m in want]
    assert len(hamming_nearest(fa.descriptors, fb.descriptors[:0])[0]) == 0
    with pytest.raises(ValidationError, match="descriptors"):
        hamming_nearest(fa.descriptors, fb.descriptors[:, :16])
    with pytest.raises(ValidationError, match="descriptors"):
        hamming_nearest(fa.descriptors, fb.descriptors.astype(np.float32))


def test_build_tracks_chains_and_flags_ambiguity():
    feats = [
        Features(
            np.array([[0, 0], [1, 1], [2, 2]], np.float32), np.zeros((3, 32), np.uint8), [], (9, 9)
        )
        for _ in range(3)
    ]
    edges = np.array([[0, 1], [1, 2], [0, 2]])
    matches = [
        np.array([[0, 0], [1, 1]]),  # 0-1
        np.array([[0, 0], [1, 1]]),  # 1-2: chains kp 0 and kp 1 through all three cameras
        np.array([[2, 2]]),  # 0-2: kp 2 of cameras 0 and 2 only
    ]
    tr = build_tracks(3, feats, edges, matches)
    assert isinstance(tr, MultiViewTracks)
    assert tr.num_tracks == 3 and tr.observations.shape == (3, 3, 2)
    n_cams = np.sum(np.isfinite(tr.observations[..., 0]), axis=0)
    assert sorted(n_cams.tolist()) == [2, 3, 3]
    assert not tr.ambiguous.any()
    # a second keypoint of camera 1 (kp 2) joining kp 0's track makes that track ambiguous
    matches.append(np.array([[0, 2]]))  # another 0-1 match: cam 0 kp 0 <-> cam 1 kp 2
    tr = build_tracks(3, feats, np.vstack([edges, [[0, 1]]]), matches)
    assert tr.ambiguous.sum() == 1
    t_amb = int(np.flatnonzero(tr.ambiguous)[0])
    # the chosen observation of camera 1 is its best-connected keypoint (kp 0)
    np.testing.assert_array_equal(tr.observations[1, t_amb], [0, 0])


def test_build_tracks_empty_and_validation():
    feats = [Features(np.zeros((0, 2), np.float32), np.zeros((0, 32), np.uint8), [], (9, 9))] * 2
    tr = build_tracks(2, feats, np.zeros((0, 2), np.int64), [])
    assert tr.num_tracks == 0 and tr.observations.shape == (2, 0, 2)
    with pytest.raises(ValidationError, match="features"):
        build_tracks(3, feats, np.zeros((0, 2), np.int64), [])


def test_resolve_ambiguous_keeps_the_consistent_keypoint(narrow_rig):
    rig = narrow_rig
    X = np.array([[0.1, 0.2, 0.0], [-0.2, 0.1, 0.1]])
    pix = rig.project(X).pixels  # (3, 2, 2)
    # track 0 has two keypoints in camera 2: the true one and one 30 px off (better connected)
    node_cam = np.array([0, 1, 2, 2, 0, 1])
    node_track = np.array([0, 0, 0, 0, 1, 1])
    node_pix = np.array(
        [pix[0, 0], pix[1, 0], pix[2, 0] + [30, 0], pix[2, 0], pix[0, 1], pix[1, 1]]
    )
    obs = np.full((3, 2, 2), np.nan)
    obs[:, 0] = [pix[0, 0], pix[1, 0], pix[2, 0] + [30, 0]]
    obs[:2, 1] = pix[:2, 1]
    tracks = MultiViewTracks(
        node_cam, node_track, node_pix, np.array([1, 1, 3, 1, 1, 1]), obs, np.array([True, False])
    )
    fixed = resolve_ambiguous(rig, tracks, X)
    np.testing.assert_allclose(fixed[2, 0], pix[2, 0])
    np.testing.assert_array_equal(fixed[:, 1], obs[:, 1])
    # a failed (NaN) triangulation keeps the first choice
    kept = resolve_ambiguous(rig, tracks, np.array([[np.nan] * 3, X[1]]))
    np.testing.assert_array_equal(kept[2, 0], obs[2, 0])


def test_match_frame_observations_triangulate_onto_the_plane(plane_scene):
    from pointtraj.reconstruct.triangulate import TriangulationConfig, triangulate_ransac

    rig, images = plane_scene
    cfg = MatchingConfig(num_features=2000)
    tracks = match_frame(rig, images, np.array([[0, 1], [1, 2], [0, 2]]), cfg)
    assert tracks.observations.shape[0] == 3 and tracks.num_tracks > 500
    assert np.all(np.sum(np.isfinite(tracks.observations[..., 0]), axis=0) >= 2)
    tri = triangulate_ransac(rig, tracks.observations, TriangulationConfig())
    ok = tri.valid
    assert ok.mean() > 0.9
    # the plane is z = 0; 1 px of disparity is about 1 cm of depth at this scale
    assert np.median(np.abs(tri.points[ok, 2])) < 0.01
    inside = np.all(np.abs(tri.points[ok, :2]) <= 1.01, axis=1)
    assert inside.mean() > 0.99


def test_match_frame_skips_features_near_live_pixels(plane_scene):
    """``skip``: the tracker's live pixels. The features within ``skip_px`` of them are not
    matched, so no track has an observation there, and the left half of every image (the
    pixels given) loses its tracks while the right half keeps the same ones."""
    rig, images = plane_scene
    cfg = MatchingConfig(num_features=2000)
    edges = np.array([[0, 1], [1, 2], [0, 2]])
    full = match_frame(rig, images, edges, cfg)
    feats = [detect_features(im, cfg) for im in images]
    # every feature of the left half of each image, as if a live trajectory observed it there
    skip = np.full((3, max(len(f) for f in feats), 2), np.nan)
    for c, f in enumerate(feats):
        left = f.pixels[f.pixels[:, 0] < 240]
        skip[c, : len(left)] = left
    part = match_frame(rig, images, edges, cfg, skip=skip, skip_px=1.0)
    assert 0 < part.num_tracks < 0.8 * full.num_tracks
    obs = part.observations
    seen = np.isfinite(obs[..., 0])
    assert not np.any(obs[..., 0][seen] < 240 - 1.0)  # nothing matched on the skipped half

    # the tracks wholly in the right halves are found as before
    def right_tracks(t):
        o = t.observations
        ok = np.all(~np.isfinite(o[..., 0]) | (o[..., 0] > 250), axis=0)
        return {
            tuple(np.round(np.nan_to_num(o[:, i], nan=-1), 2).ravel()) for i in np.flatnonzero(ok)
        }

    a, b = right_tracks(full), right_tracks(part)
    assert len(a) > 100 and len(a & b) >= 0.9 * len(a)
    # no pixels, or radius 0: every feature
    f0 = feats[0]
    assert len(without_near(f0, np.full((4, 2), np.nan), 2.0)) == len(f0)
    assert len(without_near(f0, f0.pixels[:10], 0.0)) == len(f0)
    kept = without_near(f0, f0.pixels[:10], 0.5)
    assert len(kept) == len(f0) - 10 and len(kept.keypoints) == len(kept.descriptors)
    with pytest.raises(ValidationError, match="skip"):
        match_frame(rig, images, edges, cfg, skip=skip[:2], skip_px=1.0)


def test_near_pixels_answers_as_a_kd_tree():
    """The cell search gives SciPy's k-d tree answers (strictly within the radius), also for
    queries at exactly the radius, NaN rows, float32 pixels, pixels far outside the queries'
    cells and queries spread too wide for the cells (the tree itself then)."""
    from scipy.spatial import cKDTree

    def tree(pixels, queries, r):
        pts = np.asarray(pixels, np.float64)
        pts = pts[np.isfinite(pts).all(axis=1)]
        ok = np.isfinite(queries).all(axis=1)
        out = np.zeros(len(queries), bool)
        if len(pts) and ok.any():
            d, _ = cKDTree(pts).query(queries[ok], k=1, distance_upper_bound=r)
            out[ok] = np.isfinite(d)
        return out

    rng = np.random.default_rng(7)
    near_any = 0
    for trial in range(120):
        n, m = rng.integers(1, 2000, size=2)
        scale = [10.0, 1280.0, 1e5, 1e8][trial % 4]  # the last: more cells than the grid takes
        r = float(rng.choice([0.5, 1.5, 3.0, 24.0]))
        p = rng.uniform(-0.1 * scale, scale, (n, 2))
        q = rng.uniform(-0.1 * scale, scale, (m, 2))
        k = min(n, m) // 2
        angle = rng.uniform(0, 2 * np.pi, k)
        q[:k] = p[:k] + r * rng.uniform(0.99, 1.01, (k, 1)) * np.c_[np.cos(angle), np.sin(angle)]
        q[: k // 4] = p[: k // 4] + [r, 0.0]  # exactly at the radius: not near
        p[rng.random(n) < 0.05] = np.nan
        q[rng.random(m) < 0.05, 1] = np.nan
        if trial % 2:
            p = p.astype(np.float32)
        want = tree(p, q, r)
        np.testing.assert_array_equal(near_pixels(p, q, r), want)
        near_any += int(want.sum())
    assert near_any > 10_000  # the comparisons are not all "far"
    assert not near_pixels(np.zeros((3, 2)), np.zeros((2, 2)), 0.0).any()
    assert near_pixels(np.zeros((0, 2)), np.zeros((2, 2)), 1.0).shape == (2,)
    huge = np.array([[1e308, 0.0], [0.0, 0.0]])  # beyond the cells' float range: the tree
    np.testing.assert_array_equal(near_pixels(huge, huge, 0.5), [True, True])


def test_match_frame_validates_inputs(plane_scene):
    rig, images = plane_scene
    with pytest.raises(ValidationError, match="expected 3 images"):
        match_frame(rig, images[:2], np.array([[0, 1]]))
    with pytest.raises(ValidationError, match="edges"):
        match_frame(rig, images, np.array([[0, 5]]))
    with pytest.raises(ValidationError, match="the rig says 480x360"):
        match_frame(rig, [images[0][:100]] + images[1:], np.array([[0, 1]]))


def _features(pixels: np.ndarray, descriptors: np.ndarray, size=(480, 360)) -> Features:
    import cv2

    kps = [cv2.KeyPoint(float(x), float(y), 31.0) for x, y in pixels]
    return Features(pixels.astype(np.float32), descriptors, kps, size)


@pytest.mark.parametrize("cross_check", [False, True])
def test_guided_matching_equals_brute_force_within_the_band(cross_check):
    """The vectorised band search finds each keypoint's Hamming nearest neighbour in its band."""
    from pointtraj.reconstruct.matching import _guided_matches

    rng = np.random.default_rng(5)
    rig = plane_rig(2, dist=[-0.1, 0.02, 0.0, 0.0, 0.0])
    X = rng.uniform(-0.6, 0.6, (400, 3))
    pix = rig.project(X).pixels
    inside = np.all(np.isfinite(pix), axis=(0, 2))
    pa, pb = pix[0][inside], pix[1][inside] + rng.normal(0, 0.3, pix[1][inside].shape)
    desc_a = rng.integers(0, 256, (len(pa), 32), dtype=np.uint8)
    flips = rng.random(desc_a.shape) < 0.05  # true matches differ by a few bits
    desc_b = desc_a ^ (flips * rng.integers(1, 256, desc_a.shape)).astype(np.uint8)
    # distractors: the exact descriptor of an a keypoint, far off its epipolar line
    off = np.column_stack([rng.uniform(0, 480, 60), rng.uniform(0, 360, 60)])
    off = off[epipolar_distances(rig, 0, 1, pa[:60], off) > 10.0]
    pb_all = np.vstack([pb, off])
    desc_b_all = np.vstack([desc_b, desc_a[: len(off)]])
    fa, fb = _features(pa, desc_a), _features(pb_all, desc_b_all)
    cfg = MatchingConfig(
        guided=True, gms=False, epipolar_px=2.5, ratio=0.8, cross_check=cross_check
    )
    pairs, dist = _guided_matches(rig, 0, 1, fa, fb, cfg)
    # reference: for every a keypoint, the b keypoints whose epipolar distance is within the
    # band; nearest and second nearest by Hamming distance
    bits = np.unpackbits(desc_a[:, None, :] ^ desc_b_all[None, :, :], axis=2).sum(axis=2)
    band = (
        np.stack(
            [
                epipolar_distances(rig, 0, 1, np.repeat(pa[i : i + 1], len(pb_all), 0), pb_all)
                for i in range(len(pa))
            ]
        )
        <= 2.5
    )
    got = {tuple(p) for p in pairs.tolist()}
    assert len(got) > 0.9 * len(pa)
    for i, j in got:
        assert band[i, j]  # within the band
        assert bits[i, j] == bits[i][band[i]].min()  # the nearest within it
        assert j < len(pb)  # never a distractor off the line
    assert np.all(dist == bits[pairs[:, 0], pairs[:, 1]])
    # nearly every keypoint finds its true partner (the distractors are off the line)
    assert np.mean(pairs[:, 0] == pairs[:, 1]) > 0.98


def test_moving_boxes_cover_moving_regions_and_ignore_jitter():
    """Points that move in one region of an image give a box around it (with a tile of
    margin); a few scattered moving points among still ones (tracking jitter) give none."""
    from pointtraj.reconstruct.matching import moving_boxes

    rng = np.random.default_rng(0)
    still = rng.uniform([0, 0], [640, 480], (2000, 2))
    limb = rng.uniform([300, 200], [400, 260], (200, 2))
    pixels = np.concatenate([still, limb])[None]  # (1, N, 2)
    moving = np.zeros(len(pixels[0]), bool)
    moving[len(still) :] = True
    moving[rng.choice(len(still), 40, replace=False)] = True  # 2 % jitter
    sizes = np.array([[640, 480]])
    (boxes,) = moving_boxes(pixels, moving, sizes, tile_px=64)
    assert len(boxes) == 1
    x0, y0, x1, y1 = boxes[0]
    assert x0 <= 300 - 64 and y0 <= 200 - 64 and x1 >= 400 + 64 and y1 >= 260 + 64  # margin
    assert (x1 - x0) * (y1 - y0) < 0.3 * 640 * 480  # (here 320 x 256 px)
    jitter_only = moving.copy()
    jitter_only[len(still) :] = False
    assert len(moving_boxes(pixels, jitter_only, sizes)[0]) == 0
    # NaN observations and points outside the image are ignored; no point: no box
    pixels[0, :10] = np.nan
    pixels[0, 10:20] = -100
    assert len(moving_boxes(pixels, moving, sizes)[0]) == 1
    assert (
        len(moving_boxes(np.full((2, 0, 2), np.nan), np.zeros(0, bool), np.array([[64, 64]] * 2)))
        == 2
    )


def test_detect_features_in_boxes_keeps_the_whole_image_features_there():
    """Features detected in a box lie in it, with descriptors computed on the whole image; most
    of the whole image's features in the box's interior are found again."""
    from pointtraj.reconstruct.matching import detect_features

    rng = np.random.default_rng(3)
    img = (rng.random((240, 320)) * 255).astype(np.uint8)
    img = np.ascontiguousarray(np.kron(img, np.ones((2, 2), np.uint8)))  # 480x640, textured
    cfg = MatchingConfig(num_features=2000)
    whole = detect_features(img, cfg)
    box = np.array([[200, 100, 460, 360]])
    part = detect_features(img, cfg, box)
    assert len(part) > 0 and part.descriptors.shape == (len(part), 32)
    p = part.pixels
    assert np.all((p[:, 0] >= 200) & (p[:, 0] < 460) & (p[:, 1] >= 100) & (p[:, 1] < 360))
    inner = (whole.pixels[:, 0] > 240) & (whole.pixels[:, 0] < 420)
    inner &= (whole.pixels[:, 1] > 140) & (whole.pixels[:, 1] < 320)
    d = np.linalg.norm(whole.pixels[inner][:, None] - p[None], axis=2).min(axis=1)
    assert np.mean(d < 1.0) > 0.5
    # overlapping boxes do not give a keypoint twice; no box: no feature
    twice = detect_features(img, cfg, np.array([[200, 100, 460, 360], [200, 100, 460, 360]]))
    assert len(np.unique(np.round(twice.pixels, 3), axis=0)) == len(twice)
    assert len(detect_features(img, cfg, np.zeros((0, 4), np.int64))) == 0
