"""Tests of pointtraj.session.Capture: image folders, videos, creation, and every error."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest
from helpers.rigs import ring_rig

from pointtraj.camera import CameraRig
from pointtraj.errors import FileFormatError, ValidationError
from pointtraj.rigio import load_caliscope, save_rig_toml
from pointtraj.session import Capture

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
CALISCOPE = SHARED / "data" / "caliscope_board_4cam"

W, H = 64, 48


def small_rig(names=("left", "right")) -> CameraRig:
    """One WxH camera (f = 60 px) per name, camera i at angle i radians, 2 m from the z axis."""
    return ring_rig(names=names, angles=range(len(names)), radius=2.0, size=(W, H), focal=60.0)


def frame_image(camera: int, t: int) -> np.ndarray:
    """A distinct RGB image per camera and frame (flat colour plus a gradient)."""
    img = np.zeros((H, W, 3), np.uint8)
    img[..., 0] = 10 * t
    img[..., 1] = 100 + 50 * camera
    img[..., 2] = np.linspace(0, 255, W, dtype=np.uint8)[None, :]
    return img


def make_capture(
    path: Path, T: int = 4, image_format: str = "png", names=("left", "right")
) -> Capture:
    cap = Capture.create(path, small_rig(names), fps=12.5, image_format=image_format)
    for t in range(T):
        for c, name in enumerate(names):
            cap.write_frame(name, t, frame_image(c, t))
    return cap


def test_create_write_open_read(tmp_path):
    writer = make_capture(tmp_path / "cap")
    assert writer.num_frames == 4
    np.testing.assert_array_equal(writer.read("right", 2), frame_image(1, 2))  # readable at once
    files = sorted(p.name for p in (tmp_path / "cap" / "frames" / "left").iterdir())
    assert files == ["000000.png", "000001.png", "000002.png", "000003.png"]  # no temporaries
    cap = Capture.open(tmp_path / "cap")
    assert cap.camera_names == ["left", "right"] and cap.rig.names == ["left", "right"]
    assert cap.num_frames == 4 and len(cap) == 4 and cap.fps == 12.5
    assert cap.image_size("left") == (W, H) and cap.image_size(1) == (W, H)
    img = cap.read("left", 3)
    assert img.shape == (H, W, 3) and img.dtype == np.uint8
    np.testing.assert_array_equal(img, frame_image(0, 3))  # RGB order, PNG is lossless
    np.testing.assert_array_equal(cap.read(1, 0), frame_image(1, 0))
    frame = cap.iter_frame(2)
    assert list(frame) == ["left", "right"]
    np.testing.assert_array_equal(frame["right"], frame_image(1, 2))
    assert sum(1 for _ in cap) == 4
    with pytest.raises(ValidationError, match="made by Capture.create"):
        cap.write_frame("left", 4, frame_image(0, 4))
    assert cap.labels_path is None
    (tmp_path / "cap" / "labels.toml").write_text(
        '[[classes]]\nname = "head"\ncolor = [255, 0, 0]\n'
    )
    assert cap.labels_path == tmp_path / "cap" / "labels.toml"


def test_jpeg_frames(tmp_path):
    make_capture(tmp_path / "cap", T=2, image_format="jpg")
    assert (tmp_path / "cap" / "frames" / "right" / "000001.jpg").is_file()
    cap = Capture.open(tmp_path / "cap")
    diff = np.abs(cap.read("right", 1).astype(int) - frame_image(1, 1).astype(int))
    assert diff.mean() < 2.0  # quality 95


def test_numeric_order_and_explicit_rig(tmp_path):
    """Frame files named 1, 2, 10 (no padding) are frames 0, 1, 2; the rig may come from elsewhere."""
    rig = small_rig(["a"])
    import cv2

    folder = tmp_path / "cap" / "frames" / "a"
    folder.mkdir(parents=True)
    for n in [10, 1, 2]:
        cv2.imwrite(str(folder / f"{n}.png"), frame_image(0, n)[..., ::-1])
    save_rig_toml(rig, tmp_path / "elsewhere.toml")
    for given in (rig, tmp_path / "elsewhere.toml"):
        cap = Capture.open(tmp_path / "cap", rig=given)
        assert cap.num_frames == 3
        np.testing.assert_array_equal(cap.read("a", 2), frame_image(0, 10))
        np.testing.assert_array_equal(cap.read("a", 0), frame_image(0, 1))
    with pytest.raises(FileFormatError, match="no rig.toml in the capture"):
        Capture.open(tmp_path / "cap")


def test_frame_count_mismatch(tmp_path, caplog):
    make_capture(tmp_path / "cap", T=3)
    (tmp_path / "cap" / "frames" / "right" / "000002.png").unlink()
    with pytest.raises(
        FileFormatError,
        match=r"different frame counts: left=3 \(frames/left\), right=2 \(frames/right\)",
    ):
        Capture.open(tmp_path / "cap")
    with caplog.at_level(logging.WARNING, logger="pointtraj.session"):
        cap = Capture.open(tmp_path / "cap", strict=False)
    assert cap.num_frames == 2 and "using the first 2 frames" in caplog.text
    with pytest.raises(ValidationError, match=r"camera 'left': frame 2 out of range \[0, 2\)"):
        cap.read("left", 2)


def test_cameras_not_matching_rig(tmp_path, caplog):
    make_capture(tmp_path / "cap", T=2, names=("left", "right"))
    (tmp_path / "cap" / "frames" / "extra").mkdir()
    with pytest.raises(
        FileFormatError, match="frames of camera.s. extra but the rig has left, right"
    ):
        Capture.open(tmp_path / "cap")
    (tmp_path / "cap" / "frames" / "extra").rmdir()
    for f in (tmp_path / "cap" / "frames" / "right").iterdir():
        f.unlink()
    (tmp_path / "cap" / "frames" / "right").rmdir()
    with pytest.raises(FileFormatError, match="rig camera.s. right have no frames or video"):
        Capture.open(tmp_path / "cap")
    with caplog.at_level(logging.WARNING, logger="pointtraj.session"):
        cap = Capture.open(tmp_path / "cap", strict=False)
    assert cap.camera_names == ["left"] and "dropping them from the rig" in caplog.text


def test_corrupt_and_misnamed_images(tmp_path):
    make_capture(tmp_path / "cap", T=3)
    (tmp_path / "cap" / "frames" / "right" / "000001.png").write_bytes(b"\x89PNG broken")
    cap = Capture.open(tmp_path / "cap")  # only the first frame is decoded when opening
    with pytest.raises(
        FileFormatError, match=r"000001.png: camera 'right' frame 1: unreadable or corrupt"
    ):
        cap.read("right", 1)
    (tmp_path / "cap" / "frames" / "left" / "notes.png").write_bytes(b"")
    with pytest.raises(FileFormatError, match="frame file name must be an integer"):
        Capture.open(tmp_path / "cap")


def test_image_size_mismatch(tmp_path, caplog):
    import cv2

    make_capture(tmp_path / "cap", T=2)
    small = np.zeros((H // 2, W // 2, 3), np.uint8)
    cv2.imwrite(str(tmp_path / "cap" / "frames" / "left" / "000000.png"), small)
    with pytest.raises(
        FileFormatError,
        match=r"camera 'left' frame 0: image is 32x24 but the calibration says 64x48",
    ):
        Capture.open(tmp_path / "cap")
    with caplog.at_level(logging.WARNING, logger="pointtraj.session"):
        cap = Capture.open(tmp_path / "cap", strict=False)
    assert "image is 32x24" in caplog.text
    assert cap.image_size("left") == (32, 24) and cap.read("left", 0).shape == (24, 32, 3)
    # a later frame of the wrong size is caught when read (opening decodes only frame 0)
    cv2.imwrite(
        str(tmp_path / "cap" / "frames" / "left" / "000000.png"), frame_image(0, 0)[..., ::-1]
    )
    cv2.imwrite(str(tmp_path / "cap" / "frames" / "right" / "000001.png"), small)
    cap = Capture.open(tmp_path / "cap")
    with pytest.raises(FileFormatError, match="camera 'right' frame 1: image is 32x24"):
        cap.read("right", 1)


def test_bad_arguments(tmp_path):
    cap = make_capture(tmp_path / "cap", T=1)
    with pytest.raises(ValidationError, match=r"expected \(48, 64, 3\) uint8 RGB, got \(48, 64\)"):
        cap.write_frame("left", 1, np.zeros((H, W), np.uint8))
    with pytest.raises(ValidationError, match="uint8"):
        cap.write_frame("left", 1, np.zeros((H, W, 3), np.float32))
    with pytest.raises(ValidationError, match="no camera named 'middle'"):
        cap.write_frame("middle", 0, frame_image(0, 0))
    with pytest.raises(ValidationError, match="non-negative integer"):
        cap.write_frame("left", -1, frame_image(0, 0))
    with pytest.raises(ValidationError, match=r"index in \[0, 2\)"):
        cap.read(5, 0)
    with pytest.raises(ValidationError, match="image_format must be 'jpg' or 'png'"):
        Capture.create(tmp_path / "other", small_rig(), 30.0, image_format="bmp")
    with pytest.raises(ValidationError, match="fps must be positive"):
        Capture.create(tmp_path / "other", small_rig(), 0.0)
    with pytest.raises(FileFormatError, match="capture folder does not exist"):
        Capture.open(tmp_path / "nowhere")
    (tmp_path / "cap" / "capture.toml").write_text('fps = "fast"\n')
    with pytest.raises(FileFormatError, match="fps: expected a positive number"):
        Capture.open(tmp_path / "cap")
    (tmp_path / "empty").mkdir()
    save_rig_toml(small_rig(), tmp_path / "empty" / "rig.toml")
    with pytest.raises(FileFormatError, match="no frames/<camera>/ folders or videos"):
        Capture.open(tmp_path / "empty")


def write_video(path: Path, T: int, fps: float, camera: int) -> None:
    import cv2

    path.parent.mkdir(parents=True, exist_ok=True)
    out = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (W, H))
    assert out.isOpened()
    for t in range(T):
        out.write(np.ascontiguousarray(frame_image(camera, t)[..., ::-1]))
    out.release()


def test_videos_seek_by_index(tmp_path):
    save_rig_toml(small_rig(), tmp_path / "cap" / "rig.toml")
    for c, name in enumerate(["left", "right"]):
        write_video(tmp_path / "cap" / "videos" / f"{name}.mp4", T=20, fps=24.0, camera=c)
    cap = Capture.open(tmp_path / "cap")
    assert cap.num_frames == 20 and cap.fps == pytest.approx(24.0)  # fps from the video
    for t in [0, 1, 2, 15, 3, 19, 7, 8]:  # sequential reads and backward/forward seeks
        img = cap.read("right", t)
        assert img.shape == (H, W, 3)
        assert abs(float(img[..., 0].mean()) - 10 * t) < 4, f"frame {t}"
        assert abs(float(img[..., 1].mean()) - 150) < 4
    import pickle

    clone = pickle.loads(pickle.dumps(cap))  # for process pools: videos reopen lazily
    np.testing.assert_array_equal(clone.read("right", 5), cap.read("right", 5))
    cap.close()
    clone.close()
    (tmp_path / "cap" / "capture.toml").write_text("fps = 30\n")
    assert Capture.open(tmp_path / "cap").fps == 30.0
    write_video(tmp_path / "cap" / "videos" / "right.mp4", T=15, fps=24.0, camera=1)
    with pytest.raises(
        FileFormatError, match=r"left=20 \(videos/left.mp4\), right=15 \(videos/right.mp4\)"
    ):
        Capture.open(tmp_path / "cap")
    (tmp_path / "cap" / "videos" / "left.mp4").write_bytes(b"not a video")
    with pytest.raises(FileFormatError, match="left.mp4: camera 'left'"):
        Capture.open(tmp_path / "cap")


@pytest.mark.shared
@pytest.mark.skipif(
    not (CALISCOPE / "camera_array.toml").is_file(),
    reason=f"real caliscope data not found at {CALISCOPE} (../shared is absent)",
)
def test_real_caliscope_videos(tmp_path):
    """caliscope's four 1280x720 webcam videos, linked into a capture folder."""
    rig = load_caliscope(CALISCOPE / "camera_array.toml")
    save_rig_toml(rig, tmp_path / "rig.toml")
    (tmp_path / "videos").mkdir()
    for name in rig.names:
        (tmp_path / "videos" / f"{name}.mp4").symlink_to(
            CALISCOPE / "calibration" / "extrinsic" / f"{name}.mp4"
        )
    cap = Capture.open(tmp_path)
    assert cap.num_frames == 57 and cap.camera_names == rig.names
    assert 1.0 < cap.fps < 60.0
    seq = [cap.read("cam_2", t) for t in range(12)]
    again = cap.read("cam_2", 10)  # a backward seek gives the same frame as sequential decoding
    np.testing.assert_array_equal(again, seq[10])
    assert not np.array_equal(seq[10], seq[0])
    frame = cap.iter_frame(56)
    assert all(img.shape == (720, 1280, 3) for img in frame.values())


