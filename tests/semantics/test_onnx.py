"""onnx-segmentation and onnx-detection on small real ONNX models built with onnx.helper."""

from __future__ import annotations

import numpy as np
import pytest

from pointtraj.errors import ValidationError
from pointtraj.semantics.recognizers.onnx import (
    Detections,
    OnnxDetectionRecognizer,
    OnnxSegmentationRecognizer,
    boxes_to_confidence_maps,
    decode_detections,
    suppress_detections,
    tile_windows,
)

onnx = pytest.importorskip("onnx", reason="the onnx package builds the test models")
from onnx import TensorProto, helper, numpy_helper  # noqa: E402

RNG_SEED = 7


def _save(graph, path) -> str:
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)])
    model.ir_version = 8
    onnx.checker.check_model(model)
    onnx.save(model, str(path))
    return str(path)


def _conv_model(path, weight: np.ndarray, bias: np.ndarray, size: int, nhwc: bool = False) -> str:
    """A 1x1 convolution: logits[l] = sum_c weight[l, c] * x[c] + bias[l]."""
    L = weight.shape[0]
    nodes, inits = (
        [],
        [
            numpy_helper.from_array(weight.reshape(L, 3, 1, 1).astype(np.float32), "W"),
            numpy_helper.from_array(bias.astype(np.float32), "B"),
        ],
    )
    conv_in = "image"
    if nhwc:
        nodes.append(helper.make_node("Transpose", ["image"], ["chw"], perm=[0, 3, 1, 2]))
        conv_in = "chw"
    nodes.append(helper.make_node("Conv", [conv_in, "W", "B"], ["logits"]))
    shape = [1, size, size, 3] if nhwc else [1, 3, size, size]
    graph = helper.make_graph(
        nodes,
        "seg",
        [helper.make_tensor_value_info("image", TensorProto.FLOAT, shape)],
        [helper.make_tensor_value_info("logits", TensorProto.FLOAT, [1, L, size, size])],
        inits,
    )
    return _save(graph, path)


def _const_model(path, outputs: dict[str, np.ndarray], size: int = 32) -> str:
    """A model whose outputs are constants (it ignores its image input)."""
    nodes, infos = [], []
    for name, value in outputs.items():
        tensor = numpy_helper.from_array(value, name + "_value")
        nodes.append(helper.make_node("Constant", [], [name], value=tensor))
        dtype = helper.np_dtype_to_tensor_dtype(value.dtype)
        infos.append(helper.make_tensor_value_info(name, dtype, list(value.shape)))
    graph = helper.make_graph(
        nodes,
        "det",
        [helper.make_tensor_value_info("images", TensorProto.FLOAT, [1, 3, size, size])],
        infos,
    )
    return _save(graph, path)


def _softmax(x: np.ndarray) -> np.ndarray:
    e = np.exp(x - x.max(axis=-1, keepdims=True))
    return e / e.sum(axis=-1, keepdims=True)


WEIGHT = np.array([[4.0, -1.0, 0.5], [-2.0, 3.0, 1.0], [0.0, 0.5, -3.0]])
BIAS = np.array([0.1, -0.2, 0.3])


def test_segmentation_softmax_mapping_exact(tmp_path):
    model = _conv_model(tmp_path / "seg.onnx", WEIGHT, BIAS, 8)
    image = np.random.default_rng(RNG_SEED).integers(0, 256, (8, 8, 3), dtype=np.uint8)
    rec = OnnxSegmentationRecognizer(
        ["torso", "ball", "head", "unused"],
        model=model,
        labels=["head", "torso", "ball"],
        activation="softmax",
    )
    out = rec.recognize(image)
    assert out.shape == (8, 8, 4) and out.dtype == np.float32
    expected = _softmax(image / 255.0 @ WEIGHT.T + BIAS)  # (8, 8, 3) in model label order
    np.testing.assert_allclose(out[..., 0], expected[..., 1], atol=1e-6)  # torso
    np.testing.assert_allclose(out[..., 1], expected[..., 2], atol=1e-6)  # ball
    np.testing.assert_allclose(out[..., 2], expected[..., 0], atol=1e-6)  # head
    assert np.all(out[..., 3] == 0)


