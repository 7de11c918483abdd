"""The faster forms of the plane-sweep and flow kernels (issue #14) give the results of the
plain ones, bit for bit, on rendered images: view discovery's sweeps of several reference
cameras set up, scored and accepted in one pass, densification's early rejection and NCC blocks, its grid test of
taken pixels, and the forward-backward flow that goes back only from converged points."""

from __future__ import annotations

import numpy as np
import pytest
from helpers.rigs import plane_rig
from helpers.scenes import plane_frames, plane_images
from scipy.spatial import cKDTree

import pointtraj.reconstruct.densify as densify_module
from pointtraj.reconstruct.densify import (
    DensifyConfig,
    _grid,
    _grid_axes,
    _near_grid,
    densify,
    prepare_images,
)
from pointtraj.reconstruct.flow import track_flow
from pointtraj.reconstruct.views import ViewsConfig, discover_views


def plane_points(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(-0.3, 0.3, n), rng.uniform(-0.3, 0.3, n), np.zeros(n)])


@pytest.mark.parametrize(
    "cfg",
    [
        ViewsConfig(),
        ViewsConfig(normal="bisector"),
        ViewsConfig(search_sigmas=2.0),  # with sigma_px 3: shifts across the epipolar line
    ],
    ids=["default", "bisector", "across"],
)
def test_discovery_of_several_reference_cameras_in_one_call_equals_one_at_a_time(cfg):
    rig = plane_rig(angles=(-60.0, -20.0, 20.0, 60.0))
    prepared = prepare_images(rig, [im[..., 0] for im in plane_images(rig, seed=3)])
    X = plane_points(80)
    proj = rig.project(X)
    pix = proj.pixels.copy()
    half = len(X) // 2
    pix[2:, :half] = np.nan  # the first half seen by cameras 0 and 1
    pix[1:3, half:] = np.nan  # the second by 0 and 3: camera 2's sweeps use 1 and 3
    out, searched = discover_views(rig, prepared, X, pix, proj.in_image, cfg, sigma_px=3.0)
    # each half alone: camera 2's sweeps from one reference camera per call, the same groups
    parts_out, parts_searched = pix.copy(), np.zeros_like(searched)
    for part in (slice(0, half), slice(half, None)):
        cand = np.zeros_like(proj.in_image)
        cand[:, part] = proj.in_image[:, part]
        o, s = discover_views(rig, prepared, X, pix, cand, cfg, sigma_px=3.0)
        parts_out[:, part], parts_searched[:, part] = o[:, part], s[:, part]
    np.testing.assert_array_equal(out, parts_out)
    np.testing.assert_array_equal(searched, parts_searched)
    found = np.all(np.isfinite(out[2]), axis=1)
    assert found[:half].sum() > 10 and found[half:].sum() > 10  # from both references


def test_densify_early_rejection_and_ncc_blocks_change_no_point(wide_rig, monkeypatch):
    rig = wide_rig
    prepared = prepare_images(rig, [im[..., 0] for im in plane_images(rig, seed=5)])
    X = plane_points(12)
    pix = rig.project(X).pixels
    taken = pix[:, :4]
    cfg = DensifyConfig(enabled=True, rounds=2)
    rows = {"n": 0}
    ncc = densify_module._ncc

    def counting(image, other, cam, rays, *args, **kwargs):
        rows["n"] += len(rays)
        return ncc(image, other, cam, rays, *args, **kwargs)

    monkeypatch.setattr(densify_module, "_ncc", counting)
    fast = densify(rig, prepared, X, pix, taken, cfg)
    fast_rows = rows["n"]
    rows["n"] = 0
    monkeypatch.setattr(densify_module, "_NCC_BOUND", 1e9)  # no candidate given up early
    monkeypatch.setattr(densify_module, "_NCC_BLOCK", 1 << 40)  # one block per call
    plain = densify(rig, prepared, X, pix, taken, cfg)
    assert fast.shape[1] > 50
    np.testing.assert_array_equal(fast, plain)
    assert fast_rows < rows["n"]  # candidates were given up before their last partner


@pytest.mark.parametrize("radius", [4.5, 5.999, 7.0])
def test_taken_pixels_near_the_grid_as_a_kd_tree_finds_them(radius):
    rng = np.random.default_rng(0)
    us, vs = _grid_axes(480, 360, 6.0, 7.0)
    grid = _grid(480, 360, 6.0, 7.0)
    points = np.column_stack([rng.uniform(-20, 500, 3000), rng.uniform(-20, 380, 3000)])
    # and some exactly at the radius from a grid point (strictly closer counts)
    g = grid[rng.integers(0, len(grid), 50)]
    angle = rng.uniform(0, 2 * np.pi, 50)
    points = np.vstack([points, g + radius * np.column_stack([np.cos(angle), np.sin(angle)])])
    points = np.vstack([points, grid[:5] + [radius, 0.0]])
    # on grid points and on the lines between them, where a point's cell is decided by rounding
    points = np.vstack([points, grid[100:110], grid[200:210] + [3.0, 0.0], grid[300:310] + 1e-13])
    d, _ = cKDTree(points).query(grid, k=1, distance_upper_bound=radius)
    near = _near_grid(points, us, vs, radius)
    np.testing.assert_array_equal(near, np.isfinite(d))
    assert 0 < near.sum() < len(grid)


def test_flow_goes_back_only_from_converged_points_with_the_same_results(narrow_rig):
    import cv2

    frames = plane_frames(narrow_rig, 2, seed=4, velocity=(0.01, 0.005, 0.0))
    g0, g1 = frames[0][0][..., 0], frames[1][0][..., 0]
    rng = np.random.default_rng(1)
    pts = np.column_stack([rng.uniform(-5, 485, 3000), rng.uniform(-5, 365, 3000)])
    out = track_flow(g0, g1, pts, window=21, levels=3, fb_max_px=1.0)
    # the plain form: back from every point
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 0.01)
    lk = {"winSize": (21, 21), "maxLevel": 3, "criteria": crit}
    a = pts.astype(np.float32).reshape(-1, 1, 2)
    p1, st1, _ = cv2.calcOpticalFlowPyrLK(g0, g1, a, None, **lk)
    p0b, st2, _ = cv2.calcOpticalFlowPyrLK(g1, g0, p1, None, **lk)
    p1 = p1.reshape(-1, 2)
    fb = np.linalg.norm(p0b.reshape(-1, 2) - a.reshape(-1, 2), axis=1)
    good = (st1.ravel() == 1) & (st2.ravel() == 1) & (fb <= 1.0)
    good &= (p1[:, 0] >= -0.5) & (p1[:, 0] < 479.5) & (p1[:, 1] >= -0.5) & (p1[:, 1] < 359.5)
    plain = np.where(good[:, None], p1, np.nan)
    np.testing.assert_array_equal(out, plain)
    assert 0.3 < good.mean() < 1.0  # some fail, most follow


def test_projection_into_some_cameras_is_that_of_the_whole_rig():
    # densification projects its new points only into the cameras that test them
    rig = plane_rig(angles=(-60.0, -20.0, 20.0, 60.0), dist=[-0.1, 0.02, 0.001, 0.0, 0.0])
    X = np.vstack([plane_points(500), [[0.0, 0.0, 5.0], [np.nan, 0.0, 0.0]]])
    whole = rig.project(X)
    cams = [0, 2, 3]
    part = rig.subset(cams).project(X)
    np.testing.assert_array_equal(part.pixels, whole.pixels[cams])
    np.testing.assert_array_equal(part.in_image, whole.in_image[cams])
    assert whole.in_image.any() and not whole.in_image.all()
