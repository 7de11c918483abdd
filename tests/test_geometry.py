"""Shared geometry (pointtraj.geometry): rigid fits, Rodrigues vectors, mean rotations, camera axis
angles, and the lens model and its inverse, against known answers, scipy and OpenCV."""

from __future__ import annotations

import numpy as np
import pytest

from pointtraj import geometry
from pointtraj.camera import Camera, CameraRig
from pointtraj.errors import ValidationError
from pointtraj.geometry import (
    axis_angles,
    distort_normalized,
    fit_rigid,
    mean_rotation,
    rodrigues_from_rotation,
    rotation_angle_deg,
    rotation_from_rodrigues,
    undistort_normalized,
)

#: Lenses: mild barrel, a real webcam (caliscope cam_0), radial only, pincushion, and OpenCV's
#: rational model with and without tangential terms.
LENSES = {
    "mild": [-0.12, 0.03, 0.0005, -0.0004, 0, 0, 0, 0],
    "webcam": [-0.3320992998866297, 0.04641968621160267, -0.0043, 0.0041, 0.0666, 0, 0, 0],
    "radial": [-0.3, 0.1, 0, 0, 0, 0, 0, 0],
    "pincushion": [0.12, 0.0, 0, 0, 0, 0, 0, 0],
    "rational": [0.2, -0.05, 0.001, 0, 0.01, 0.1, 0.01, 0.001],
    "rational-radial": [0.1, 0, 0, 0, 0, 0.1, 0, 0],
}
#: Focal length (pixels) used to state undistortion errors in pixels.
FOCAL = 1000.0


