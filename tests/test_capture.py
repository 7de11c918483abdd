"""``make_capture`` and ``pointtraj capture``: capture folders from real videos (written by
OpenCV), image folders and rig files in several formats, and every bad input named."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from helpers.rigs import ring_rig

from pointtraj.capture import make_capture, media_by_camera
from pointtraj.cli import main
from pointtraj.config import load_toml
from pointtraj.errors import FileFormatError, ValidationError
from pointtraj.labelset import LabelSet
from pointtraj.rigio import save_rig
from pointtraj.session import Capture

W, H, T = 64, 48, 5


def frame_image(camera: int, t: int) -> np.ndarray:
    img = np.zeros((H, W, 3), np.uint8)
    img[..., 0] = 20 * t
    img[..., 1] = 60 + 60 * camera
    img[..., 2] = np.linspace(0, 255, W, dtype=np.uint8)[None, :]
    return img


def write_video(path: Path, camera: int, frames: int = T, fps: float = 25.0, size=(W, H)):
    import cv2

    path.parent.mkdir(parents=True, exist_ok=True)
    out = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, size)
    assert out.isOpened()
    for t in range(frames):
        img = cv2.resize(frame_image(camera, t), size)
        out.write(np.ascontiguousarray(img[..., ::-1]))
    out.release()


def write_images(folder: Path, camera: int, frames: int = T, size=(W, H)) -> None:
    """PNGs named ``img_1.png`` .. ``img_<frames>.png``: not integer names, and ``img_10``
    sorts before ``img_2`` by name, so frame order must come from the numbers."""
    import cv2

    folder.mkdir(parents=True, exist_ok=True)
    for t in range(frames):
        img = cv2.resize(frame_image(camera, t), size)
        cv2.imwrite(str(folder / f"img_{t + 1}.png"), np.ascontiguousarray(img[..., ::-1]))


@pytest.fixture
def media(tmp_path) -> dict:
    """A 3-camera rig (as a caliscope file and as rig.toml), 2 videos and 1 image folder."""
    rig = ring_rig(3, size=(W, H), focal=60.0, names="cam_{i}")
    save_rig(rig, tmp_path / "camera_array.toml", fmt="caliscope")
    save_rig(rig, tmp_path / "rig.toml", fmt="toml")
    write_video(tmp_path / "in" / "cam_0.mp4", 0)
    write_video(tmp_path / "in" / "cam_1.mp4", 1)
    write_images(tmp_path / "in" / "cam_2", 2, frames=T)
    return {"root": tmp_path, "rig": rig, "in": tmp_path / "in"}


def test_make_capture_from_videos_and_images(media):
    root = media["root"]
    made = make_capture(
        root / "cap",
        root / "camera_array.toml",
        media_by_camera([media["in"]], media["rig"]),
        labels="default",
        description="three cameras",
    )
    assert made.rig_source.endswith("camera_array.toml (caliscope)")
    assert [(m.camera, m.kind, m.num_frames, m.size) for m in made.media] == [
        ("cam_0", "video", T, (W, H)),
        ("cam_1", "video", T, (W, H)),
        ("cam_2", "images", T, (W, H)),
    ]
    assert made.fps == pytest.approx(25.0) and made.fps_source == "video header"
    assert [p.name for p in made.files] == ["rig.toml", "capture.toml", "labels.toml"]
    cap = Capture.open(root / "cap")  # strict: every check passes
    assert cap.camera_names == ["cam_0", "cam_1", "cam_2"] and cap.num_frames == T
    np.testing.assert_allclose(cap.rig.K, media["rig"].K)
    np.testing.assert_allclose(cap.rig.C, media["rig"].C, atol=1e-9)
    # Images keep their frame order (img_1 .. img_5 -> 000000 .. 000004), losslessly.
    assert sorted(p.name for p in (root / "cap" / "frames" / "cam_2").iterdir()) == [
        f"{t:06d}.png" for t in range(T)
    ]
    for t in range(T):
        np.testing.assert_array_equal(cap.read("cam_2", t), frame_image(2, t))
    assert abs(float(cap.read("cam_1", 3)[..., 0].mean()) - 60) < 4  # the video's frame 3
    assert (root / "cap" / "videos" / "cam_0.mp4").read_bytes() == (
        media["in"] / "cam_0.mp4"
    ).read_bytes()
    assert not (root / "cap" / "videos" / "cam_0.mp4").is_symlink()
    assert LabelSet.load(root / "cap" / "labels.toml") == LabelSet.default()
    doc = load_toml(root / "cap" / "capture.toml")
    assert doc["description"] == "three cameras" and "fps" not in doc and "up" not in doc
    np.testing.assert_allclose(made.up, [0, 0, 1], atol=1e-9)  # detected: the ring's plane
    assert not [p for p in root.iterdir() if p.name.startswith(".cap")]  # no temporaries


def test_make_capture_links_and_writes_settings(media):
    root = media["root"]
    items = [f"cam_0={media['in'] / 'cam_0.mp4'}", media["in"] / "cam_1.mp4", media["in"] / "cam_2"]
    made = make_capture(
        root / "cap",
        root / "rig.toml",
        media_by_camera(items, media["rig"]),
        fps=12.5,
        up="-y",
        mode="link",
    )
    assert (root / "cap" / "videos" / "cam_0.mp4").is_symlink()
    assert (root / "cap" / "frames" / "cam_2" / "000004.png").resolve() == (
        media["in"] / "cam_2" / "img_5.png"
    ).resolve()
    doc = load_toml(root / "cap" / "capture.toml")
    assert doc["fps"] == 12.5 and doc["up"] == "-y"
    cap = Capture.open(root / "cap")
    assert cap.fps == 12.5
    np.testing.assert_array_equal(cap.up, [0, -1, 0])
    np.testing.assert_array_equal(made.up, [0, -1, 0])
    assert "set" in made.up_source


def test_implausible_header_fps_is_reported(media, caplog):
    root = media["root"]
    for c in (0, 1):
        write_video(media["in"] / f"cam_{c}.mp4", c, fps=0.2)
    with caplog.at_level(logging.WARNING, logger="pointtraj"):
        made = make_capture(
            root / "cap", root / "rig.toml", media_by_camera([media["in"]], media["rig"])
        )
    assert made.fps == 30.0 and made.fps_source.startswith("assumed")
    assert "cam_0.mp4: the video header says 0.2 fps, which is implausible" in caplog.text
    assert str(root / "cap") not in caplog.text  # warnings name the user's files only
    res = CliRunner().invoke(
        main, ["capture", str(root / "cap2"), str(media["in"]), "--rig", str(root / "rig.toml"),
               "--fps", "6"],
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    assert "at 6 fps (given)" in res.output
    assert Capture.open(root / "cap2").fps == 6.0


def test_cli_prints_what_it_made(media):
    root = media["root"]
    res = CliRunner().invoke(
        main,
        ["capture", str(root / "cap"), str(media["in"]), "--rig", str(root / "camera_array.toml"),
         "--labels", "default", "--link"],
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    lines = res.output.splitlines()
    assert lines[0].startswith(f"made {root / 'cap'}: 3 cameras, 5 frames at 25 fps")
    assert "cam_2" in lines[3] and "images" in lines[3] and "linked from" in lines[3]
    assert lines[-2].startswith("up (+0.00, +0.00, +1.00): plane of the 3 camera centres")
    assert lines[-1] == "wrote rig.toml, capture.toml, labels.toml"


def _run(args: list[str]) -> str:
    res = CliRunner().invoke(main, ["capture", *args])
    assert res.exit_code != 0
    assert "Traceback" not in res.output
    return res.output


def test_bad_inputs_are_named(media):
    root, src = media["root"], media["in"]
    rig = ["--rig", str(root / "rig.toml")]
    out = str(root / "cap")
    # Frame counts that differ: every camera's count and file.
    write_images(root / "short" / "cam_2", 2, frames=T - 1)
    msg = _run(
        [out, str(src / "cam_0.mp4"), str(src / "cam_1.mp4"), str(root / "short" / "cam_2"), *rig]
    )
    assert "cameras have different frame counts: cam_0=5 (" in msg and "cam_2=4 (" in msg
    assert "short/cam_2" in msg
    # An image size that disagrees with the calibration: the folder named.
    write_images(root / "big" / "cam_2", 2, size=(W, H + 2))
    msg = _run(
        [out, str(src / "cam_0.mp4"), str(src / "cam_1.mp4"), str(root / "big" / "cam_2"), *rig]
    )
    assert (
        f"{root / 'big' / 'cam_2'}: camera 'cam_2' frame 0: image is 64x50 but the calibration says 64x48"
        in msg
    )
    # A video of the wrong size.
    write_video(root / "wide" / "cam_1.mp4", 1, size=(W + 16, H))
    msg = _run(
        [out, str(src / "cam_0.mp4"), str(root / "wide" / "cam_1.mp4"), str(src / "cam_2"), *rig]
    )
    assert "wide/cam_1.mp4: camera 'cam_1' frame 0: image is 80x48" in msg
    # Names that are not the rig's; a camera without media; a camera given twice.
    msg = _run([out, f"left={src / 'cam_0.mp4'}", str(src / "cam_1.mp4"), str(src / "cam_2"), *rig])
    assert (
        "media of camera(s) left" in msg and "has cam_0, cam_1, cam_2: name each NAME=PATH" in msg
    )
    msg = _run([out, str(src / "cam_0.mp4"), str(src / "cam_1.mp4"), *rig])
    assert "rig camera(s) cam_2 of" in msg and "--drop-missing" in msg
    msg = _run([out, str(src), str(src / "cam_0.mp4"), *rig])
    assert "camera 'cam_0' is given twice" in msg
    # Files that are not media; a corrupt image; a path that does not exist.
    (root / "notes.txt").write_text("x")
    msg = _run(
        [out, str(src / "cam_0.mp4"), str(src / "cam_1.mp4"), f"cam_2={root / 'notes.txt'}", *rig]
    )
    assert "notes.txt: camera 'cam_2': not a video" in msg
    write_images(root / "bad" / "cam_2", 2)
    (root / "bad" / "cam_2" / "img_1.png").write_bytes(b"\x89PNG\r\n\x1a\n truncated")
    msg = _run(
        [out, str(src / "cam_0.mp4"), str(src / "cam_1.mp4"), str(root / "bad" / "cam_2"), *rig]
    )
    assert "img_1.png" in msg
    msg = _run([out, str(root / "nowhere.mp4"), *rig])
    assert "nowhere.mp4: no such file or folder" in msg
    msg = _run([out, str(src), *rig, "--up", "sideways"])
    assert "up: expected 'auto', one of +x" in msg
    # Nothing was written by any of them.
    assert not (root / "cap").exists()
    assert not [p for p in root.iterdir() if p.name.startswith(".cap")]
    # An existing, non-empty folder is refused.
    (root / "cap").mkdir()
    (root / "cap" / "keep.txt").write_text("mine")
    msg = _run([out, str(src), *rig])
    assert "exists and is not an empty folder" in msg
    assert (root / "cap" / "keep.txt").read_text() == "mine"


def test_drop_missing_and_library_errors(media):
    root = media["root"]
    made = make_capture(
        root / "cap",
        media["rig"],
        {"cam_0": media["in"] / "cam_0.mp4", "cam_2": media["in"] / "cam_2"},
        strict=False,
    )
    assert made.dropped == ["cam_1"]
    assert Capture.open(root / "cap").camera_names == ["cam_0", "cam_2"]
    with pytest.raises(ValidationError, match="mode: expected 'copy' or 'link'"):
        make_capture(root / "c2", media["rig"], {"cam_0": media["in"]}, mode="move")
    with pytest.raises(ValidationError, match="fps: must be a positive number"):
        make_capture(root / "c2", media["rig"], {"cam_0": media["in"]}, fps=0.0)
    with pytest.raises(ValidationError, match="no media"):
        make_capture(root / "c2", media["rig"], {})
    with pytest.raises(FileFormatError, match="labels.toml"):
        make_capture(
            root / "c2",
            root / "rig.toml",
            media_by_camera([media["in"]], media["rig"]),
            labels=root / "labels.toml",
        )
    assert not (root / "c2").exists()
