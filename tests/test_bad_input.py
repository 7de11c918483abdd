"""Issue #16: bad input is a one-line error naming the file and the problem, never a traceback.

Every case runs the real ``pointtraj`` command on a real (tiny, synthetic) capture and work
folder that one pipeline run builds for the module; each test damages a copy.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from pointtraj.cli import main


@pytest.fixture(scope="module")
def tiny(tiny_reference) -> tuple[Path, Path]:
    """(capture, work) of the session's tiny pipeline run: copy before damaging."""
    return tiny_reference / "cap", tiny_reference / "work"


@pytest.fixture
def copies(tiny, tmp_path) -> tuple[Path, Path]:
    """A private copy of the tiny capture and of its work folder (recording the copy)."""
    cap = tmp_path / "cap"
    work = tmp_path / "work"
    shutil.copytree(tiny[0], cap, symlinks=True)
    shutil.copytree(tiny[1], work, symlinks=True)
    text = (work / "work.toml").read_text(encoding="utf-8")
    (work / "work.toml").write_text(text.replace(str(tiny[0].resolve()), str(cap)), "utf-8")
    return cap, work


def fails(args: list[str], *names: str) -> str:
    """Run ``pointtraj ARGS``; assert it fails with one ``Error:`` line containing ``names``.

    Returns
    -------
    str
        The error line, without ``Error: ``.
    """
    res = CliRunner().invoke(main, [str(a) for a in args])
    out = res.output
    assert res.exit_code == 1, out
    assert "Traceback" not in out, out
    assert isinstance(res.exception, SystemExit), repr(res.exception)
    errors = [line for line in out.splitlines() if line.startswith("Error:")]
    assert len(errors) == 1, out
    message = errors[0][len("Error: ") :]
    # The message is the whole error: nothing of it spills onto further lines.
    tail = out[out.index("Error:") :].strip()
    assert tail == errors[0], out
    for name in names:
        assert name in message, message
    return message


def truncate(path: Path, fraction: float) -> None:
    """Keep the first ``fraction`` of a file's bytes."""
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * fraction)])


# -- 1. one loader for every npz ---------------------------------------------------------------
def test_truncated_semantic_map(copies):
    _, work = copies
    truncate(work / "semantic_map.npz", 0.5)
    fails(["label", str(work)], str(work / "semantic_map.npz"), "truncated or corrupt")


def test_truncated_affinity(copies):
    _, work = copies
    truncate(work / "affinity.npz", 0.5)
    fails(["label", str(work)], str(work / "affinity.npz"), "truncated or corrupt")


def test_truncated_labels(copies):
    _, work = copies
    truncate(work / "labels.npz", 0.5)
    fails(["render", str(work)], str(work / "labels.npz"), "truncated or corrupt")


def test_npz_missing_array(copies):
    _, work = copies
    data = dict(np.load(work / "affinity.npz"))
    del data["weight"]
    np.savez(work / "affinity.npz", **data)
    fails(["label", str(work)], str(work / "affinity.npz"), "missing array 'weight'")


# -- 2. non-finite coordinates -------------------------------------------------------------------
@pytest.mark.parametrize("value", [np.nan, np.inf])
def test_non_finite_xyz(copies, value):
    _, work = copies
    data = dict(np.load(work / "trajectories.npz"))
    data["xyz"][[3, 7]] = value
    np.savez(work / "trajectories.npz", **data)
    for args in (["affinity", work], ["semantics", work, "-r", "simulated"]):
        message = fails(args, str(work / "trajectories.npz"))
        assert f"xyz: 2 of {len(data['xyz'])} point-frames are NaN or infinite" in message


# -- 3. out-of-range frame selections ------------------------------------------------------------
def test_frames_out_of_range_on_the_command_line(copies, tmp_path):
    cap, _ = copies
    message = fails(["reconstruct", cap, "--out", tmp_path / "w", "--frames", "0:100"], "--frames")
    assert "'0:100' ends at frame 100, but the capture has 3 frames" in message
    assert not (tmp_path / "w" / "trajectories.npz").exists()