def random_rotations(rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, 3, 3) uniformly random rotations."""
    from scipy.spatial.transform import Rotation

    return Rotation.random(n, random_state=rng).as_matrix()


# -- fit_rigid -----------------------------------------------------------------------------------
def test_fit_rigid_recovers_batched_similarities():
    rng = np.random.default_rng(0)
    B, N = 40, 12
    R = random_rotations(rng, B)
    t = rng.normal(size=(B, 3))
    s = rng.uniform(0.2, 5.0, B)
    src = rng.normal(size=(B, N, 3))
    dst = s[:, None, None] * src @ R.transpose(0, 2, 1) + t[:, None]
    fit = fit_rigid(src, dst, with_scale=True)
    assert fit.scale.shape == (B,) and fit.rotation.shape == (B, 3, 3)
    assert fit.translation.shape == (B, 3) and fit.valid.shape == (B,)
    np.testing.assert_allclose(fit.scale, s, rtol=1e-12)
    np.testing.assert_allclose(fit.rotation, R, atol=1e-12)
    np.testing.assert_allclose(fit.translation, t, atol=1e-12)
    assert fit.valid.all()
    # Rigid (no scale): the rotation is the same, the scale 1.
    rigid = fit_rigid(src, src @ R.transpose(0, 2, 1) + t[:, None])
    np.testing.assert_array_equal(rigid.scale, 1.0)
    np.testing.assert_allclose(rigid.rotation, R, atol=1e-12)
    np.testing.assert_allclose(rigid.translation, t, atol=1e-12)


def test_fit_rigid_uncentred_fixes_reflections_and_weights_out_outliers():
    """Kabsch on vectors (no centring): proper rotations, even for a mirror image."""
    rng = np.random.default_rng(1)
    R = random_rotations(rng, 50)
    a = rng.normal(size=(50, 6, 3))
    b = a @ R.transpose(0, 2, 1)
    fit = fit_rigid(a, b, center=False)
    np.testing.assert_allclose(fit.rotation, R, atol=1e-9)
    np.testing.assert_array_equal(fit.translation, 0.0)
    mirror = a * np.array([1.0, 1.0, -1.0])  # the best orthogonal map is a reflection
    np.testing.assert_allclose(
        np.linalg.det(fit_rigid(a, mirror, center=False).rotation), 1.0, atol=1e-9
    )
    b_out = b.copy()
    b_out[:, 0] += 5.0
    w = np.ones((50, 6))
    w[:, 0] = 0
    np.testing.assert_allclose(fit_rigid(a, b_out, w, center=False).rotation, R, atol=1e-9)
    # Weights of one are no weights.
    np.testing.assert_allclose(
        fit_rigid(a, b, np.ones((50, 6)), center=False).rotation, fit.rotation, atol=1e-15
    )


def test_fit_rigid_weighted_similarity_ignores_zero_weight_pairs():
    rng = np.random.default_rng(2)
    R = random_rotations(rng, 5)
    src = rng.normal(size=(5, 10, 3))
    dst = 2.0 * src @ R.transpose(0, 2, 1) + [1.0, -2.0, 0.5]
    dst[:, :3] = rng.normal(size=(5, 3, 3)) * 10  # outliers
    w = np.ones((5, 10))
    w[:, :3] = 0
    fit = fit_rigid(src, dst, w, with_scale=True)
    np.testing.assert_allclose(fit.scale, 2.0, rtol=1e-12)
    np.testing.assert_allclose(fit.rotation, R, atol=1e-12)
    np.testing.assert_allclose(fit.translation, np.tile([1.0, -2.0, 0.5], (5, 1)), atol=1e-12)


def test_fit_rigid_flags_degenerate_sets():
    rng = np.random.default_rng(3)
    good = rng.normal(size=(4, 3))
    line = np.outer(np.arange(4.0), [1.0, 2.0, 3.0])
    same = np.ones((4, 3))
    src = np.stack([good, line, same])
    fit = fit_rigid(src, src + 1.0, with_scale=True)
    np.testing.assert_array_equal(fit.valid, [True, False, False])
    assert np.all(np.isfinite(fit.rotation)) and np.all(np.isfinite(fit.scale))


def test_fit_rigid_rejects_bad_shapes():
    a = np.zeros((2, 4, 3))
    with pytest.raises(ValidationError, match=r"src: expected shape \(N, N, 3\)"):
        fit_rigid(a[0], a[0])
    with pytest.raises(ValidationError, match=r"dst: expected shape \(2, 4, 3\)"):
        fit_rigid(a, a[:, :3])
    with pytest.raises(ValidationError, match=r"weights: expected shape \(2, 4\)"):
        fit_rigid(a, a, np.ones((2, 3)))


# -- rotations -----------------------------------------------------------------------------------
def test_rodrigues_round_trip_against_scipy_and_opencv():
    import cv2
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(4)
    for R in random_rotations(rng, 20):
        rvec = rodrigues_from_rotation(R)
        assert rvec.shape == (3,) and np.linalg.norm(rvec) <= np.pi + 1e-12
        np.testing.assert_allclose(rotation_from_rodrigues(rvec), R, atol=1e-12)
        np.testing.assert_allclose(Rotation.from_rotvec(rvec).as_matrix(), R, atol=1e-12)
        np.testing.assert_allclose(cv2.Rodrigues(rvec)[0], R, atol=1e-12)
    np.testing.assert_array_equal(rotation_from_rodrigues([0, 0, 0]), np.eye(3))
    quarter = rotation_from_rodrigues([0.0, 0.0, np.pi / 2])
    np.testing.assert_allclose(quarter @ [1.0, 0, 0], [0, 1.0, 0], atol=1e-15)


def test_rodrigues_rejects_bad_input():
    with pytest.raises(ValidationError, match=r"rvec: expected shape \(3,\)"):
        rotation_from_rodrigues([1.0, 2.0])
    with pytest.raises(ValidationError, match="rvec: contains NaN"):
        rotation_from_rodrigues([np.nan, 0, 0])
    with pytest.raises(ValidationError, match=r"R: expected shape \(3, 3\)"):
        rodrigues_from_rotation(np.eye(4))


def test_mean_rotation_and_rotation_angle():
    rng = np.random.default_rng(5)
    R = random_rotations(rng, 1)[0]
    axis = np.array([0.0, 0.6, 0.8])
    Rs = np.stack([R @ rotation_from_rodrigues(a * axis) for a in (-0.2, 0.0, 0.2)])
    np.testing.assert_allclose(mean_rotation(Rs), R, atol=1e-12)
    np.testing.assert_allclose(
        rotation_angle_deg(Rs, R[None]), [11.459156, 0, 11.459156], atol=1e-5
    )
    assert rotation_angle_deg(R, R) == pytest.approx(0.0, abs=1e-5)


def test_axis_angles_of_a_rig():
    cams = [
        Camera.look_at("x", [-3.0, 0, 0], [0, 0, 0], (64, 48), 50.0),  # looks along +x
        Camera.look_at("y", [0, -3.0, 0], [0, 0, 0], (64, 48), 50.0),  # along +y
        Camera.look_at("-x", [3.0, 0, 0], [0, 0, 0], (64, 48), 50.0),  # along -x
    ]
    angles = axis_angles(CameraRig(cams))
    assert angles.shape == (3, 3)
    np.testing.assert_allclose(angles, [[0, 90, 180], [90, 0, 90], [180, 90, 0]], atol=1e-5)


# -- lens distortion -----------------------------------------------------------------------------
@pytest.mark.parametrize("lens", list(LENSES))
def test_undistort_inverts_distort(lens):
    """Undistortion inverts distortion to 1e-9 px wherever fixed-point steps lead Newton to the
    solution (the webcam's beyond a normalised radius of about 1.2: far outside its image)."""
    d = np.array([LENSES[lens]])
    half = 0.8 if lens == "webcam" else 0.9
    xy = np.random.default_rng(6).uniform(-half, half, size=(1, 5000, 2))
    xy_d = distort_normalized(xy, d)
    out = undistort_normalized(xy_d, d)
    assert out.shape == xy.shape
    np.testing.assert_allclose(out * FOCAL, xy * FOCAL, atol=1e-9)
    np.testing.assert_allclose(distort_normalized(out, d) * FOCAL, xy_d * FOCAL, atol=1e-9)


def test_undistort_matches_opencv():
    import cv2

    rng = np.random.default_rng(7)
    xy_d = rng.uniform(-0.6, 0.6, size=(300, 2))
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-14)
    for lens in ("webcam", "rational"):
        d = np.array(LENSES[lens])
        ref = cv2.undistortPoints(xy_d[:, None], np.eye(3), d, criteria=crit)[:, 0]
        np.testing.assert_allclose(undistort_normalized(xy_d, d), ref, atol=1e-9)


