"""body-parts recogniser on real Pose2Sim frames, and the model cache (pointtraj.models).

The MediaPipe model files are fetched once (``pip download mediapipe==0.10.21``, ~36 MB) into
``$POINTTRAJ_CACHE`` or ``~/.cache/pointtraj/models``; the tests that need them skip when the
wheel cannot be fetched (offline) or LiteRT is not installed.
"""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from pointtraj import models
from pointtraj.errors import ValidationError
from pointtraj.labelset import BODY_PARTS
from pointtraj.models import ModelNotFoundError, fetch_model, locate_model

IMAGES = Path(__file__).resolve().parents[2] / "docs" / "images"
PARTS = list(BODY_PARTS)

# Points annotated by hand on the half-resolution frames (x, y pixels) -> the true part.
# cam01 sees the person from the front (their left is on the image's right), cam03 from behind.
ANNOTATIONS = {
    "pose2sim_cam01_f010.jpg": {
        (262, 195): "head",
        (215, 320): "torso",
        (187, 417): "right_thigh",
        (233, 417): "left_thigh",
        (283, 372): "left_forearm",
        (143, 320): "right_forearm",
    },
    "pose2sim_cam03_f010.jpg": {
        (260, 235): "head",
        (297, 363): "torso",
        (253, 363): "left_upper_arm",
        (238, 447): "left_forearm",
        (273, 480): "left_thigh",
        (330, 480): "right_thigh",
    },
}


def _read(name: str) -> np.ndarray:
    import cv2

    image = cv2.imread(str(IMAGES / name))
    assert image is not None, name
    return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)


@pytest.fixture(scope="module")
def recognizer_factory():
    pytest.importorskip("ai_edge_litert", reason="LiteRT (ai-edge-litert) is not installed")
    try:
        locate_model("body-parts", verify=True)
    except ModelNotFoundError:
        try:
            fetch_model("body-parts")
        except ModelNotFoundError as exc:
            pytest.skip(f"cannot fetch the mediapipe==0.10.21 wheel: {exc}")
    from pointtraj.semantics.recognizers.bodyparts import BodyPartRecognizer

    return BodyPartRecognizer


@pytest.mark.parametrize("name", sorted(ANNOTATIONS))
def test_parts_at_annotated_points(recognizer_factory, name):
    """Left and right are the person's own, in a front and a back view."""
    classes = [*PARTS, "ball"]
    rec = recognizer_factory(classes)
    image = _read(name)
    maps = rec.recognize(image)
    H, W = image.shape[:2]
    h, w = maps.shape[:2]
    assert maps.dtype == np.float32 and max(h, w) == 512 and h <= H and w <= W
    assert maps.min() >= 0 and maps.max() <= 1
    assert np.all(maps[..., classes.index("ball")] == 0)
    for (x, y), part in ANNOTATIONS[name].items():
        i, j = int((y + 0.5) * h / H), int((x + 0.5) * w / W)
        got = classes[int(np.argmax(maps[i, j]))]
        assert got == part, f"{name} ({x}, {y}): expected {part}, got {got}"
        assert maps[i, j].max() > 0.5
    # Background (top-left corner: lab wall) has no confidence.
    assert maps[:20, :20].max() < 0.05


def test_landmarks_and_mapping(recognizer_factory):
    image = _read("pose2sim_cam01_f010.jpg")
    rec = recognizer_factory(
        ["person", "limbs"],
        mapping={"person": "person", "left_shin": "limbs", "right_shin": "limbs"},
    )
    poses = rec.estimate_poses(image)
    assert len(poses) == 1 and poses[0].landmarks.shape == (33, 2)
    lm = poses[0].landmarks
    assert lm[0, 1] < lm[11, 1] < lm[23, 1] < lm[25, 1] < lm[27, 1]  # nose above ... ankles
    assert lm[11, 0] > lm[12, 0]  # front view: the left shoulder is on the image's right
    maps = rec.recognize(image)
    assert maps.shape[2] == 2
    assert (maps[..., 0] > 0.5).mean() > 0.03  # the person mask
    assert maps[..., 1].max() > 0.5
    assert maps[..., 1].sum() < maps[..., 0].sum()


def test_no_person_gives_zeros(recognizer_factory):
    rec = recognizer_factory(PARTS, map_size=64)
    maps = rec.recognize(np.full((120, 90, 3), 200, np.uint8))
    assert maps.shape == (64, 48, 14)
    assert np.all(maps == 0)


def test_options_are_checked(recognizer_factory):
    with pytest.raises(ValidationError, match="valid names"):
        recognizer_factory(PARTS, mapping={"tail": "torso"})
    with pytest.raises(ValidationError, match="softness"):
        recognizer_factory(PARTS, softness=0)


# -- model cache ------------------------------------------------------------------------------


