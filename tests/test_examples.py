"""Tests of pointtraj.examples: real example captures laid out as pointtraj captures."""

from __future__ import annotations

import csv
import os
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from pointtraj.camera import Camera
from pointtraj.errors import FileFormatError, ValidationError
from pointtraj.examples import (
    ExampleNotFoundError,
    caliscope_sync_report,
    candidate_mappings,
    choose_image_mapping,
    download_pose2sim_wheel,
    fetch_caliscope_board,
    fetch_example,
    fetch_pose2sim,
    measure_image_mapping,
)
from pointtraj.labelset import LabelSet
from pointtraj.reconstruct.texture import texture_patch_spacing
from pointtraj.session import Capture

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
CALISCOPE = SHARED / "data" / "caliscope_board_4cam"
needs_caliscope = pytest.mark.skipif(
    not CALISCOPE.is_dir(), reason=f"needs the shared caliscope capture at {CALISCOPE}"
)


def _texture(h: int, w: int, seed: int = 0) -> np.ndarray:
    """(h, w, 3) uint8 RGB image with blobs at several scales (feature-rich, seeded)."""
    import cv2

    rng = np.random.default_rng(seed)
    img = np.zeros((h, w), np.float32)
    for cell in (4, 16, 48):
        small = rng.random((h // cell + 2, w // cell + 2)).astype(np.float32)
        img += cv2.resize(small, (w, h), interpolation=cv2.INTER_CUBIC)[:h, :w]
    img = (img - img.min()) / (img.max() - img.min()) * 255
    return np.repeat(img.astype(np.uint8)[..., None], 3, axis=2)


def _letterbox(img: np.ndarray, width: int) -> np.ndarray:
    """Scale to ``width`` and pad with black rows to the original height, centred."""
    import cv2

    h, w = img.shape[:2]
    hs = int(round(h * width / w))
    small = cv2.resize(img, (width, hs), interpolation=cv2.INTER_AREA)
    out = np.zeros((h, width, 3), np.uint8)
    top = (h - hs) // 2
    out[top : top + hs] = small
    return out


# -- image mappings --------------------------------------------------------------------------


def test_candidate_mappings_values():
    c = candidate_mappings((1088, 1920), (1080, 1920))
    lb, cc = c["letterbox"], c["centre-crop"]
    assert lb.sx == pytest.approx(1080 / 1088) and lb.sy == pytest.approx(1906 / 1920)
    assert lb.ty == pytest.approx(7 + 0.5 * (1906 / 1920 - 1))
    assert (cc.sx, cc.sy, cc.tx, cc.ty) == (1.0, 1.0, -4, 0)
    side = candidate_mappings((1920, 1080), (1920, 1000))["letterbox"]  # fit the height
    assert side.sy == pytest.approx(1000 / 1080) and side.tx > 0
    with pytest.raises(ValidationError, match="positive"):
        candidate_mappings((0, 10), (10, 10))


def test_mapping_apply_matches_pixel_map():
    """Projecting with the adapted camera = mapping the original projection (with distortion)."""
    cam = Camera.look_at(
        "c", [3.0, 0.5, 1.2], [0, 0, 1.0], (1088, 1920), 1600.0, dist=[0.05, -0.02, 0.001, 0, 0]
    )
    rng = np.random.default_rng(1)
    X = rng.uniform(-0.4, 0.4, (50, 3)) + [0, 0, 1.0]
    for m in candidate_mappings((1088, 1920), (1080, 1920)).values():
        new = m.apply(cam)
        assert new.size == (1080, 1920)
        np.testing.assert_allclose(new.dist, cam.dist)
        p0 = cam.project(X)[0]
        p1 = new.project(X)[0]
        expected = p0 * [m.sx, m.sy] + [m.tx, m.ty]
        np.testing.assert_allclose(p1, expected, atol=1e-9)


def test_measure_and_choose_letterbox():
    ref = _texture(640, 368)
    frame = _letterbox(ref, 360)
    measured = measure_image_mapping(ref, frame)
    assert measured is not None and measured.inliers >= 50
    assert measured.sx == pytest.approx(360 / 368, abs=2e-3)
    mapping, why = choose_image_mapping("c", (368, 640), frame, ref)
    assert mapping.model == "letterbox", why
    # Without a reference, the black bars decide.
    mapping, why = choose_image_mapping("c", (368, 640), frame)
    assert mapping.model == "letterbox" and "letterbox model expects" in why


def test_measure_and_choose_centre_crop():
    ref = _texture(640, 368, seed=2)
    frame = np.ascontiguousarray(ref[:, 4:-4])
    mapping, why = choose_image_mapping("c", (368, 640), frame, ref)
    assert mapping.model == "centre-crop", why
    assert (mapping.tx, mapping.ty) == (-4, 0)
    mapping, why = choose_image_mapping("c", (368, 640), frame)
    assert mapping.model == "centre-crop" and "unverified" in why
    with pytest.raises(ValidationError, match="reference image"):
        choose_image_mapping("c", (368, 640), frame, ref[:, :300])


def test_measure_rejects_unrelated_images():
    assert measure_image_mapping(_texture(200, 200, 3), _texture(200, 200, 4)) is None


# -- sync report ------------------------------------------------------------------------------


def test_sync_report(tmp_path):
    path = tmp_path / "t.csv"
    rows = ["sync_index,cam_id,frame_index,frame_time"]
    for s in range(10):
        for c in range(3):
            rows.append(f"{s},{c},{s},{1.0 + s / 6 + 0.002 * c}")
    rows.append("10,0,10,2.8")  # a sync index not seen by every camera
    path.write_text("\n".join(rows) + "\n")
    rep = caliscope_sync_report(path, {"cam_0": 11})
    assert rep.spread.shape == (10,)
    np.testing.assert_allclose(rep.spread, 0.004)
    assert rep.fps == pytest.approx(6.0)
    assert rep.timestamp_counts == {"cam_0": 11, "cam_1": 10, "cam_2": 10}
    assert "median 4.0 ms" in rep.describe()
    bad = tmp_path / "bad.csv"
    bad.write_text("sync_index,cam\n0,0\n")
    with pytest.raises(FileFormatError, match="missing column"):
        caliscope_sync_report(bad)


def test_fetch_example_errors(tmp_path):
    with pytest.raises(
        ValidationError, match="valid names: pose2sim, pose2sim-multi, caliscope-board"
    ):
        fetch_example("nope", tmp_path / "x")
    with pytest.raises(ExampleNotFoundError, match="missing"):
        fetch_caliscope_board(tmp_path / "x", source=tmp_path)
    (tmp_path / "busy").mkdir()
    (tmp_path / "busy" / "file.txt").write_text("mine")
    with pytest.raises(ValidationError, match="not empty"):
        fetch_example("pose2sim", tmp_path / "busy", wheel=tmp_path / "none.whl")
    with pytest.raises(ValidationError, match="refusing"):
        fetch_example("pose2sim", tmp_path / "busy", wheel=tmp_path / "none.whl", overwrite=True)
    with pytest.raises(FileFormatError, match="not a readable wheel"):
        fetch_example("pose2sim", tmp_path / "new", wheel=tmp_path / "busy" / "file.txt")
    assert not (tmp_path / "new").exists()
    assert (tmp_path / "busy" / "file.txt").read_text() == "mine"


# -- caliscope board --------------------------------------------------------------------------


@needs_caliscope
@pytest.mark.shared
def test_caliscope_board_capture(tmp_path):
    import cv2

    out = tmp_path / "board"
    res = fetch_caliscope_board(out, source=CALISCOPE)
    assert res.num_frames == {f"cam_{i}": 57 for i in range(4)}
    assert res.fps == pytest.approx(6.0, abs=0.05)
    assert all((out / "videos" / f"cam_{i}.mp4").is_symlink() for i in range(4))
    for strict in (True, False):
        cap = Capture.open(out, strict=strict)
        assert cap.camera_names == [f"cam_{i}" for i in range(4)]
        assert cap.num_frames == 57 and cap.fps == pytest.approx(res.fps)
    labels = LabelSet.load(cap.labels_path)
    assert labels.kinds[labels.index("board")] == "object"
    assert (out / "charuco.toml").is_file() and (out / "charuco" / "xy_CHARUCO.csv").is_file()
    # Each camera reads; caliscope's corners (re-indexed by video frame) lie on the detected
    # ChArUco corners of that very frame and not of the next one.
    with open(out / "charuco" / "corners_2d.csv") as f:
        rows = list(csv.DictReader(f))
    board = cv2.aruco.CharucoBoard(
        (4, 5), 0.054, 0.054 * 0.75, cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_1000)
    )
    detector = cv2.aruco.CharucoDetector(board)
    same, next_ = [], []
    for cam in cap.camera_names:
        frames = sorted({int(r["frame"]) for r in rows if r["camera"] == cam})
        for frame in frames[len(frames) // 2 : len(frames) // 2 + 2]:
            img = cap.read(cam, frame)
            assert img.shape == (720, 1280, 3) and img.dtype == np.uint8
            corners, ids, _, _ = detector.detectBoard(255 - cv2.cvtColor(img, cv2.COLOR_RGB2GRAY))
            if ids is None:
                continue
            found = corners.reshape(-1, 2)
            for f, dest in ((frame, same), (frame + 1, next_)):
                ref = np.array(
                    [
                        [float(r["x"]), float(r["y"])]
                        for r in rows
                        if r["camera"] == cam and int(r["frame"]) == f
                    ]
                ).reshape(-1, 2)
                if len(ref):
                    d = np.linalg.norm(found[:, None] - ref[None], axis=2).min(axis=1)
                    dest.append(np.median(d))
    assert len(same) >= 4, "too few frames with a detected board"
    assert np.median(same) < 1.0 and np.median(next_) > 3.0
    # Overwrite with copies, and through the CLI.
    runner = CliRunner()
    from pointtraj.cli import main

    result = runner.invoke(
        main,
        ["examples", "fetch", "caliscope-board", "--out", str(out), "--force", "--copy"],
    )
    assert result.exit_code == 0, result.output
    assert "cam_0=57" in result.output and "spread" in result.output
    assert not (out / "videos" / "cam_0.mp4").is_symlink()
    assert Capture.open(out).read("cam_3", 56).shape == (720, 1280, 3)


def test_cli_list_and_errors(tmp_path):
    from pointtraj.cli import main

    runner = CliRunner()
    result = runner.invoke(main, ["examples", "list"])
    assert result.exit_code == 0 and "pose2sim" in result.output
    assert "BSD-3-Clause" in result.output
    result = runner.invoke(main, ["examples", "fetch", "nope", "--out", str(tmp_path / "x")])
    assert result.exit_code == 2 and "valid names" in result.output
    result = runner.invoke(
        main, ["examples", "fetch", "pose2sim", "--out", str(tmp_path / "x"), "--copy"]
    )
    assert result.exit_code == 2 and "caliscope-board example only" in result.output


# -- pose2sim ---------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def pose2sim_wheel() -> Path:
    try:
        return download_pose2sim_wheel()
    except ExampleNotFoundError as exc:
        pytest.skip(f"cannot download pose2sim==0.10.49 from PyPI (no network?): {exc}")


def test_download_rejects_corrupt_cache(tmp_path, monkeypatch):
    """A truncated cached wheel is deleted and downloaded again (here pip has no index)."""
    bad = tmp_path / "pose2sim-0.10.49-py3-none-any.whl"
    bad.write_bytes(b"PK truncated")
    monkeypatch.setenv("PIP_CONFIG_FILE", os.devnull)
    monkeypatch.setenv("PIP_NO_INDEX", "1")
    monkeypatch.delenv("PIP_FIND_LINKS", raising=False)
    with pytest.raises(ExampleNotFoundError, match="could not download pose2sim==0.10.49"):
        download_pose2sim_wheel(tmp_path)
    assert not bad.exists()


@pytest.mark.slow
def test_pose2sim_capture(tmp_path, pose2sim_wheel, caplog):
    from pointtraj.rigio import load_qualisys

    out = tmp_path / "p2s"
    with caplog.at_level("WARNING", logger="pointtraj.examples"):
        res = fetch_pose2sim(out, wheel=pose2sim_wheel)
    assert "cam01, cam02" in caplog.text
    assert res.num_frames == {f"cam0{i}": 100 for i in range(1, 5)}
    assert sorted(res.corrections) == ["cam01", "cam02"]
    assert all(m.model == "letterbox" and m.inliers >= 100 for m in res.corrections.values())
    assert "BSD 3-Clause License" in (out / "LICENSE").read_text()
    assert "BSD-3-Clause" in (out / "capture.toml").read_text()
    assert "Demo_SinglePerson" in (out / "README.md").read_text()
    original = load_qualisys(out / "source" / "Calib.qca.txt")
    # The stored frames do not match the raw calibration (strict open fails) ...
    with pytest.raises(FileFormatError, match="1080x1920 but the calibration says 1088x1920"):
        Capture.open(out, rig=original)
    # ... and do match the written rig.
    for strict in (True, False):
        cap = Capture.open(out, strict=strict)
        assert cap.num_frames == 100 and cap.fps == 60.0
        assert cap.camera_names == ["cam01", "cam02", "cam03", "cam04"]
    s = 1080 / 1088
    for cam in cap.rig:
        raw = original[cam.name]
        if cam.name in ("cam01", "cam02"):
            assert cam.size == (1080, 1920)
            assert cam.K[0, 0] == pytest.approx(raw.K[0, 0] * s)
            assert cam.K[1, 2] == pytest.approx(raw.K[1, 2] * 1906 / 1920 + 7, abs=0.01)
        else:
            assert cam.size == (1088, 1920)
            np.testing.assert_allclose(cam.K, raw.K)
        np.testing.assert_allclose(cam.R, raw.R, atol=1e-9)
        img = cap.read(cam.name, 99)
        assert img.shape == (1920, cam.size[0], 3)
    # The person on the treadmill at the world origin projects into every image.
    proj = cap.rig.project(np.array([[0.0, 0.0, 0.1], [0.0, 0.0, 1.6]]))
    assert proj.in_image.all()
    assert LabelSet.load(cap.labels_path) == LabelSet.default()
    # Densification's patch chosen from the texture of the first frame: 5 px, the spacing
    # pipelines/pose2sim_demo.toml was measured best with (docs/real_captures.md)
    assert texture_patch_spacing([cap.read(n, 0) for n in cap.camera_names])[0] == 5.0


@pytest.mark.slow
def test_pose2sim_multi_person_capture(tmp_path, pose2sim_wheel):
    from pointtraj.cli import main

    out = tmp_path / "p2sm"
    res = CliRunner().invoke(
        main,
        ["examples", "fetch", "pose2sim-multi", "--out", str(out), "--wheel", str(pose2sim_wheel)],
    )
    assert res.exit_code == 0, res.output
    readme = (out / "README.md").read_text()
    assert "Demo_MultiPerson" in readme and "a woman beside it" in readme
    assert "calibration adapted" not in res.output  # its four videos are 1088 px wide
    cap = Capture.open(out)
    single = fetch_pose2sim(tmp_path / "p2s", wheel=pose2sim_wheel)
    ref = Capture.open(single.path)
    assert cap.num_frames == 100 and cap.fps == 60.0 and cap.camera_names == ref.camera_names
    for cam in cap.rig:  # the same calibration; only the single-person videos were letterboxed
        assert cam.size == (1088, 1920)
        np.testing.assert_allclose(cam.R, ref.rig[cam.name].R, atol=1e-12)
        np.testing.assert_allclose(cam.C, ref.rig[cam.name].C, atol=1e-12)
    assert not np.array_equal(cap.read("cam03", 50), ref.read("cam03", 50))  # other videos
    assert (out / "source" / "extrinsics" / "cam01_ext.png").is_file()
    assert texture_patch_spacing([cap.read(n, 0) for n in cap.camera_names])[0] == 5.0