def test_undistort_broadcasts_over_cameras_and_keeps_nan():
    rng = np.random.default_rng(8)
    dist = np.array(list(LENSES.values()))  # (C, 8)
    C = len(dist)
    xy_d = rng.uniform(-0.5, 0.5, size=(C, 200, 2))
    xy_d[2, 5] = np.nan
    out = undistort_normalized(xy_d, dist)
    assert out.shape == (C, 200, 2)
    for c in range(C):
        np.testing.assert_allclose(out[c], undistort_normalized(xy_d[c], dist[c]), atol=1e-15)
    assert np.isnan(out[2, 5]).all() and np.isfinite(np.delete(out[2], 5, axis=0)).all()
    # No distortion: a copy of the input.
    same = undistort_normalized(xy_d, np.zeros((C, 8)))
    np.testing.assert_array_equal(same, xy_d)
    assert same is not xy_d


def test_undistort_solves_far_points_again(monkeypatch):
    """Regression: far out in a strong pincushion lens, three fixed-point steps leave Newton too
    far from the solution to converge; those entries are solved again from 30 fixed-point steps."""
    d = np.array([0.57, 0.54, -0.0085, 0.0032, -0.24, 0, 0, 0])
    xy = np.array([[0.01, -0.966], [0.3, 0.2]])
    xy_d = distort_normalized(xy, d)
    np.testing.assert_allclose(undistort_normalized(xy_d, d), xy, atol=1e-12)
    monkeypatch.setattr(geometry, "_UNDISTORT_FIXED_POINT_SLOW", geometry._UNDISTORT_FIXED_POINT)
    assert np.abs(undistort_normalized(xy_d, d)[0] - xy[0]).max() > 1e-3


