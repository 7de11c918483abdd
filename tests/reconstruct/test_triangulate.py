"""Tests of robust multi-view triangulation and visibility (pointtraj.reconstruct.triangulate)."""

from __future__ import annotations

import functools

import numpy as np
import pytest
from helpers.rigs import ring_rig

from pointtraj.camera import Camera, CameraRig
from pointtraj.errors import ValidationError
from pointtraj.reconstruct.occlusion import occlusion_test
from pointtraj.reconstruct.triangulate import (
    Triangulation,
    TriangulationConfig,
    compute_visibility,
    triangulate_points,
    triangulate_ransac,
)

DIST = [-0.12, 0.03, 0.0005, -0.0004, 0.0, 0.0, 0.0, 0.0]


#: Two-height ring of ``n`` 1280x1024 cameras (f = 1000 px) 3 m from (0, 0, 1), looking at it.
make_ring = functools.partial(
    ring_rig, size=(1280, 1024), focal=1000.0, heights=(0.6, 1.6), names="cam{i:02d}"
)


def make_scene(
    rng: np.random.Generator, rig: CameraRig, n: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points in the capture volume and their exact observations (NaN outside the image)."""
    X = rng.uniform([-0.7, -0.7, 0.3], [0.7, 0.7, 1.7], size=(n, 3))
    proj = rig.project(X)
    obs = np.where(proj.in_image[..., None], proj.pixels, np.nan)
    return X, obs, proj.in_image


def corrupt(
    rng: np.random.Generator, obs: np.ndarray, fraction: float, noise_px: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """Add Gaussian noise and replace ``fraction`` of the observed views by random pixels."""
    seen = np.all(np.isfinite(obs), axis=-1)
    out = obs + rng.normal(0.0, noise_px, obs.shape) if noise_px else obs.copy()
    bad = seen & (rng.random(seen.shape) < fraction)
    out[bad] = rng.uniform([0, 0], [1279, 1023], size=(int(bad.sum()), 2))
    return out, bad


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(12345)


# -- triangulate_points ----------------------------------------------------------------------


@pytest.mark.parametrize("dist", [None, DIST])
def test_triangulate_points_noise_free_round_trip(rng, dist):
    rig = make_ring(8, dist=dist)
    X, obs, _ = make_scene(rng, rig, 500)
    Y = triangulate_points(rig, obs)
    assert Y.shape == (500, 3) and Y.dtype == np.float64
    np.testing.assert_allclose(Y, X, atol=1e-9)


def test_triangulate_points_nan_propagation(rng):
    rig = make_ring(6)
    X, obs, _ = make_scene(rng, rig, 4)
    obs[:, 0] = np.nan  # no view
    obs[1:, 1] = np.nan  # one view
    obs[2:, 2] = np.nan  # two views: enough
    Y = triangulate_points(rig, obs)
    assert np.all(np.isnan(Y[:2]))
    np.testing.assert_allclose(Y[2:], X[2:], atol=1e-9)


def test_triangulate_points_bad_shape():
    rig = make_ring(4)
    with pytest.raises(ValueError, match=r"observations: expected shape \(4, N, 2\)"):
        triangulate_points(rig, np.zeros((3, 10, 2)))
    with pytest.raises(ValueError, match="infinite"):
        triangulate_points(rig, np.full((4, 1, 2), np.inf))


def test_triangulate_points_matches_opencv_two_views(rng):
    """Regression against cv2.triangulatePoints (DLT) on two noisy views."""
    import cv2

    rig = make_ring(8).subset([0, 2])  # 90 degrees apart
    X, obs, seen = make_scene(rng, rig, 300)
    keep = seen.all(axis=0)
    obs = obs[:, keep] + rng.normal(0.0, 0.5, (2, int(keep.sum()), 2))
    ours = triangulate_points(rig, obs)
    xy = rig.normalized(obs)  # no distortion here: K^-1 x
    P = [np.hstack([cam.R, cam.t[:, None]]) for cam in rig]
    h = cv2.triangulatePoints(P[0], P[1], xy[0].T.copy(), xy[1].T.copy())
    theirs = (h[:3] / h[3]).T
    # Both minimise the same algebraic error, up to our world conditioning (which changes the
    # ||h|| = 1 gauge): they agree to a few microns while the noise moves points by ~a millimetre.
    diff = np.linalg.norm(ours - theirs, axis=1)
    noise_effect = np.linalg.norm(ours - X[keep], axis=1)
    assert np.max(diff) < 5e-5
    assert np.median(diff) < 0.01 * np.median(noise_effect)


# -- triangulate_ransac ----------------------------------------------------------------------


def test_ransac_noise_free_round_trip_with_distortion(rng):
    rig = make_ring(8, dist=DIST)
    X, obs, seen = make_scene(rng, rig, 400)
    res = triangulate_ransac(rig, obs)
    assert isinstance(res, Triangulation)
    assert res.points.shape == (400, 3) and res.points.dtype == np.float64
    assert res.inliers.shape == (8, 400) and res.inliers.dtype == bool
    assert res.errors.shape == (8, 400)
    assert res.visibility.shape == (400, 8) and res.visibility.dtype == np.float32
    assert res.mean_error.shape == (400,)
    np.testing.assert_allclose(res.points, X, atol=1e-9)
    np.testing.assert_array_equal(res.inliers, seen)
    assert np.nanmax(res.errors) < 1e-6
    np.testing.assert_allclose(res.visibility, seen.T.astype(np.float32), atol=1e-6)
    assert np.all(np.isnan(res.errors[~seen]))


def test_ransac_rejects_corrupted_views(rng):
    rig = make_ring(12, dist=DIST)
    X, obs, seen = make_scene(rng, rig, 3000)
    noisy, bad = corrupt(rng, obs, 0.3, noise_px=0.5)
    res = triangulate_ransac(rig, noisy)
    err = np.linalg.norm(res.points - X, axis=1)
    # With 5 or more clean views a point must be recovered; with 3 or 4 (of up to 12) nearly
    # always (an all-clean pair is then rare and the hypothesis budget is 50).
    n_clean = (seen & ~bad).sum(axis=0)
    assert np.all(np.isfinite(err[n_clean >= 5]))
    clean = n_clean >= 3
    assert np.isfinite(err[clean]).mean() > 0.995
    clean &= np.isfinite(err)
    assert np.median(err[clean]) < 2e-3
    assert np.percentile(err[clean], 99) < 1e-2
    # The corrupted views are found: almost none is an inlier, almost every clean view is.
    ok = res.valid
    assert res.inliers[bad & ok].mean() < 0.01
    assert res.inliers[seen & ~bad & ok].mean() > 0.97
    # The plain DLT over all views is ruined by the same outliers.
    dlt = np.linalg.norm(triangulate_points(rig, noisy) - X, axis=1)
    assert np.median(dlt[clean]) > 10 * np.median(err[clean])
    # Mean error and visibility are consistent with the inliers.
    assert np.all(res.mean_error[ok] < 2.0)
    assert np.all(res.visibility[~res.inliers.T & (res.errors.T > 3.0)] < np.exp(-9) + 1e-7)


def test_ransac_nan_propagation(rng):
    rig = make_ring(6)
    X, obs, _ = make_scene(rng, rig, 5)
    obs[:, 0] = np.nan  # no view
    obs[1:, 1] = np.nan  # one view
    obs[2:, 2] = np.nan  # two views
    obs[:, 3] = [[100.0, 100.0], [1200.0, 900.0], [600, 30], [10, 1000], [700, 700], [5, 5]]
    res = triangulate_ransac(rig, obs)
    assert np.all(np.isnan(res.points[[0, 1, 3]]))  # 0, 1 views; 6 views that disagree
    assert not res.inliers[:, [0, 1, 3]].any()
    assert np.all(np.isnan(res.mean_error[[0, 1, 3]]))
    assert np.all(res.visibility[[0, 1, 3]] == 0)
    np.testing.assert_allclose(res.points[[2, 4]], X[[2, 4]], atol=1e-9)
    assert res.inliers[:2, 2].all() and not res.inliers[2:, 2].any()


def test_ransac_min_views_and_determinism(rng):
    rig = make_ring(8)
    X, obs, seen = make_scene(rng, rig, 300)
    noisy, _ = corrupt(rng, obs, 0.3, noise_px=0.5)
    cfg = TriangulationConfig(min_views=4, seed=7)
    a = triangulate_ransac(rig, noisy, cfg)
    b = triangulate_ransac(rig, noisy, cfg)
    np.testing.assert_array_equal(a.points, b.points)
    assert np.all(a.inliers.sum(axis=0)[a.valid] >= 4)
    assert np.all(np.isnan(a.points[a.inliers.sum(axis=0) < 4]))
    # Small chunks (the chunk loop) give equally good results.
    c = triangulate_ransac(rig, noisy, cfg, chunk_size=37)
    ea = np.linalg.norm(a.points - X, axis=1)
    ec = np.linalg.norm(c.points - X, axis=1)
    assert abs(np.nanmedian(ea) - np.nanmedian(ec)) < 2e-4
    assert abs(a.valid.mean() - c.valid.mean()) < 0.02


def test_ransac_config_and_input_errors():
    rig = make_ring(4)
    with pytest.raises(ValueError, match="threshold_px"):
        TriangulationConfig(threshold_px=0)
    with pytest.raises(ValueError, match="min_views"):
        TriangulationConfig(min_views=1)
    with pytest.raises(ValueError, match="confidence"):
        TriangulationConfig(confidence=1.0)
    with pytest.raises(ValueError, match="config"):
        triangulate_ransac(rig, np.zeros((4, 1, 2)), {"threshold_px": 2})
    with pytest.raises(ValidationError, match="observations"):
        triangulate_ransac(rig, np.zeros((4, 1, 3)))


def test_ransac_empty_input():
    rig = make_ring(4)
    res = triangulate_ransac(rig, np.zeros((4, 0, 2)))
    assert res.points.shape == (0, 3) and res.visibility.shape == (0, 4)


# -- visibility and occlusion ----------------------------------------------------------------


def test_visibility_formula_behind_and_outside():
    cam = Camera.look_at("a", [3.0, 0.0, 1.0], [0.0, 0.0, 1.0], (640, 480), 500.0)
    rig = CameraRig([cam])
    X = np.array(
        [
            [0.0, 0.0, 1.0],  # in front, observed exactly
            [0.0, 0.0, 1.0],  # in front, observed 1 sigma off
            [6.0, 0.0, 1.0],  # behind the camera
            [0.0, 5.0, 1.0],  # in front but outside the image
            [0.0, 0.2, 1.0],  # in front, unobserved
        ]
    )
    pix = rig.project(X).pixels
    obs = pix.copy()
    obs[0, 1] += [0.6, 0.8]  # 1 px error
    obs[0, 2] = [320.0, 240.0]  # an observation the point (behind) cannot explain
    obs[0, 3] = pix[0, 3]  # project outside, still "observed" there
    obs[0, 4] = np.nan
    v = compute_visibility(rig, X, obs, sigma_px=2.0)
    assert v.shape == (5, 1) and v.dtype == np.float32
    np.testing.assert_allclose(v[:, 0], [1.0, np.exp(-0.25), 0.0, 0.0, 0.0], atol=1e-6)
    # Projection-based: 1 wherever the point is in the image, regardless of observations.
    np.testing.assert_array_equal(compute_visibility(rig, X, None, 1.0)[:, 0], [1, 1, 0, 0, 1])
    nan_point = compute_visibility(rig, np.full((1, 3), np.nan), None, 1.0)
    assert nan_point[0, 0] == 0
    with pytest.raises(ValueError, match="sigma_px"):
        compute_visibility(rig, X, None, 0.0)


def make_two_walls() -> tuple[CameraRig, np.ndarray, np.ndarray]:
    """Two parallel walls of points (x = +0.3 and x = -0.3) between cameras on the +x and -x
    axes; a third camera looks down along the walls, which it sees edge-on."""
    rig = CameraRig(
        [
            Camera.look_at("east", [3.0, 0.0, 1.0], [0, 0, 1.0], (640, 480), 600.0),
            Camera.look_at("west", [-3.0, 0.0, 1.0], [0, 0, 1.0], (640, 480), 600.0),
            Camera.look_at("north", [0.0, 4.0, 1.0], [0, 0, 1.0], (640, 480), 600.0, up=[1, 0, 0]),
        ]
    )
    g = np.linspace(-0.4, 0.4, 25)
    yy, zz = np.meshgrid(g, g + 1.0)
    wall = np.stack([np.zeros(yy.size), yy.ravel(), zz.ravel()], axis=1)
    east_wall = wall + [0.3, 0.0, 0.0]
    west_wall = wall - [0.3, 0.0, 0.0]
    is_east = np.r_[np.ones(len(wall), bool), np.zeros(len(wall), bool)]
    return rig, np.concatenate([east_wall, west_wall]), is_east


def test_occlusion_test_on_two_walls():
    rig, X, is_east = make_two_walls()
    occ = occlusion_test(rig, X, depth_tolerance=0.05, cell_px=8.0)
    assert occ.shape == (X.shape[0], 3) and occ.dtype == bool
    # The east camera sees the east wall and not the west wall behind it, and vice versa.
    assert not occ[is_east, 0].any() and occ[~is_east, 0].mean() > 0.95
    assert not occ[~is_east, 1].any() and occ[is_east, 1].mean() > 0.95
    # The north camera sees the walls edge-on: each wall's nearest column of points hides the
    # rest of that wall, and the two walls do not hide each other.
    y = X[:, 1]
    assert not occ[y == y.max(), 2].any() and occ[y < y.max() - 0.1, 2].mean() > 0.8
    # A large tolerance accepts everything.
    assert not occlusion_test(rig, X, depth_tolerance=1.0).any()
    # Visibility drops to 0 exactly where occluded.
    v = compute_visibility(rig, X, None, 1.0, occlusion_depth=0.05, occlusion_cell_px=8.0)
    np.testing.assert_array_equal(v == 0, occ | ~rig.project(X).in_image.T)
    # The automatic cell size (from the projected point spacing) finds the same walls.
    auto = occlusion_test(rig, X, depth_tolerance=0.05)
    assert not auto[is_east, 0].any() and auto[~is_east, 0].mean() > 0.95
    assert not auto[~is_east, 1].any() and auto[is_east, 1].mean() > 0.95
    # NaN points are ignored and never occluded.
    Xn = np.vstack([X, np.full((1, 3), np.nan)])
    assert not occlusion_test(rig, Xn, 0.05)[-1].any()
    with pytest.raises(ValueError, match="depth_tolerance"):
        occlusion_test(rig, X, -1.0)


def test_ransac_outer_chunks_bound_memory(rng, monkeypatch):
    """Chunked refits (small chunks forced) give results as good as one chunk."""
    import pointtraj.reconstruct.triangulate as tri

    rig = make_ring(8, dist=DIST)
    X, obs, _ = make_scene(rng, rig, 600)
    noisy, _ = corrupt(rng, obs, 0.3, noise_px=0.5)
    whole = triangulate_ransac(rig, noisy)
    monkeypatch.setattr(tri, "_MAX_REFIT_ELEMENTS", 8 * 50)  # 50 points per outer chunk
    parts = triangulate_ransac(rig, noisy, chunk_size=20)
    for res in (whole, parts):
        assert res.points.shape == (600, 3) and res.visibility.shape == (600, 8)
    e_whole = np.linalg.norm(whole.points - X, axis=1)
    e_parts = np.linalg.norm(parts.points - X, axis=1)
    assert abs(np.nanmedian(e_whole) - np.nanmedian(e_parts)) < 2e-4
    assert abs(whole.valid.mean() - parts.valid.mean()) < 0.02
    # Noise-free observations are reproduced exactly through the chunked path too.
    exact = triangulate_ransac(rig, obs, chunk_size=7)
    np.testing.assert_allclose(exact.points, X, atol=1e-9)


def test_ransac_hypothesis_budget_is_respected(rng, monkeypatch):
    """At most ``iterations`` hypotheses per point, also when ``batch`` does not divide it."""
    import pointtraj.reconstruct.triangulate as tri

    rig = make_ring(8)
    _, obs, _ = make_scene(rng, rig, 200)
    noisy, _ = corrupt(rng, obs, 0.6, noise_px=0.5)  # many outliers: no early stop
    drawn = []
    real = tri._sample_pairs

    def counting(rng_, order, n_obs, count):
        drawn.append(count)
        return real(rng_, order, n_obs, count)

    monkeypatch.setattr(tri, "_sample_pairs", counting)
    triangulate_ransac(rig, noisy, TriangulationConfig(iterations=10, batch=4))
    assert sum(drawn) <= 10 and drawn[:3] == [4, 4, 2]


def test_ransac_prescoring_path(rng, monkeypatch):
    """Large rigs pre-score hypotheses on a subset of views; forced here on 12 cameras."""
    import pointtraj.reconstruct.triangulate as tri

    rig = make_ring(12, dist=DIST)
    X, obs, seen = make_scene(rng, rig, 1500)
    noisy, bad = corrupt(rng, obs, 0.3, noise_px=0.5)
    full = triangulate_ransac(rig, noisy)
    monkeypatch.setattr(tri, "_PRESCORE_VIEWS", 4)  # 12 > 2 * 4: pre-scoring on
    pre = triangulate_ransac(rig, noisy)
    e_full = np.linalg.norm(full.points - X, axis=1)
    e_pre = np.linalg.norm(pre.points - X, axis=1)
    assert abs(np.nanmedian(e_pre) - np.nanmedian(e_full)) < 2e-4
    assert pre.valid.mean() > full.valid.mean() - 0.01
    assert pre.inliers[bad & pre.valid].mean() < 0.01
    np.testing.assert_allclose(triangulate_ransac(rig, obs).points, X, atol=1e-9)