def test_segmentation_bgr_mean_std_sigmoid_nhwc(tmp_path):
    model = _conv_model(tmp_path / "seg.onnx", WEIGHT, BIAS, 8, nhwc=True)
    image = np.random.default_rng(RNG_SEED + 1).integers(0, 256, (8, 8, 3), dtype=np.uint8)
    mean, std = (0.4, 0.5, 0.6), (0.2, 0.25, 0.3)
    rec = OnnxSegmentationRecognizer(
        ["a", "b", "c"],
        model=model,
        labels=["a", "b", "c"],
        activation="sigmoid",
        color="bgr",
        mean=mean,
        std=std,
    )
    assert rec.net.pre.layout == "nhwc"
    x = (image[..., ::-1] / 255.0 - mean) / std
    expected = 1 / (1 + np.exp(-(x @ WEIGHT.T + BIAS)))
    np.testing.assert_allclose(rec.recognize(image), expected, atol=1e-5)


def test_segmentation_letterbox_crops_padding(tmp_path):
    """A 4x8 image letterboxed into 8x8: the map covers only the 4 image rows."""
    model = _conv_model(tmp_path / "seg.onnx", WEIGHT, BIAS, 8)
    image = np.random.default_rng(RNG_SEED + 2).integers(0, 256, (4, 8, 3), dtype=np.uint8)
    rec = OnnxSegmentationRecognizer(
        ["0", "1", "2"], model=model, resize="letterbox", activation="softmax"
    )
    out = rec.recognize(image)
    assert out.shape == (4, 8, 3)
    np.testing.assert_allclose(out, _softmax(image / 255.0 @ WEIGHT.T + BIAS), atol=1e-6)


def test_segmentation_errors(tmp_path):
    model = _conv_model(tmp_path / "seg.onnx", WEIGHT, BIAS, 8)
    with pytest.raises(ValidationError, match="not a class"):
        OnnxSegmentationRecognizer(["a"], model=model, labels=["x", "y", "z"], mapping={"x": "b"})
    with pytest.raises(ValidationError, match="valid choices"):
        OnnxSegmentationRecognizer(["a"], model=model, activation="relu")
    with pytest.raises(ValidationError, match="no such ONNX file"):
        OnnxSegmentationRecognizer(["a"], model=tmp_path / "missing.onnx")
    rec = OnnxSegmentationRecognizer(["a"], model=model, labels=["a", "b"])
    with pytest.raises(ValidationError, match="3 channels"):
        rec.recognize(np.zeros((8, 8, 3), np.uint8))
    with pytest.raises(ValidationError, match="image"):
        rec.recognize(np.zeros((8, 8), np.uint8))


# Detection: input 32x32, image 64x64 -> letterbox scale 0.5, no padding.
# Boxes (cx, cy, w, h) in model pixels and class scores over [person, sports_ball, chair].
CANDIDATES = [
    ((10, 10, 8, 8), (0.9, 0.0, 0.0)),  # A: person -> image x, y in [12, 28)
    ((11, 10, 8, 8), (0.8, 0.0, 0.0)),  # B: overlaps A (IoU 0.78): suppressed
    ((24, 24, 4, 6), (0.0, 0.6, 0.0)),  # C: ball -> image x [44, 52), y [42, 54)
    ((16, 16, 8, 8), (0.5, 0.0, 0.0)),  # D: person, IoU 0.03 with A -> x, y in [24, 40)
    ((5, 28, 4, 4), (0.0, 0.0, 0.1)),  # E: below the threshold
]
LABELS = ["person", "sports_ball", "chair"]


def _expected_detection_maps() -> np.ndarray:
    exp = np.zeros((64, 64, 3), np.float32)  # classes: torso, ball, chair
    exp[24:40, 24:40, 0] = 0.5
    exp[12:28, 12:28, 0] = 0.9
    exp[42:54, 44:52, 1] = 0.6
    return exp


def _yolov8(cands) -> np.ndarray:
    rows = np.array([[*b, *s] for b, s in cands], np.float32)  # (N, 4 + nc)
    return rows.T[None].copy()  # (1, 4 + nc, N)


def test_detection_yolov8_exact(tmp_path):
    model = _const_model(tmp_path / "det.onnx", {"output0": _yolov8(CANDIDATES)})
    rec = OnnxDetectionRecognizer(
        ["torso", "ball", "chair"],
        model=model,
        labels=LABELS,
        mapping={"person": "torso", "sports_ball": "ball"},
    )
    image = np.zeros((64, 64, 3), np.uint8)
    det = rec.detect(image)
    np.testing.assert_allclose(det.scores, [0.9, 0.6, 0.5], atol=1e-6)
    np.testing.assert_allclose(det.boxes[0], [12, 12, 28, 28])
    np.testing.assert_array_equal(rec.recognize(image), _expected_detection_maps())