def test_zero_distortion_shortcut_equals_the_model_bit_for_bit():
    """With all coefficients zero the model is skipped; the values are the model's, including
    NaN rows, NaN in one coordinate, infinities and radii near overflow."""
    rng = np.random.default_rng(3)
    xy = rng.normal(size=(4, 500, 2)) * 10.0 ** rng.integers(-3, 160, (4, 500, 2))
    xy[0, :5] = np.nan
    xy[1, :5, 0] = np.nan
    xy[2, :5] = np.inf
    xy[3, :3] = [1e151, 1e151]  # r2 finite, r2 + 2 x^2 still finite
    xy[3, 3:6] = [1e154, 0.0]  # r2 overflows
    zeros = np.zeros((4, 8))
    x, y = xy[..., 0], xy[..., 1]
    with np.errstate(invalid="ignore", over="ignore"):
        got = geometry.distort_normalized(xy, zeros)
        model = geometry._distort(x, y, x * x + y * y, zeros[:, None, :])
    np.testing.assert_array_equal(got, model)
    assert np.isnan(got[1, :5]).all() and np.isnan(got[2, :5]).all()
    assert np.isfinite(got[3, :3]).all() and np.isnan(got[3, 3:6, 0]).all()


# -- the up axis ---------------------------------------------------------------------------------
def _moved(rig: CameraRig, Q: np.ndarray) -> CameraRig:
    """The rig in a world frame rotated by ``Q`` (``X' = Q X``)."""
    return CameraRig([Camera(c.name, c.K, c.R @ Q.T, Q @ c.C, c.size, c.dist) for c in rig])


def _rolled(rig: CameraRig, deg: float) -> CameraRig:
    """Every camera turned about its optical axis (a portrait mount for +-90)."""
    a = np.radians(deg)
    Rz = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1.0]])
    return CameraRig([Camera(c.name, c.K, Rz @ c.R, c.C, c.size, c.dist) for c in rig])


Y_DOWN = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])  # world z -> -y (a camera's frame)


def test_detect_up_on_rings_in_any_frame():
    from helpers.rigs import ring_rig

    from pointtraj.geometry import detect_up
    from pointtraj.synth.presets import make_rig

    ring = ring_rig(8, heights=(2.0, 1.6))  # looking down at (0, 0, 1)
    for rig, expected in (
        (ring, [0, 0, 1]),
        (_moved(ring, Y_DOWN), [0, -1, 0]),  # a y-down world (caliscope's camera frame)
        (_rolled(ring, 90), [0, 0, 1]),  # portrait cameras: the ring's plane, not image-up
        (_moved(_rolled(ring, -90), Y_DOWN), [0, -1, 0]),
    ):
        up, how = detect_up(rig)
        np.testing.assert_allclose(up, expected, atol=1e-9)
        assert "plane of the 8 camera centres" in how
    # paper69: two rings at different heights, not one plane: its cameras are level.
    up, how = detect_up(_moved(make_rig("paper69"), Y_DOWN))
    np.testing.assert_allclose(up, [0, -1, 0], atol=1e-9)
    assert how.startswith("normal of the 69 cameras' image rows")
    # A frontal arc of 4 cameras looking 25 degrees down: their mean image-up leans towards
    # the subject, the normal of their image rows does not.
    arc = _moved(ring_rig(angles=np.radians([0, 20, 40, 60]), heights=(2.4,)), Y_DOWN)
    up, how = detect_up(arc)
    np.testing.assert_allclose(up, [0, -1, 0], atol=1e-9)
    mean_up = -arc.R[:, 1].mean(axis=0)
    assert np.degrees(np.arccos(mean_up @ up / np.linalg.norm(mean_up))) > 20