def test_implausible_video_fps_is_reported_and_can_be_overridden(tmp_path, caplog):
    """Regression: a 0.2 fps video header was taken as is (captions said 35.00 s for frame 7).
    It is reported with a warning naming the file and not used; capture.toml's fps overrides."""
    from pointtraj.session import check_video_fps

    save_rig_toml(small_rig(), tmp_path / "cap" / "rig.toml")
    for c, name in enumerate(["left", "right"]):
        write_video(tmp_path / "cap" / "videos" / f"{name}.mp4", T=5, fps=0.2, camera=c)
    import cv2

    probe = cv2.VideoCapture(str(tmp_path / "cap" / "videos" / "left.mp4"))
    assert probe.get(cv2.CAP_PROP_FPS) == pytest.approx(0.2)  # the header really says 0.2
    probe.release()
    with caplog.at_level(logging.WARNING, logger="pointtraj.session"):
        cap = Capture.open(tmp_path / "cap")
    assert cap.fps == 30.0  # DEFAULT_FPS, not 0.2
    text = caplog.text
    assert "left.mp4: the video header says 0.2 fps, which is implausible" in text
    assert "right.mp4" in text and "fps = ... in capture.toml" in text
    caplog.clear()
    (tmp_path / "cap" / "capture.toml").write_text("fps = 6.0\n")
    with caplog.at_level(logging.WARNING, logger="pointtraj.session"):
        assert Capture.open(tmp_path / "cap").fps == 6.0
    assert "implausible" not in caplog.text  # the header is not consulted
    # A plausible header is used; the other is reported.
    (tmp_path / "cap" / "capture.toml").unlink()
    write_video(tmp_path / "cap" / "videos" / "right.mp4", T=5, fps=24.0, camera=1)
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="pointtraj.session"):
        assert Capture.open(tmp_path / "cap").fps == pytest.approx(24.0)
    assert "left.mp4: the video header says 0.2 fps" in caplog.text
    assert check_video_fps(5000.0, "x.mp4") is None and check_video_fps(25.0, "x.mp4") == 25.0
    assert check_video_fps(float("nan"), "x.mp4") is None


def test_capture_toml_up(tmp_path):
    make_capture(tmp_path / "cap")
    assert Capture.open(tmp_path / "cap").up is None  # auto
    (tmp_path / "cap" / "capture.toml").write_text('fps = 12.5\nup = "-y"\n')
    np.testing.assert_array_equal(Capture.open(tmp_path / "cap").up, [0.0, -1.0, 0.0])
    (tmp_path / "cap" / "capture.toml").write_text("up = [0, 0, 2]\n")
    np.testing.assert_array_equal(Capture.open(tmp_path / "cap").up, [0.0, 0.0, 1.0])
    (tmp_path / "cap" / "capture.toml").write_text('up = "sideways"\n')
    with pytest.raises(FileFormatError, match=r"capture.toml: up: expected 'auto', one of \+x"):
        Capture.open(tmp_path / "cap")
