"""Tests of pointtraj.camera: projection, distortion, masks, validation."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from pointtraj.camera import (
    Camera,
    CameraRig,
    distort_normalized,
    rodrigues_from_rotation,
    rotation_from_rodrigues,
    undistort_normalized,
)
from pointtraj.errors import ValidationError

#: caliscope_board_4cam cam_0 (a real webcam with strong barrel distortion), from its camera_array.toml.
CALISCOPE_K = np.array(
    [
        [903.550124089999, 0.0, 618.3086297620227],
        [0.0, 907.8788668762852, 394.213230569746],
        [0, 0, 1],
    ]
)
CALISCOPE_DIST = np.array(
    [
        -0.3320992998866297,
        0.04641968621160267,
        -0.004295771569519648,
        0.004113240100199701,
        0.0665682301495769,
    ]
)
RATIONAL_DIST = np.array([0.12, -0.05, 0.001, -0.002, 0.01, 0.03, -0.01, 0.002])


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def make_rig(rng: np.random.Generator, dists: list[np.ndarray]) -> CameraRig:
    """Cameras on a circle of radius 3 m looking at the origin, with the given distortions."""
    cams = []
    for i, d in enumerate(dists):
        a = 2 * np.pi * i / len(dists)
        centre = [3 * np.cos(a), 3 * np.sin(a), 1.0 + 0.2 * rng.normal()]
        cams.append(Camera.look_at(f"cam{i}", centre, [0, 0, 1.0], (640, 480), 500.0, dist=d))
    return CameraRig(cams)


def random_points(rng: np.random.Generator, n: int) -> np.ndarray:
    return rng.uniform(-0.5, 0.5, size=(n, 3)) + [0, 0, 1.0]


@pytest.mark.parametrize(
    "dist", [np.zeros(8), CALISCOPE_DIST, RATIONAL_DIST], ids=["none", "k5", "k8"]
)
def test_project_matches_opencv(dist):
    rng = np.random.default_rng(0)
    rig = make_rig(rng, [dist] * 3)
    X = random_points(rng, 200)
    proj = rig.project(X)
    assert proj.pixels.shape == (3, 200, 2)
    assert proj.depth.shape == (3, 200) and proj.in_image.shape == (3, 200)
    for c, cam in enumerate(rig):
        rvec, _ = cv2.Rodrigues(cam.R)
        ref, _ = cv2.projectPoints(X, rvec, cam.t, cam.K, cam.dist)
        np.testing.assert_allclose(proj.pixels[c], ref[:, 0], atol=1e-9, rtol=0)
        np.testing.assert_allclose(proj.depth[c], (X - cam.C) @ cam.R[2], atol=1e-12)


def test_projection_matrix_agrees_without_distortion():
    rng = np.random.default_rng(1)
    rig = make_rig(rng, [np.zeros(8)] * 2)
    X = random_points(rng, 50)
    h = np.einsum("cij,nj->cni", rig.P, np.c_[X, np.ones(len(X))])
    np.testing.assert_allclose(rig.project(X).pixels, h[..., :2] / h[..., 2:], atol=1e-9)


@pytest.mark.parametrize(
    "dist", [np.zeros(8), CALISCOPE_DIST, RATIONAL_DIST], ids=["none", "k5", "k8"]
)
def test_project_then_rays_recovers_point(dist):
    rng = np.random.default_rng(2)
    rig = make_rig(rng, [dist] * 4)
    X = random_points(rng, 300)
    proj = rig.project(X)
    origins, dirs = rig.rays(proj.pixels)
    assert origins.shape == dirs.shape == (4, 300, 3)
    np.testing.assert_allclose(np.linalg.norm(dirs, axis=-1), 1.0, atol=1e-12)
    back = origins + dirs * (proj.depth / np.einsum("cnj,cj->cn", dirs, rig.R[:, 2]))[..., None]
    np.testing.assert_allclose(back, np.broadcast_to(X, back.shape), atol=1e-9)


def test_single_camera_methods_match_rig():
    rng = np.random.default_rng(3)
    rig = make_rig(rng, [CALISCOPE_DIST] * 2)
    X = random_points(rng, 20)
    pix, depth, inside = rig[1].project(X)
    proj = rig.project(X)
    np.testing.assert_array_equal(pix, proj.pixels[1])
    o, d = rig[1].rays(pix)
    np.testing.assert_allclose(o, np.broadcast_to(rig[1].C, o.shape))
    ideal = rig[1].undistort_pixels(pix)
    h = (rig[1].P @ np.c_[X, np.ones(20)].T).T
    np.testing.assert_allclose(ideal, h[:, :2] / h[:, 2:], atol=1e-8)


@pytest.mark.parametrize("dist", [CALISCOPE_DIST, RATIONAL_DIST], ids=["k5-caliscope", "k8"])
def test_distort_undistort_identity(dist):
    """Undistorting every pixel of a real 1280x720 webcam (k1 = -0.33) and distorting back."""
    u, v = np.meshgrid(np.linspace(0, 1279, 64), np.linspace(0, 719, 36))
    pix = np.stack([u.ravel(), v.ravel()], axis=-1)
    xy_d = (pix - CALISCOPE_K[:2, 2]) / np.diag(CALISCOPE_K)[:2]
    d8 = np.zeros(8)
    d8[: len(dist)] = dist
    xy = undistort_normalized(xy_d, d8)
    np.testing.assert_allclose(distort_normalized(xy, d8), xy_d, atol=1e-12)
    # and the other way round, from undistorted coordinates
    xy2 = np.random.default_rng(4).uniform(-0.6, 0.6, size=(500, 2))
    np.testing.assert_allclose(
        undistort_normalized(distort_normalized(xy2, d8), d8), xy2, atol=1e-10
    )


def test_undistort_matches_opencv():
    rng = np.random.default_rng(5)
    pix = rng.uniform([0, 0], [1279, 719], size=(200, 2))
    cam = Camera.from_extrinsics(
        "c", CALISCOPE_K, np.eye(3), np.zeros(3), (1280, 720), CALISCOPE_DIST
    )
    ref = cv2.undistortPoints(
        pix[:, None],
        CALISCOPE_K,
        CALISCOPE_DIST,
        P=CALISCOPE_K,
        criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-14),
    )[:, 0]
    np.testing.assert_allclose(cam.undistort_pixels(pix), ref, atol=1e-6)


def test_in_image_mask():
    cam = Camera.look_at("c", [0, -3, 0], [0, 0, 0], (640, 480), 500.0)
    rig = CameraRig([cam])
    X = np.array(
        [
            [0.0, 0.0, 0.0],  # centre of view
            [0.0, -4.0, 0.0],  # behind the camera
            [5.0, 0.0, 0.0],  # in front, far right of the image
            [0.0, 0.0, -0.5],  # in front, below the centre, inside
        ]
    )
    proj = rig.project(X)
    np.testing.assert_array_equal(proj.in_image[0], [True, False, False, True])
    assert proj.depth[0, 1] < 0
    assert np.all(np.isnan(proj.pixels[0, 1]))  # behind the camera: no pixel
    # right at the image border (pixel w - 0.5 is outside, w - 0.51 inside)
    o, d = cam.rays([[639.49, 240.0], [-0.49, 0.0]])
    assert rig.project(o + 2 * d).in_image.all()


def test_in_image_mask_rejects_fold_back():
    """A lens that folds back: a point far outside the field of view lands inside the image.

    With k1 = -0.5, k2 = 0.1 the distorted radius peaks at 0.6 (r = 1) and comes back to 0.566
    at r = 1.4, inside the 640x480 image at f = 500; such points must not count as in the image.
    """
    dist = np.array([-0.5, 0.1, 0, 0, 0])
    cam = Camera.from_extrinsics(
        "c", [[500, 0, 319.5], [0, 500, 239.5], [0, 0, 1]], np.eye(3), np.zeros(3), (640, 480), dist
    )
    X = np.array([[1.4, 0.0, 1.0], [1.5, 0.1, 1.0], [0.3, 0.1, 1.0]])
    pix, depth, inside = cam.project(X)
    assert np.all((pix >= 0) & (pix < [640, 480]))  # the folded points project "inside" ...
    np.testing.assert_array_equal(inside, [False, False, True])  # ... but are masked out


def test_in_image_mask_keeps_whole_image_of_strong_lens():
    """Every pixel of the real k1 = -0.33 webcam, back-projected, projects in the image."""
    cam = Camera.from_extrinsics(
        "c", CALISCOPE_K, np.eye(3), np.zeros(3), (1280, 720), CALISCOPE_DIST
    )
    u, v = np.meshgrid(np.linspace(-0.45, 1279.45, 80), np.linspace(-0.45, 719.45, 45))
    pix = np.stack([u.ravel(), v.ravel()], axis=-1)
    o, d = cam.rays(pix)
    back, _, inside = cam.project(o + 3.0 * d)
    np.testing.assert_allclose(back, pix, atol=1e-9)
    assert inside.all()


def test_nan_propagation():
    rng = np.random.default_rng(6)
    rig = make_rig(rng, [CALISCOPE_DIST] * 2)
    X = random_points(rng, 5)
    X[2] = np.nan
    proj = rig.project(X)
    assert np.all(np.isnan(proj.pixels[:, 2])) and not proj.in_image[:, 2].any()
    assert np.all(np.isfinite(proj.pixels[:, [0, 1, 3, 4]]))
    pix = proj.pixels.copy()
    o, d = rig.rays(pix)
    assert np.all(np.isnan(d[:, 2])) and np.all(np.isfinite(d[:, [0, 1, 3, 4]]))
    obs = pix.copy()
    obs[0, 1] = np.nan
    err = rig.reprojection_errors(X, obs)
    assert err.shape == (2, 5)
    assert np.isnan(err[0, 1]) and np.isnan(err[:, 2]).all()
    np.testing.assert_allclose(err[1, [0, 1, 3, 4]], 0, atol=1e-9)


def test_rodrigues_round_trip():
    rng = np.random.default_rng(7)
    for _ in range(20):
        R = random_rotation(rng)
        np.testing.assert_allclose(
            rotation_from_rodrigues(rodrigues_from_rotation(R)), R, atol=1e-12
        )
        rvec = rodrigues_from_rotation(R)
        np.testing.assert_allclose(cv2.Rodrigues(rvec)[0], R, atol=1e-12)
    np.testing.assert_array_equal(rotation_from_rodrigues([0, 0, 0]), np.eye(3))


def test_from_extrinsics_and_t():
    rng = np.random.default_rng(8)
    R = random_rotation(rng)
    t = rng.normal(size=3)
    cam = Camera.from_extrinsics("c", CALISCOPE_K, R, t, (1280, 720), CALISCOPE_DIST)
    np.testing.assert_allclose(cam.t, t, atol=1e-12)
    np.testing.assert_allclose(cam.C, -R.T @ t, atol=1e-12)
    assert cam.dist.shape == (8,) and cam.has_distortion
    np.testing.assert_allclose(cam.viewing_direction, R[2])
    assert cam.with_name("d").name == "d"
    with pytest.raises(ValueError):
        cam.K[0, 0] = 1.0  # read-only


GOOD = dict(K=CALISCOPE_K, R=np.eye(3), C=np.zeros(3), size=(1280, 720))


@pytest.mark.parametrize(
    ("change", "match"),
    [
        ({"K": np.eye(3)[:2]}, r"K: expected shape \(3, 3\), got \(2, 3\)"),
        ({"R": np.eye(4)}, r"R: expected shape \(3, 3\)"),
        ({"C": np.zeros(2)}, r"C: expected shape \(3,\)"),
        ({"R": np.diag([1.0, 2.0, 1.0])}, "not a rotation"),
        ({"R": np.diag([1.0, 1.0, -1.0])}, r"det R = -1"),
        ({"K": np.diag([-500.0, 500.0, 1.0])}, "focal lengths must be positive"),
        ({"K": np.diag([500.0, 0.0, 1.0])}, "focal lengths must be positive"),
        ({"K": [[500, 0, 1], [0, 500, 1], [0, 1, 1]]}, "upper triangular"),
        ({"size": (0, 720)}, "image size must be positive"),
        ({"size": (1280,)}, "size must be"),
        ({"dist": np.zeros(3)}, "0, 4, 5 or 8 coefficients"),
        ({"dist": np.zeros(6)}, "got 6"),
        ({"dist": [np.nan, 0, 0, 0]}, "NaN"),
        ({"C": [np.nan, 0, 0]}, "NaN"),
        ({"name": "a/b"}, "without slashes"),
        ({"name": ""}, "non-empty"),
    ],
)
def test_camera_validation(change, match):
    kwargs = {"name": "c", **GOOD, **change}
    with pytest.raises(ValidationError, match=match):
        Camera(**kwargs)


def test_rig_validation_and_access():
    a = Camera.look_at("a", [2, 0, 1], [0, 0, 1], (64, 48), 50.0)
    b = Camera.look_at("b", [0, 2, 1], [0, 0, 1], (64, 48), 50.0)
    with pytest.raises(ValidationError, match="duplicate camera names in rig: a"):
        CameraRig([a, b, a.with_name("a")])
    with pytest.raises(ValidationError, match="at least one camera"):
        CameraRig([])
    with pytest.raises(ValidationError, match="expects Camera objects"):
        CameraRig([a, "b"])
    rig = CameraRig([a, b])
    assert rig.names == ["a", "b"] and rig.index("b") == 1 and rig["b"] is b
    assert rig.subset(["b"]).names == ["b"] and rig[1:].names == ["b"]
    assert (
        rig.K.shape == (2, 3, 3)
        and rig.dist.shape == (2, 8)
        and rig.sizes.tolist() == [[64, 48]] * 2
    )
    with pytest.raises(ValidationError, match="no camera named 'z'"):
        rig.index("z")
    with pytest.raises(ValidationError, match=r"points: expected shape \(N, 3\)"):
        rig.project(np.zeros((4, 2)))
    with pytest.raises(ValidationError, match=r"pixels: expected shape \(2, N, 2\)"):
        rig.rays(np.zeros((3, 4, 2)))


def test_look_at_points_at_target():
    cam = Camera.look_at("c", [1.0, 2.0, 3.0], [0.0, 0.0, 1.0], (101, 81), 80.0)
    pix, depth, inside = cam.project([[0.0, 0.0, 1.0], [0.0, 0.0, 2.0]])
    np.testing.assert_allclose(pix[0], [50.0, 40.0], atol=1e-9)
    assert inside.all() and depth[0] > 0
    assert pix[1, 1] < 40.0  # world up is image up
    with pytest.raises(ValidationError, match="coincide"):
        Camera.look_at("c", [1, 1, 1], [1, 1, 1], (10, 10), 5.0)


@pytest.mark.parametrize("share", [0.02, 0.1, 0.5, 1.0])
def test_sparse_undistortion_gives_the_dense_values_bit_for_bit(share, monkeypatch):
    """Mostly-NaN pixels (each camera observes a few points) are undistorted one by one, with
    each camera's K and lens: the same bits as the whole-array form, on a rig mixing lenses
    and pinholes, with pixels far outside the images too."""
    import pointtraj.camera as camera

    rng = np.random.default_rng(11)
    rig = make_rig(rng, [CALISCOPE_DIST, RATIONAL_DIST, [0.0] * 5, CALISCOPE_DIST])
    pix = rng.uniform([-300, -300], [1600, 1000], size=(len(rig), 5000, 2))
    pix[rng.random((len(rig), 5000)) > share] = np.nan
    pix[2] = np.nan  # a camera with no pixel
    sparse = (rig.undistort_pixels(pix), rig.normalized(pix))
    cams, cols, ideal = rig.undistort_observed(pix)
    monkeypatch.setattr(camera, "SPARSE_UNDISTORT", 0.0)  # the whole-array form
    dense = (rig.undistort_pixels(pix), rig.normalized(pix))
    for a, b in zip(sparse, dense, strict=True):
        np.testing.assert_array_equal(a, b)
    ok = np.all(np.isfinite(pix), axis=2)
    np.testing.assert_array_equal(np.stack(np.nonzero(ok)), np.stack([cams, cols]))
    np.testing.assert_array_equal(ideal, dense[0][cams, cols])
    assert not np.isin(2, cams)
    shuffled = rng.permutation(len(cams))  # rows in any camera order
    np.testing.assert_array_equal(
        rig._ideal(cams[shuffled], pix[cams[shuffled], cols[shuffled]]), ideal[shuffled]
    )


def test_undistortion_without_lenses_gives_the_pixels_back():
    """A rig without lens models has nothing to undistort: the pixels come back as a float64
    copy, NaN in place, within rounding of the round trip through normalised coordinates."""
    rng = np.random.default_rng(12)
    rig = make_rig(rng, [[0.0] * 5] * 3)
    pix = rng.uniform([-300, -300], [1600, 1000], size=(3, 400, 2)).astype(np.float32)
    pix[rng.random((3, 400)) > 0.3] = np.nan
    out = rig.undistort_pixels(pix)
    assert out.dtype == np.float64 and not np.shares_memory(out, pix)
    np.testing.assert_array_equal(out, pix.astype(np.float64))
    cams, cols, ideal = rig.undistort_observed(pix)
    np.testing.assert_array_equal(ideal, pix[cams, cols].astype(np.float64))
    trip = np.concatenate([rig.normalized(pix), np.ones((3, 400, 1))], axis=-1) @ np.swapaxes(
        rig.K, 1, 2
    )
    np.testing.assert_allclose(out, trip[..., :2], atol=1e-9)


@pytest.mark.parametrize("dist", [np.zeros(8), np.array([-0.2, 0.05, 0.001, -0.002, 0.0])])
def test_resized_projects_like_resized_pixels(dist):
    """A camera resized by s sees a point where OpenCV's resize moves its pixel:
    ``u' = (u + 0.5) s - 0.5`` (the rounded size's ratio on each axis)."""
    cam = Camera.look_at("c", [0, -3, 1], [0, 0, 1], size=(640, 480), focal=500.0)
    cam = Camera(cam.name, cam.K, cam.R, cam.C, cam.size, dist)
    X = np.array([[0.1, 0.2, 1.0], [-0.3, 0.1, 1.4]])
    uv, _, _ = cam.project(X)
    for s in (0.25, 0.5, 2.0):
        small = cam.resized(s)
        assert small.size == (round(640 * s), round(480 * s)) and small.name == "c"
        np.testing.assert_allclose(small.project(X)[0], (uv + 0.5) * s - 0.5, atol=1e-9)
        np.testing.assert_array_equal(small.dist, cam.dist)
    odd = Camera.look_at("o", [0, -3, 1], [0, 0, 1], size=(641, 481), focal=500.0)
    half = odd.resized(0.5)  # 320.5 x 240.5 rounds to 320 x 240: each axis by its own ratio
    assert half.size == (320, 240)
    np.testing.assert_allclose(half.K[0, 0], 500.0 * 320 / 641)
    np.testing.assert_allclose(half.K[1, 1], 500.0 * 240 / 481)
    with pytest.raises(ValidationError, match="scale must be positive"):
        cam.resized(0.0)