def test_detect_up_fallbacks():
    from helpers.rigs import ring_rig

    from pointtraj.geometry import detect_up

    # Two cameras facing one way, both upright: their image-up vectors agree.
    pair = _moved(ring_rig(angles=[0.0, 0.0], heights=(1.0, 1.5)), Y_DOWN)
    up, how = detect_up(pair)
    assert up @ [0, -1, 0] > 0.99 and how.startswith("mean image-up")
    # One camera upright, one upside down, level: the up axis is known, its sign is not.
    upright, upside_down = ring_rig(angles=[0.0]), _rolled(ring_rig(angles=[0.5]), 180)
    up, how = detect_up(CameraRig([upright[0], upside_down[0].with_name("c1")]))
    np.testing.assert_allclose(up, [0, 0, 1], atol=1e-9)
    assert "sign ambiguous" in how
    # The same, both facing one way: no guess; +z, and the reason says so.
    same_way = _rolled(ring_rig(angles=[0.0]), 180)[0].with_name("c1")
    up, how = detect_up(CameraRig([upright[0], same_way]))
    np.testing.assert_array_equal(up, [0, 0, 1])
    assert "give no up direction" in how and "set up to choose" in how


def test_parse_and_resolve_up():
    from helpers.rigs import ring_rig

    from pointtraj.geometry import parse_up, resolve_up

    assert parse_up("auto") is None
    np.testing.assert_array_equal(parse_up("-y"), [0, -1, 0])
    np.testing.assert_array_equal(parse_up("Z"), [0, 0, 1])
    np.testing.assert_allclose(parse_up([3, 0, 4]), [0.6, 0, 0.8])
    for bad in ("up", [0, 0, 0], [1, 2], True, [np.nan, 0, 1]):
        with pytest.raises(ValidationError, match=r"where: expected 'auto', one of \+x, -x"):
            parse_up(bad, "where")
    up, how = resolve_up("+x", ring_rig(4))
    np.testing.assert_array_equal(up, [1, 0, 0])
    assert how == "up = '+x'"
    up, how = resolve_up("auto", None)
    np.testing.assert_array_equal(up, [0, 0, 1])
    up, _ = resolve_up("auto", _moved(ring_rig(6), Y_DOWN))
    np.testing.assert_allclose(up, [0, -1, 0], atol=1e-9)


def test_finite_rows_and_pixel_distance_are_numpys_values():
    """The column-by-column forms give what the reductions over the last axis give."""
    rng = np.random.default_rng(2)
    a = rng.normal(0, 100, size=(7, 300, 2))
    b = rng.normal(0, 100, size=(7, 300, 2)).astype(np.float32)
    a[rng.random(a.shape) < 0.2] = np.nan  # one coordinate or both
    a[0, :3] = [np.inf, 1.0]
    b[1, :3] = [-np.inf, 2.0]
    np.testing.assert_array_equal(geometry.finite_rows(a), np.all(np.isfinite(a), axis=-1))
    xyz = rng.normal(size=(50, 3))
    xyz[::7, 1] = np.nan
    np.testing.assert_array_equal(geometry.finite_rows(xyz), np.all(np.isfinite(xyz), axis=1))
    assert geometry.finite_rows(np.zeros((4, 0))).tolist() == [True] * 4
    with np.errstate(invalid="ignore"):
        want = np.linalg.norm(a - b, axis=-1)
    np.testing.assert_array_equal(geometry.pixel_distance(a, b), want)


@pytest.mark.parametrize("k", [None, 1, 3])
def test_observed_first_lists_each_columns_true_rows_as_a_stable_sort_does(k):
    from pointtraj.geometry import observed_first

    rng = np.random.default_rng(2)
    observed = rng.random((9, 500)) < 0.3
    observed[:, 0] = False  # a point no camera observes
    observed[:, 1] = True  # one every camera does
    got = observed_first(observed, k)
    want = np.argsort(~observed, axis=0, kind="stable")[:k]
    assert got.shape == want.shape
    rows = np.arange(len(got))[:, None] < observed.sum(axis=0)[None]  # the True rows listed
    np.testing.assert_array_equal(got[rows], want[rows])
    assert rows[:, 1].all() and not rows[:, 0].any()
    assert np.all((got >= 0) & (got < 9))  # the rest is a valid index