def test_frames_out_of_range_in_a_pipeline_file(copies, tmp_path):
    cap, _ = copies
    pipe = tmp_path / "frames.toml"
    pipe.write_text(f'capture = "{cap}"\nwork = "{tmp_path / "w"}"\nframes = "5:"\n', "utf-8")
    message = fails(["run", pipe], f"{pipe}: frames")
    assert "'5:' starts at frame 5, but the capture has 3 frames" in message


# -- 4. images must decode completely ------------------------------------------------------------
@pytest.mark.parametrize("image_format", ["jpg", "png"])
def test_truncated_image(copies, tmp_path, image_format):
    import cv2

    cap, _ = copies
    image = cap / "frames" / "cam02" / "000001.jpg"
    if image_format == "png":  # the same frame as a PNG
        cv2.imwrite(str(image.with_suffix(".png")), cv2.imread(str(image)))
        image.unlink()
        image = image.with_suffix(".png")
    truncate(image, 0.05)
    message = fails(["reconstruct", cap, "--out", tmp_path / "w"], str(image))
    assert "camera 'cam02' frame 1: truncated" in message


# -- 5. duplicate camera sources -----------------------------------------------------------------
@pytest.mark.parametrize("link", ["folder", "files"])
def test_duplicate_camera_source(copies, tmp_path, link):
    cap, _ = copies
    cam3, cam2 = cap / "frames" / "cam03", cap / "frames" / "cam02"
    shutil.rmtree(cam3)
    if link == "folder":
        cam3.symlink_to(cam2, target_is_directory=True)
        shared = cam2
    else:
        cam3.mkdir()
        for f in sorted(cam2.iterdir()):
            (cam3 / f.name).symlink_to(f)
        shared = cam2 / "000000.jpg"
    message = fails(["reconstruct", cap, "--out", tmp_path / "w"], str(cap), "'cam02'", "'cam03'")
    assert f"read the same frames ({shared.resolve()})" in message


# -- 6. a work folder of one rig against another capture -----------------------------------------
@pytest.fixture
def eight_cameras(copies, tmp_path) -> Path:
    """The tiny 4-camera capture grown to 8 cameras (cam04..cam07 copy cam00..cam03)."""
    cap, _ = copies
    big = tmp_path / "cap8"
    shutil.copytree(cap, big)
    rig = (big / "rig.toml").read_text(encoding="utf-8")
    extra = []
    for i in range(4):
        shutil.copytree(big / "frames" / f"cam0{i}", big / "frames" / f"cam0{i + 4}")
        block = rig.split(f"[cam_{i}]")[1].split("\n[cam_")[0]
        extra.append(f"[cam_{i + 4}]" + block.replace(f'"cam0{i}"', f'"cam0{i + 4}"'))
    (big / "rig.toml").write_text(rig.rstrip() + "\n\n" + "\n".join(extra), encoding="utf-8")
    return big


@pytest.mark.parametrize("stage", ["evaluate", "semantics", "render"])
def test_work_folder_of_another_rig(copies, eight_cameras, stage):
    _, work = copies
    shutil.rmtree(work / "report")
    if stage == "render":  # render takes the capture that work.toml records
        text = (work / "work.toml").read_text(encoding="utf-8")
        capture = text.split('capture = "')[1].split('"')[0]
        (work / "work.toml").write_text(text.replace(capture, str(eight_cameras)), "utf-8")
        args = ["render", work]
    else:
        args = [stage, work, "--capture", eight_cameras]
        args += ["-r", "simulated"] if stage == "semantics" else []
    message = fails(args, str(work / "trajectories.npz"), str(eight_cameras))
    assert "its 4 cameras (cam00, cam01, cam02, cam03) are not the 8 cameras" in message
    assert not (work / "report" / "index.md").exists()


# -- 7. labels.toml changed after the semantic map ------------------------------------------------
def _swap_two_classes(cap: Path) -> None:
    text = (cap / "labels.toml").read_text(encoding="utf-8")
    text = text.replace('"left_upper_arm"', '"TMP"').replace(
        '"right_upper_arm"', '"left_upper_arm"'
    )
    (cap / "labels.toml").write_text(text.replace('"TMP"', '"right_upper_arm"'), "utf-8")


