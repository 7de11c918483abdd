"""Rig calibration: similarity alignment, ChArUco, and pycolmap SfM on a rendered capture."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from helpers.rigs import ring_rig

from pointtraj.calibrate import (
    Calibration,
    CalibrationError,
    CalibrationOptions,
    CharucoBoard,
    align_rig_to,
    align_rig_to_charuco,
    calibrate_charuco,
    calibrate_images,
    compare_rigs,
    detect_charuco,
    estimate_rig_similarity,
    find_degenerate_cameras,
    scale_rig_by_distance,
    transform_rig,
    umeyama,
)
from pointtraj.calibrate.sfm import _opencv_from_colmap
from pointtraj.camera import Camera, CameraRig
from pointtraj.errors import FileFormatError, ValidationError
from pointtraj.geometry import rotation_from_rodrigues

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
CALISCOPE = SHARED / "data" / "caliscope_board_4cam"


def ring(n: int, radius: float = 2.0) -> CameraRig:
    """``n`` 640x480 cameras (f = 500 px) at heights 1.0 and 1.3 m looking at (0, 0, 0.8)."""
    return ring_rig(
        radius=radius,
        heights=(1.0, 1.3),
        target=(0, 0, 0.8),
        angles=np.linspace(0, 2 * np.pi, n, endpoint=False),
    )


def random_similarity(rng: np.random.Generator) -> tuple[float, np.ndarray, np.ndarray]:
    return (
        float(rng.uniform(0.3, 3.0)),
        rotation_from_rodrigues(rng.normal(size=3)),
        rng.normal(size=3),
    )


def test_umeyama_recovers_similarity_and_rejects_degenerate_input():
    rng = np.random.default_rng(1)
    src = rng.normal(size=(20, 3))
    s, R, t = random_similarity(rng)
    dst = s * src @ R.T + t
    s2, R2, t2 = umeyama(src, dst)
    assert s2 == pytest.approx(s, rel=1e-10)
    np.testing.assert_allclose(R2, R, atol=1e-10)
    np.testing.assert_allclose(t2, t, atol=1e-10)
    assert np.linalg.det(R2) == pytest.approx(1.0)
    # Rigid fit keeps s = 1.
    assert umeyama(src, src @ R.T + t, with_scale=False)[0] == 1.0
    with pytest.raises(ValidationError, match="at least 3"):
        umeyama(src[:2], dst[:2])
    with pytest.raises(ValidationError, match="degenerate"):
        line = np.outer(np.arange(5.0), [1.0, 2.0, 3.0])
        umeyama(line, line)
    with pytest.raises(ValidationError, match="dst"):
        umeyama(src, dst[:5])


def test_transform_rig_keeps_every_projection():
    rng = np.random.default_rng(2)
    rig = ring(5)
    s, R, t = random_similarity(rng)
    X = rng.uniform(-0.5, 0.5, size=(50, 3)) + [0, 0, 0.8]
    moved = transform_rig(rig, s, R, t)
    np.testing.assert_allclose(
        moved.project(s * X @ R.T + t).pixels, rig.project(X).pixels, atol=1e-8
    )
    np.testing.assert_allclose(moved.C, s * rig.C @ R.T + t, atol=1e-12)
    with pytest.raises(ValidationError, match="positive"):
        transform_rig(rig, -1.0, R, t)


def test_align_and_compare_round_trip():
    rng = np.random.default_rng(3)
    ref = ring(6)
    s, R, t = random_similarity(rng)
    est = transform_rig(ref, s, R, t)
    aligned, (s2, _, _) = align_rig_to(est, ref)
    assert s2 == pytest.approx(1 / s, rel=1e-9)
    np.testing.assert_allclose(aligned.C, ref.C, atol=1e-9)
    cmp = compare_rigs(est, ref)
    summary = cmp.summary()
    assert summary["cameras"] == 6
    assert summary["rotation_deg_max"] < 1e-5 and summary["centre_mm_max"] < 1e-6
    assert summary["focal_pct_max"] == 0.0 and summary["distortion_px_rms_max"] == 0.0
    # Two shared cameras: orientation + baseline.
    two = align_rig_to(est.subset(["c0", "c3"]), ref)[0]
    np.testing.assert_allclose(two.C, ref.subset(["c0", "c3"]).C, atol=1e-9)
    with pytest.raises(ValidationError, match="share 0 camera"):
        align_rig_to(est, CameraRig([ref[0].with_name("zz")]))


def test_compare_rigs_measures_perturbations():
    ref = ring(4)
    cams = list(ref)
    K = cams[1].K.copy()
    K[0, 0] *= 1.01
    K[1, 1] *= 1.01
    cams[1] = Camera(cams[1].name, K, cams[1].R, cams[1].C + [0.01, 0, 0], size=cams[1].size)
    cmp = compare_rigs(CameraRig(cams), ref, align=False)
    assert cmp.focal_rel[1] == pytest.approx(0.01)
    assert cmp.centre_m[1] == pytest.approx(0.01)
    assert cmp.centre_m[0] == 0.0


def wreck(cam: Camera, focal: float | None = None, shift=(0.0, 0.0, 0.0)) -> Camera:
    """A copy of ``cam`` with another focal length and/or a moved centre and tilted axes."""
    K = cam.K.copy()
    if focal is not None:
        K[0, 0] = K[1, 1] = focal
    R = rotation_from_rodrigues([0.0, 0.3, 0.0]) @ cam.R if any(shift) else cam.R
    return Camera(cam.name, K, R, cam.C + np.asarray(shift), size=cam.size, dist=cam.dist)


def test_outlier_camera_does_not_spoil_the_alignment():
    """Regression: one badly placed camera (SfM gave ring12's cam03 a 10 px focal length and a
    wrong pose) skewed the unweighted Umeyama fit, so every good camera showed ~7.6 deg and
    0.5-0.9 m of error. The robust fit leaves it out and aligns the others exactly."""
    rng = np.random.default_rng(7)
    ref = ring(12, radius=2.5)
    cams = list(ref)
    cams[3] = wreck(cams[3], focal=10.3, shift=(0.9, -1.4, 0.7))
    est = transform_rig(CameraRig(cams), *random_similarity(rng))
    # Without the robust fit the good cameras are off (what the bug did).
    plain = compare_rigs(est, ref, robust=False)
    good = np.arange(12) != 3
    assert plain.centre_m[good].max() > 0.05 and plain.alignment_outliers == []
    cmp = compare_rigs(est, ref)
    assert cmp.alignment_outliers == ["c3"]
    assert cmp.rotation_deg[good].max() < 1e-5 and cmp.centre_m[good].max() < 1e-9
    assert cmp.centre_m[3] > 1.0  # still compared, and shown to be wrong
    assert cmp.summary()["alignment_outliers"] == 1.0
    fit = estimate_rig_similarity(est, ref)
    assert fit.outliers == ["c3"] and len(fit.inliers) == 11
    assert fit.residual_m["c3"] > fit.threshold_m > max(fit.residual_m["c0"], 1e-9)
    np.testing.assert_allclose(align_rig_to(est, ref)[0].C[good], ref.C[good], atol=1e-9)


def test_robust_alignment_keeps_noisy_but_consistent_cameras():
    """Centre noise of a few mm everywhere: no camera is an outlier, and the fit is the plain
    least-squares one."""
    rng = np.random.default_rng(8)
    ref = ring(8)
    noisy = CameraRig(
        [Camera(c.name, c.K, c.R, c.C + rng.normal(scale=0.004, size=3), size=c.size) for c in ref]
    )
    fit = estimate_rig_similarity(noisy, ref)
    assert fit.outliers == [] and len(fit.inliers) == 8
    plain = estimate_rig_similarity(noisy, ref, robust=False).similarity
    np.testing.assert_allclose(fit.similarity[1], plain[1], atol=1e-12)
    # Two outliers among 8 cameras are both found.
    cams = list(noisy)
    cams[1] = wreck(cams[1], shift=(0.5, 0.0, 0.0))
    cams[6] = wreck(cams[6], shift=(0.0, 0.0, -0.4))
    fit = estimate_rig_similarity(CameraRig(cams), ref)
    assert fit.outliers == ["c1", "c6"]
    # With 3 shared cameras nothing can be told apart: all are used.
    assert estimate_rig_similarity(CameraRig(cams[:3]), ref).outliers == []


def fake_calibration(rig: CameraRig, errors=None, observations=None) -> Calibration:
    names = rig.names
    return Calibration(
        rig=rig,
        camera_names=names,
        errors=dict(zip(names, errors or [0.3] * len(rig), strict=True)),
        observations=dict(zip(names, observations or [2000] * len(rig), strict=True)),
        failed={},
        match_counts=np.zeros((len(rig), len(rig)), np.int64),
    )


def test_degenerate_cameras_are_found_with_the_reason():
    """Regression: pycolmap gave ring12's cam03 a focal length of 10.3 px (true 420 px) and the
    calibration accepted it."""
    ref = ring(6)
    assert find_degenerate_cameras(fake_calibration(ref)) == {}
    cams = list(ref)
    cams[3] = wreck(cams[3], focal=10.3)
    bad = find_degenerate_cameras(fake_calibration(CameraRig(cams)))
    assert list(bad) == ["c3"]
    assert "focal length 10.3 px" in bad["c3"] and "plausible: 0.1 to 10" in bad["c3"]
    cams[3] = Camera(
        ref[3].name, ref[3].K, ref[3].R, ref[3].C, size=ref[3].size, dist=[2.8, 0, 0, 0]
    )
    assert "distortion" in find_degenerate_cameras(fake_calibration(CameraRig(cams)))["c3"]
    errors = [0.3, 0.35, 0.28, 0.31, 2.5, 0.3]
    observations = [2000, 2100, 90, 1900, 2000, 2050]
    bad = find_degenerate_cameras(fake_calibration(ref, errors, observations))
    assert list(bad) == ["c2", "c4"]
    assert "90 observations" in bad["c2"] and "reprojection error 2.5 px" in bad["c4"]
    # A high error is not an outlier when every camera is as bad (ratio), nor below 1 px.
    assert find_degenerate_cameras(fake_calibration(ref, [2.0] * 6)) == {}
    assert find_degenerate_cameras(fake_calibration(ref, [0.1] * 5 + [0.9])) == {}
    with pytest.raises(ValidationError, match="min_focal_ratio"):
        CalibrationOptions(min_focal_ratio=5.0, max_focal_ratio=2.0)


def test_scale_rig_by_distance():
    rig = transform_rig(ring(4), 0.37, np.eye(3), np.zeros(3))
    scaled = scale_rig_by_distance(rig, "c0", "c2", 4.0)
    assert np.linalg.norm(scaled.C[0] - scaled.C[2]) == pytest.approx(4.0)
    with pytest.raises(ValidationError, match="'nope' is not in the calibrated rig"):
        scale_rig_by_distance(rig, "c0", "nope", 1.0)
    with pytest.raises(ValidationError, match="positive"):
        scale_rig_by_distance(rig, "c0", "c1", 0.0)


def test_colmap_intrinsics_shift_principal_point_by_half_a_pixel():
    K, dist = _opencv_from_colmap("RADIAL", np.array([500.0, 320.0, 240.0, 0.1, -0.02]))
    np.testing.assert_allclose(K, [[500, 0, 319.5], [0, 500, 239.5], [0, 0, 1]])
    np.testing.assert_allclose(dist, [0.1, -0.02, 0, 0, 0, 0, 0, 0])
    K, dist = _opencv_from_colmap("OPENCV", np.arange(1.0, 9.0))
    np.testing.assert_allclose(np.diag(K)[:2], [1, 2])
    np.testing.assert_allclose(dist[:4], [5, 6, 7, 8])
    with pytest.raises(ValidationError, match="unsupported"):
        _opencv_from_colmap("FISHEYE", np.ones(4))


def test_options_validate():
    with pytest.raises(ValidationError, match="choose from"):
        CalibrationOptions(camera_model="NOPE")
    with pytest.raises(ValidationError, match="num_threads"):
        CalibrationOptions(num_threads=0)


# ---------------------------------------------------------------------------------- ChArUco


def write_board_toml(path: Path) -> Path:
    path.write_text(
        'columns = 5\nrows = 7\ndictionary = "DICT_4X4_50"\nsquare_size_override_cm = 6.0\n'
        "aruco_scale = 0.75\ninverted = false\n"
    )
    return path


def render_board(rig: CameraRig, board: CharucoBoard, pose: tuple[np.ndarray, np.ndarray]):
    """Images of a planar board (plane -> image homography per camera, no distortion)."""
    import cv2

    R, t = pose  # X_world = R X_board + t
    ppm = 2000  # board image pixels per metre
    w_m, h_m = board.columns * board.square_m, board.rows * board.square_m
    art = board.cv_board().generateImage((int(w_m * ppm), int(h_m * ppm)), marginSize=0)
    # Board image pixel (u, v) -> board point (u / ppm, v / ppm, 0) (OpenCV board y points down
    # the image, as getChessboardCorners does).
    src = np.array([[0, 0], [art.shape[1], 0], [art.shape[1], art.shape[0]], [0, art.shape[0]]])
    corners = np.c_[src / ppm, np.zeros(4)] @ R.T + t
    images = []
    for cam in rig:
        dst = cam.project(corners)[0]
        H = cv2.getPerspectiveTransform(src.astype(np.float32) - 0.5, dst.astype(np.float32))
        img = cv2.warpPerspective(art, H, cam.size, borderValue=255, flags=cv2.INTER_AREA)
        images.append(np.repeat(img[..., None], 3, axis=2))
    return images


def board_pose(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    # Board facing the cameras on the +x side (board x -> world +y, board y -> world -z,
    # board z -> world -x), tilted at random, near the rig's centre.
    base = np.array([[0.0, 0, -1], [1, 0, 0], [0, -1, 0]])
    R = rotation_from_rodrigues(rng.normal(scale=0.25, size=3)) @ base
    return R, rng.uniform(-0.15, 0.15, size=3) + [0, -0.15, 0.6]


def test_charuco_board_toml_and_errors(tmp_path):
    board = CharucoBoard.from_toml(write_board_toml(tmp_path / "b.toml"))
    assert (board.columns, board.rows) == (5, 7)
    assert board.square_m == pytest.approx(0.06) and board.marker_m == pytest.approx(0.045)
    c = board.corners()
    assert c.shape == (24, 3) and np.all(c[:, 2] == 0)
    (tmp_path / "bad.toml").write_text('columns = 5\ndictionary = "DICT_4X4_50"\n')
    with pytest.raises(FileFormatError, match="missing field 'rows'"):
        CharucoBoard.from_toml(tmp_path / "bad.toml")
    with pytest.raises(FileFormatError, match="no such file"):
        CharucoBoard.from_toml(tmp_path / "missing.toml")


def test_charuco_detection_and_alignment_recover_scale_and_frame(tmp_path):
    board = CharucoBoard.from_toml(write_board_toml(tmp_path / "b.toml"))
    rig = CameraRig(
        [
            Camera.look_at(f"c{i}", [2.0, y, 0.7], [0, y / 3, 0.6], (640, 480), 700.0)
            for i, y in enumerate((-0.8, 0.0, 0.8))
        ]
    )
    rng = np.random.default_rng(4)
    poses = [board_pose(rng) for _ in range(3)]
    dets = {}
    for f, pose in enumerate(poses):
        for c, img in enumerate(render_board(rig, board, pose)):
            dets[(c, f)] = detect_charuco(img, board)
    ids, xy = dets[(1, 0)]
    assert len(ids) >= 20
    # Detections agree with the projected board corners.
    R, t = poses[0]
    truth = rig[1].project(board.corners()[ids] @ R.T + t)[0]
    err = np.linalg.norm(xy - truth, axis=1)
    assert err.max() < 1.0 and err.mean() < 0.5
    # An SfM-like rig (unknown similarity) is brought back to metric scale in the board frame.
    s, Rs, ts = random_similarity(rng)
    arbitrary = transform_rig(rig, s, Rs, ts)
    aligned, stats = align_rig_to_charuco(arbitrary, dets, board)
    assert stats["board_rms_mm"] < 5.0 and stats["frames"] == 3
    # Expected: the world frame is the board in the best frame.
    Rb, tb = poses[int(stats["reference_frame"])]
    expected = transform_rig(rig, 1.0, Rb.T, -Rb.T @ tb)
    # Metric scale from all frames: within 1 %.
    assert compare_rigs(aligned, expected).similarity[0] == pytest.approx(1.0, abs=0.01)
    # The frame comes from one noisy board pose (0.4 px corners, 3 mm triangulation noise over
    # a 24 x 36 cm board): a few tenths of a degree, i.e. ~2 cm at the cameras 2 m away.
    cmp = compare_rigs(aligned, expected, align=False)
    assert cmp.rotation_deg.max() < 1.0 and cmp.centre_m.max() < 0.04


def test_calibrate_charuco_recovers_intrinsics_and_poses(tmp_path):
    board = CharucoBoard.from_toml(write_board_toml(tmp_path / "b.toml"))
    rig = CameraRig(
        [
            Camera.look_at(f"c{i}", [1.6, y, 0.7], [0, y / 3, 0.6], (640, 480), f)
            for i, (y, f) in enumerate(((-0.6, 650.0), (0.0, 720.0), (0.6, 600.0)))
        ]
    )
    rng = np.random.default_rng(5)
    dets = {}
    for f in range(8):
        for c, img in enumerate(render_board(rig, board, board_pose(rng))):
            dets[(c, f)] = detect_charuco(img, board)
    cal, stats = calibrate_charuco(dets, board, rig.names, [tuple(s) for s in rig.sizes])
    assert stats["rms_px"] < 0.5
    assert len(cal.rig) == 3 and not cal.failed
    cmp = compare_rigs(cal.rig, rig)
    assert cmp.similarity[0] == pytest.approx(1.0, abs=0.01)  # metric from the board
    assert np.abs(cmp.focal_rel).max() < 0.01
    assert cmp.rotation_deg.max() < 0.3 and cmp.centre_m.max() < 0.01
    with pytest.raises(ValidationError, match="lens"):
        calibrate_charuco(dets, board, rig.names, [tuple(s) for s in rig.sizes], lens="odd")
    # Distortion beyond k1 is held at 0 for cameras whose board corners stay near the centre
    # (regression: caliscope's cam_3 got k2 = +2.78 from corners within 0.3 of the
    # half-diagonal, 761 px of distortion difference towards the image corners).
    sizes = [tuple(s) for s in rig.sizes]
    free, _ = calibrate_charuco(dets, board, rig.names, sizes, min_k2_coverage=0.0)
    held, stats = calibrate_charuco(dets, board, rig.names, sizes, min_k2_coverage=1.0)
    assert np.all(held.rig.dist[:, 1] == 0) and np.all(free.rig.dist[:, 1] != 0)
    assert "k1 only" in held.notes[-1] and all(n in held.notes[-1] for n in rig.names)
    assert 0 < stats["coverage_c0"] < 1
    assert compare_rigs(held.rig, rig).rotation_deg.max() < 0.3


# ---------------------------------------------------------------------------------- pycolmap


def test_missing_images_and_no_overlap(tmp_path):
    import cv2

    with pytest.raises(CalibrationError, match="does not exist"):
        calibrate_images(tmp_path / "nothing", tmp_path / "w")
    (tmp_path / "img" / "a").mkdir(parents=True)
    (tmp_path / "img" / "b").mkdir(parents=True)
    with pytest.raises(CalibrationError, match="missing images"):
        calibrate_images(tmp_path / "img", tmp_path / "w")
    rng = np.random.default_rng(6)
    for cam in ("a", "b"):  # unrelated noise images: features, but nothing in common
        img = (rng.random((120, 160)) * 255).astype(np.uint8)
        cv2.imwrite(str(tmp_path / "img" / cam / "000000.png"), cv2.resize(img, (320, 240)))
    with pytest.raises(CalibrationError, match="no overlap"):
        calibrate_images(tmp_path / "img", tmp_path / "w")


@pytest.fixture(scope="module")
def ring8_capture(tmp_path_factory) -> Path:
    from pointtraj.synth.render import render_capture

    out = tmp_path_factory.mktemp("ring8") / "capture"
    render_capture(out, preset="ring8", scene="static_room", frames=1, seed=0)
    return out


@pytest.mark.slow
def test_cli_calibrates_a_rendered_capture(ring8_capture, tmp_path):
    """End to end: render ring8 (8 cameras, 640x512), calibrate with pycolmap, align to truth."""
    from pointtraj.cli import main
    from pointtraj.rigio import load_rig

    out = tmp_path / "rig.toml"
    gt_path = ring8_capture / "rig.toml"
    gt = load_rig(gt_path)
    runner = CliRunner()
    result = runner.invoke(
        main,
        ["calibrate", str(ring8_capture), "--out", str(out), "--align-to", str(gt_path)],
    )
    assert result.exit_code == 0, result.output
    assert "registered 8 of 8 cameras" in result.output
    assert "px mean reprojection error" in result.output
    rig = load_rig(out)
    assert rig.names == gt.names
    cmp = compare_rigs(rig, gt, align=False).summary()  # already in the truth's frame
    assert cmp["rotation_deg_max"] < 0.2
    assert cmp["centre_mm_max"] < 30.0
    assert cmp["focal_pct_max"] < 1.5
    assert (tmp_path / "rig_connectivity.png").stat().st_size > 1000
    assert gt_path.exists()
    # Scale from a known camera distance: metric up to the SfM error.
    out2 = tmp_path / "rig2.toml"
    d = float(np.linalg.norm(gt.C[0] - gt.C[4]))
    result = runner.invoke(
        main,
        [
            "calibrate",
            str(ring8_capture),
            "--out",
            str(out2),
            "--scale-distance",
            "cam00",
            "cam04",
            str(d),
        ],
    )
    assert result.exit_code == 0, result.output
    scaled = load_rig(out2)
    assert compare_rigs(scaled, gt).similarity[0] == pytest.approx(1.0, abs=0.01)


def test_cli_usage_errors(ring8_capture, tmp_path):
    from pointtraj.cli import main

    runner = CliRunner()
    res = runner.invoke(
        main,
        [
            "calibrate",
            str(ring8_capture),
            "--out",
            str(tmp_path / "r.toml"),
            "--scale-distance",
            "cam00",
            "cam01",
            "1.0",
            "--align-to",
            str(ring8_capture / "rig.toml"),
        ],
    )
    assert res.exit_code != 0 and "only one of" in res.output
    res = runner.invoke(
        main, ["calibrate", str(ring8_capture), "--out", str(tmp_path / "r.toml"), "--frames", "5"]
    )
    assert res.exit_code != 0 and "outside the capture" in res.output
    res = runner.invoke(
        main,
        ["calibrate", str(ring8_capture), "--out", str(tmp_path / "r.toml"), "--method", "charuco"],
    )
    assert res.exit_code != 0 and "needs --charuco" in res.output


@pytest.mark.skipif(not CALISCOPE.is_dir(), reason=f"shared data not found at {CALISCOPE}")
def test_charuco_board_of_the_real_capture_is_detected():
    import cv2

    board = CharucoBoard.from_toml(CALISCOPE / "charuco.toml")
    assert board.inverted and board.square_m == pytest.approx(0.054)
    video = cv2.VideoCapture(str(CALISCOPE / "calibration" / "extrinsic" / "cam_0.mp4"))
    video.set(cv2.CAP_PROP_POS_FRAMES, 20)
    ok, frame = video.read()
    video.release()
    assert ok
    ids, xy = detect_charuco(frame[..., ::-1], board)
    assert len(ids) >= 10 and xy.shape == (len(ids), 2)


@pytest.mark.slow
def test_retry_registers_a_dropped_camera_with_the_median_focal(ring8_capture, tmp_path):
    """A camera taken out of the model (as a degenerate one is) is registered again by
    continuing the mapping with the median focal length as its prior."""
    import pycolmap

    from pointtraj.calibrate import export_frames
    from pointtraj.calibrate.sfm import _retry_registration
    from pointtraj.session import Capture

    cap = Capture.open(ring8_capture)
    list(export_frames(cap, [0], tmp_path / "images"))
    cal = calibrate_images(tmp_path / "images", tmp_path / "w")
    assert len(cal.rig) == 8
    rec = pycolmap.Reconstruction(str(tmp_path / "w" / "model"))
    for image_id in list(rec.reg_image_ids()):
        if rec.images[image_id].name.startswith("cam05/"):
            rec.deregister_frame(rec.images[image_id].frame_id)
    assert rec.num_reg_images() == 7
    mapper = pycolmap.IncrementalPipelineOptions()
    mapper.num_threads = 2
    redone = _retry_registration(
        rec,
        cal,
        ["cam05"],
        tmp_path / "w" / "database.db",
        tmp_path / "images",
        tmp_path / "w",
        mapper,
    )
    assert redone.num_reg_images() == 8
    names = {redone.images[i].name.split("/")[0] for i in redone.reg_image_ids()}
    assert "cam05" in names