def test_detection_yolov5_and_generic_layouts_agree(tmp_path):
    rows = np.array([[*b, 1.0, *s] for b, s in CANDIDATES], np.float32)
    rows[:, 4] = 0.5  # objectness halves every confidence
    rows[:, 5:] *= 2.0
    v5 = _const_model(tmp_path / "v5.onnx", {"output0": rows[None]})
    b = np.array([c[0] for c in CANDIDATES], np.float32)
    xyxy = np.concatenate([b[:, :2] - b[:, 2:] / 2, b[:, :2] + b[:, 2:] / 2], axis=1)
    s = np.array([max(c[1]) for c in CANDIDATES], np.float32)
    lab = np.array([int(np.argmax(c[1])) for c in CANDIDATES], np.int64)
    generic = _const_model(
        tmp_path / "bsl.onnx", {"det_scores": s, "det_labels": lab, "det_boxes": xyxy[None]}
    )
    image = np.zeros((64, 64, 3), np.uint8)
    mapping = {"person": "torso", "sports_ball": "ball"}
    for path in (v5, generic):
        rec = OnnxDetectionRecognizer(
            ["torso", "ball", "chair"], model=path, labels=LABELS, mapping=mapping
        )
        np.testing.assert_allclose(rec.recognize(image), _expected_detection_maps(), atol=1e-6)


def test_detection_unnamed_classes_and_map_size(tmp_path):
    model = _const_model(tmp_path / "det.onnx", {"output0": _yolov8(CANDIDATES)})
    rec = OnnxDetectionRecognizer(
        ["x", "ball"], model=model, mapping={"1": "ball"}, map_size=32, format="yolov8"
    )
    out = rec.recognize(np.zeros((64, 64, 3), np.uint8))
    assert out.shape == (32, 32, 2)
    assert np.all(out[..., 0] == 0)
    expected = np.zeros((32, 32), np.float32)
    expected[21:27, 22:26] = 0.6
    np.testing.assert_allclose(out[..., 1], expected, atol=1e-6)
    with pytest.raises(ValidationError, match="named by index"):
        OnnxDetectionRecognizer(["ball"], model=model, mapping={"sports_ball": "ball"})


def test_detection_class_count_mismatch(tmp_path):
    model = _const_model(tmp_path / "det.onnx", {"output0": _yolov8(CANDIDATES)})
    rec = OnnxDetectionRecognizer(["a"], model=model, labels=["a", "b"], format="yolov8")
    with pytest.raises(ValidationError, match="3 classes"):
        rec.recognize(np.zeros((64, 64, 3), np.uint8))


def test_boxes_to_maps_max_and_clipping():
    boxes = np.array([[-5, -5, 3, 3], [1, 1, 10, 10], [2, 2, 3, 3]], float)
    maps = boxes_to_confidence_maps(boxes, [0.2, 0.7, 0.9], [0, 0, -1], 1, (4, 5))
    exp = np.zeros((4, 5), np.float32)
    exp[:3, :3] = 0.2
    exp[1:, 1:] = 0.7
    np.testing.assert_array_equal(maps[..., 0], exp)


def test_suppress_detections_per_class():
    """Two overlapping boxes of different classes both survive NMS."""
    det = Detections(
        np.array([[0, 0, 10, 10], [0, 0, 10, 10], [0, 0, 10, 9.5]], float),
        np.array([0.9, 0.8, 0.7]),
        np.array([0, 1, 0]),
    )
    kept = suppress_detections(det, 0.25, 0.45)
    np.testing.assert_array_equal(kept.labels, [0, 1])
    assert len(suppress_detections(det, 0.95, 0.45)) == 0


def _ssd_outputs(rows, count: int | None = None) -> dict[str, np.ndarray]:
    """TFLite_Detection_PostProcess-like outputs: rows of ((y0, x0, y1, x1) in [0, 1], id, score)."""
    boxes = np.array([r[0] for r in rows], np.float32)[None]  # (1, N, 4)
    classes = np.array([r[1] for r in rows], np.float32)[None]  # (1, N)
    scores = np.array([r[2] for r in rows], np.float32)[None]  # (1, N)
    n = np.array([len(rows) if count is None else count], np.float32)  # (1,)
    return {"boxes": boxes, "classes": classes, "scores": scores, "count": n}