def _fake_wheel(path: Path, *, drop: str | None = None) -> Path:
    """A zip laid out like the mediapipe wheel (members with small placeholder contents)."""
    spec = models.MODELS["body-parts"]
    with zipfile.ZipFile(path, "w") as zf:
        for member in [*spec.files.values(), spec.licence_member]:
            if member != drop:
                zf.writestr(member, f"content of {member}")
    return path


def test_fetch_extracts_and_verifies(tmp_path, monkeypatch):
    monkeypatch.setenv("POINTTRAJ_CACHE", str(tmp_path / "cache"))
    with pytest.raises(ModelNotFoundError, match="pointtraj models fetch body-parts"):
        locate_model("body-parts")
    folder = fetch_model("body-parts", wheel=_fake_wheel(tmp_path / "mp.whl"))
    assert folder == tmp_path / "cache" / "body-parts"
    manifest = json.loads((folder / "manifest.json").read_text())
    assert manifest["licence"] == "Apache-2.0"
    assert set(manifest["files"]) == {*models.MODELS["body-parts"].files, "LICENSE"}
    files = locate_model("body-parts", verify=True)
    assert files["pose_detection.tflite"].read_text().startswith("content of")
    assert models.model_status("body-parts") == "cached"
    files["pose_landmark_full.tflite"].write_text("tampered")
    with pytest.raises(ModelNotFoundError, match="checksum"):
        locate_model("body-parts", verify=True)
    assert models.model_status("body-parts") == "corrupt"
    fetch_model("body-parts", wheel=_fake_wheel(tmp_path / "mp.whl"))  # repairs it
    assert models.model_status("body-parts") == "cached"


def test_fetch_errors(tmp_path, monkeypatch):
    monkeypatch.setenv("POINTTRAJ_CACHE", str(tmp_path / "cache"))
    member = models.MODELS["body-parts"].files["pose_landmark_full.tflite"]
    with pytest.raises(ModelNotFoundError, match="has no .*pose_landmark_full"):
        fetch_model("body-parts", wheel=_fake_wheel(tmp_path / "bad.whl", drop=member))
    with pytest.raises(ModelNotFoundError, match="valid names"):
        fetch_model("hands")


def test_models_cli(tmp_path, monkeypatch):
    from pointtraj.cli import main

    monkeypatch.setenv("POINTTRAJ_CACHE", str(tmp_path / "cache"))
    runner = CliRunner()
    result = runner.invoke(main, ["models", "list"])
    assert result.exit_code == 0, result.output
    assert "body-parts" in result.output and "missing" in result.output
    wheel = _fake_wheel(tmp_path / "mp.whl")
    result = runner.invoke(main, ["models", "fetch", "body-parts", "--wheel", str(wheel)])
    assert result.exit_code == 0, result.output
    assert "cached" in runner.invoke(main, ["models", "list"]).output
    result = runner.invoke(main, ["models", "fetch", "nope"])
    assert result.exit_code != 0 and "valid names" in result.output


def test_two_people_side_by_side(recognizer_factory):
    """A front and a back view pasted side by side: the default (every person, issue 17: it
    kept one) and max_people=2 find both, 1 finds one; the person-id map tells them apart."""
    image = np.concatenate(
        [_read("pose2sim_cam01_f010.jpg")[:, :540], _read("pose2sim_cam03_f010.jpg")[:, :540]],
        axis=1,
    )
    default = recognizer_factory(PARTS)
    assert default.max_people is None
    for rec in (default, recognizer_factory(PARTS, max_people=2)):
        poses = rec.estimate_poses(image)
        assert len(poses) == 2
        centres = sorted(float(p.landmarks[[11, 12, 23, 24], 0].mean()) for p in poses)
        assert centres[0] < 540 < centres[1]
    assert len(recognizer_factory(PARTS, max_people=1).estimate_poses(image)) == 1
    L2D, people = default.recognize_people(image)
    np.testing.assert_array_equal(L2D, default.recognize(image))
    assert people.shape == L2D.shape[:2] and people.dtype == np.int16
    half = people.shape[1] // 2
    left = np.unique(people[:, :half][people[:, :half] >= 0])
    right = np.unique(people[:, half:][people[:, half:] >= 0])
    assert len(left) == 1 and len(right) == 1 and left[0] != right[0]
    with pytest.raises(ValidationError, match="max_people"):
        recognizer_factory(PARTS, max_people=0)


def test_missing_model_files_name_the_fetch_command(tmp_path, monkeypatch):
    pytest.importorskip("ai_edge_litert", reason="LiteRT (ai-edge-litert) is not installed")
    from pointtraj.semantics.recognizers.bodyparts import BodyPartRecognizer

    monkeypatch.setenv("POINTTRAJ_CACHE", str(tmp_path))
    with pytest.raises(ModelNotFoundError, match="pointtraj models fetch body-parts"):
        BodyPartRecognizer(PARTS)
    with pytest.raises(ValidationError, match="does not exist"):
        BodyPartRecognizer(PARTS, model_dir=str(tmp_path))