@pytest.mark.parametrize("stage", ["label", "evaluate", "render"])
def test_labels_toml_with_swapped_classes(copies, stage):
    cap, work = copies
    _swap_two_classes(cap)
    made = "labels.npz" if stage == "render" else "semantic_map.npz"
    message = fails([stage, work], str(cap / "labels.toml"), str(work / made))
    assert "class 2 is 'right_upper_arm', but 'left_upper_arm' in" in message


# -- 8. a frame without points; a one-camera capture ---------------------------------------------
def test_black_frame_does_not_abort_the_reconstruction(copies, tmp_path, caplog):
    import cv2

    from pointtraj.trajectories import load_cloud

    cap, _ = copies
    for image in (cap / "frames").glob("*/000001.jpg"):
        cv2.imwrite(str(image), np.zeros((256, 320, 3), np.uint8))
    work = tmp_path / "w"
    with caplog.at_level("WARNING", logger="pointtraj"):
        res = CliRunner().invoke(main, ["reconstruct", str(cap), "--out", str(work)])
    assert res.exit_code == 0, res.output
    assert "frame 1: no point reconstructed" in caplog.text
    # Nothing was seen at frame 1: its cloud holds at most the points that stitching
    # interpolated across the black frame (no view).
    cloud = load_cloud(work / "clouds" / "000001.ply")
    assert "track_id" in cloud and not cloud["num_views"].any()
    assert (work / "trajectories.npz").is_file()
    # The later stages go on too; label rewrites every cloud, the empty one included.
    for args in (["semantics", work, "-r", "simulated"], ["affinity", work], ["label", work]):
        res = CliRunner().invoke(main, [str(a) for a in args])
        assert res.exit_code == 0, res.output
    cloud = load_cloud(work / "clouds" / "000001.ply")
    assert "label" in cloud and not cloud["num_views"].any()


def test_one_camera_capture(copies, tmp_path):
    cap, _ = copies
    rig = (cap / "rig.toml").read_text(encoding="utf-8")
    (cap / "rig.toml").write_text(rig.split("\n[cam_1]")[0] + "\n", encoding="utf-8")
    for name in ("cam01", "cam02", "cam03"):
        shutil.rmtree(cap / "frames" / name)
    message = fails(["reconstruct", cap, "--out", tmp_path / "w"], str(cap))
    assert "reconstruction needs at least 2 cameras; the capture has 1 (cam00)" in message


# -- 9. messages that name the right key and the full path ---------------------------------------
def test_eps_e_out_of_range_names_eps_e(tmp_path):
    pipe = tmp_path / "eps.toml"
    pipe.write_text('capture = "c"\nwork = "w"\n[semantics]\neps_e = 1.5\n', encoding="utf-8")
    message = fails(["run", pipe], str(pipe), "eps_e: must be in [0, 1), got 1.5")
    assert "unobserved_visibility" not in message


def test_label_map_beyond_labels_toml_names_the_map(copies):
    cap, work = copies
    text = (cap / "labels.toml").read_text(encoding="utf-8")
    (cap / "labels.toml").write_text("[[classes]]".join(text.split("[[classes]]")[:3]), "utf-8")
    label_map = cap / "gt" / "labels" / "cam00" / "000000.png"
    message = fails(["semantics", work, "-r", "simulated"], str(label_map))
    assert "label_map: class indices must be in -1..1" in message
    assert "(labels.toml has 2 classes)" in message


def test_write_error_names_the_full_destination(copies, tmp_path):
    """An OS error while writing names the file (not the atomic write's temporary)."""
    cap, _ = copies
    work = tmp_path / "w"
    res = CliRunner().invoke(main, ["reconstruct", str(cap), "--out", str(work)])
    assert res.exit_code == 0, res.output
    (work / "state" / "000002.npz").unlink()
    (work / "state" / "000002.npz").mkdir()  # where frame 2's state must go
    (work / "state" / "000002.npz" / "keep").write_text("x")
    message = fails(["reconstruct", cap, "--out", work], f"{work / 'state' / '000002.npz'}: ")
    assert "/." not in message  # no temporary file