def test_detection_ssd_layout_with_sparse_label_ids(tmp_path):
    """SSD outputs (normalised y0, x0, y1, x1; sparse class ids; a valid-row count)."""
    rows = [
        ((0.25, 0.125, 0.5, 0.375), 36, 0.9),  # sports_ball (id 36)
        ((0.5, 0.5, 1.0, 0.75), 0, 0.6),  # person (id 0)
        ((0.0, 0.0, 0.25, 0.25), 5, 0.95),  # id 5 is no label: dropped
        ((0.0, 0.75, 0.25, 1.0), 0, 0.3),  # below the score threshold
        ((0.75, 0.0, 1.0, 0.25), 0, 0.99),  # beyond the count: ignored
    ]
    model = _const_model(tmp_path / "ssd.onnx", _ssd_outputs(rows, count=4), size=32)
    rec = OnnxDetectionRecognizer(
        ["ball", "torso"],
        model=model,
        labels=["person", "sports_ball"],
        label_ids=[0, 36],
        mapping={"person": "torso", "sports_ball": "ball"},
        resize="stretch",
        score_threshold=0.4,
    )
    image = np.zeros((64, 128, 3), np.uint8)  # stretched to 32x32: x / 4, y / 2
    det = rec.detect(image)
    np.testing.assert_allclose(det.scores, [0.9, 0.6], atol=1e-6)
    np.testing.assert_array_equal(det.labels, [1, 0])
    np.testing.assert_allclose(det.boxes, [[16, 16, 48, 32], [64, 32, 96, 64]], atol=1e-4)
    maps = rec.recognize(image)
    expected = np.zeros((64, 128, 2), np.float32)
    expected[16:32, 16:48, 0] = 0.9
    expected[32:64, 64:96, 1] = 0.6
    np.testing.assert_allclose(maps, expected, atol=1e-6)
    # "auto" recognises the layout; an explicit format on other outputs fails clearly.
    assert decode_detections(list(_ssd_outputs(rows).values()), []).boxes.shape == (5, 4)
    wrong = _const_model(tmp_path / "v8.onnx", {"output0": _yolov8(CANDIDATES)})
    rec = OnnxDetectionRecognizer(["ball"], model=wrong, format="ssd")
    with pytest.raises(ValidationError, match="ssd output"):
        rec.detect(image)


def test_detection_tiles_find_boxes_in_each_window(tmp_path):
    """A constant box is reported once per window (whole image, then 2 tiles), shifted."""
    model = _const_model(
        tmp_path / "det.onnx", {"output0": _yolov8([((20, 30, 8, 8), (0.0, 0.8))])}, size=64
    )
    rec = OnnxDetectionRecognizer(
        ["ball"], model=model, labels=["person", "ball"], tiles=(2, 1), tile_overlap=0.0
    )
    image = np.zeros((64, 128, 3), np.uint8)
    det = rec.detect(image)
    # whole image: letterbox scale 0.5, 16 rows of padding; tiles: 64x64, scale 1.
    boxes = sorted(map(tuple, det.boxes.round(6).tolist()))
    assert boxes == [(16, 26, 24, 34), (32, 20, 48, 36), (80, 26, 88, 34)]
    expected = np.zeros((64, 128), np.float32)
    expected[26:34, 16:24] = expected[20:36, 32:48] = expected[26:34, 80:88] = 0.8
    np.testing.assert_allclose(rec.recognize(image)[..., 0], expected, atol=1e-6)


def test_tile_windows_cover_the_image():
    windows = tile_windows(1080, 1920, (2, 3), 0.25)
    assert windows[0] == (0, 0, 1080, 1920) and len(windows) == 7
    covered = np.zeros((1920, 1080), bool)
    for x0, y0, x1, y1 in windows[1:]:
        assert 0 <= x0 < x1 <= 1080 and 0 <= y0 < y1 <= 1920
        covered[y0:y1, x0:x1] = True
    assert covered.all()
    assert windows[1][2] > windows[2][0]  # neighbours overlap
    assert tile_windows(10, 10, (1, 1), 0.5) == [(0, 0, 10, 10)]


def test_detection_option_errors(tmp_path):
    model = _const_model(tmp_path / "det.onnx", {"output0": _yolov8(CANDIDATES)})
    with pytest.raises(ValidationError, match="tiles"):
        OnnxDetectionRecognizer(["a"], model=model, tiles=(0, 2))
    with pytest.raises(ValidationError, match="tile_overlap"):
        OnnxDetectionRecognizer(["a"], model=model, tile_overlap=1.0)
    with pytest.raises(ValidationError, match="label_ids: needs 'labels'"):
        OnnxDetectionRecognizer(["a"], model=model, label_ids=[0])
    with pytest.raises(ValidationError, match="expected 2 distinct"):
        OnnxDetectionRecognizer(["a"], model=model, labels=["a", "b"], label_ids=[3, 3])
    with pytest.raises(ValidationError, match="no such TFLite file"):
        OnnxDetectionRecognizer(["a"], model=tmp_path / "missing.tflite")
