"""Pre- and post-processing shared by the ONNX and LiteRT recognisers.

Pre-processing (:class:`Preprocessing`, :func:`prepare_input`): input size, letterbox or stretch
resize, RGB or BGR, ``(x * scale - mean) / std`` normalisation and NCHW or NHWC layout.
Post-processing: detector outputs to boxes (:func:`decode_detections`, SSD included),
non-maximum suppression (:func:`suppress_detections`), tiling (:func:`tile_windows`), boxes to
confidence maps (:func:`boxes_to_confidence_maps`) and model labels to classes
(:func:`resolve_mapping`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from ...errors import ValidationError, check_array

_RESIZE = ("letterbox", "stretch")
_COLOR = ("rgb", "bgr")
_LAYOUT = ("auto", "nchw", "nhwc")
_ACTIVATION = ("none", "softmax", "sigmoid")
_DET_FORMAT = ("auto", "yolov8", "yolov5", "boxes_scores_labels", "ssd")


def _choice(name: str, value: str, choices: Sequence[str]) -> str:
    if value not in choices:
        raise ValidationError(f"{name}: got {value!r}; valid choices: {', '.join(choices)}")
    return value


@dataclass(frozen=True)
class Preprocessing:
    """How an image becomes a model input tensor.

    Attributes
    ----------
    size : (int, int)
        Model input (width, height) in pixels.
    resize : {"letterbox", "stretch"}
        Keep the aspect ratio and pad (letterbox, centred) or stretch to ``size``.
    color : {"rgb", "bgr"}
        Channel order the model expects.
    mean, std : (3,) float
        Per-channel normalisation ``(x * scale - mean) / std``, in the model's channel order.
    scale : float
        Multiplier applied to the 0-255 pixel values first (``1/255`` maps to [0, 1]).
    layout : {"nchw", "nhwc"}
        Tensor layout.
    pad_value : float
        Pixel value (0-255) of letterbox padding.
    """

    size: tuple[int, int]
    resize: str = "letterbox"
    color: str = "rgb"
    mean: tuple[float, float, float] = (0.0, 0.0, 0.0)
    std: tuple[float, float, float] = (1.0, 1.0, 1.0)
    scale: float = 1.0 / 255.0
    layout: str = "nchw"
    pad_value: float = 114.0


def prepare_input(
    image: np.ndarray, pre: Preprocessing, dtype: type = np.float32
) -> tuple[np.ndarray, np.ndarray]:
    """Resize, normalise and lay out an image as a batch of one.

    Parameters
    ----------
    image : (H, W, 3) uint8 ndarray
        RGB image.
    pre : Preprocessing
        The recipe.
    dtype : numpy dtype
        Tensor dtype (``uint8`` skips normalisation).

    Returns
    -------
    tensor : (1, 3, h, w) or (1, h, w, 3) ndarray
        The model input.
    transform : (4,) float ndarray
        ``(sx, sy, px, py)``: a model-input pixel is ``x_model = x_image * sx + px`` (and the
        same for y).
    """
    import cv2

    H, W = image.shape[:2]
    w, h = pre.size
    if pre.resize == "letterbox":
        s = min(w / W, h / H)
        nw, nh = max(1, round(W * s)), max(1, round(H * s))
        px, py = (w - nw) // 2, (h - nh) // 2
        canvas = np.full((h, w, 3), pre.pad_value, dtype=np.uint8)
        canvas[py : py + nh, px : px + nw] = cv2.resize(
            image, (nw, nh), interpolation=cv2.INTER_AREA if s < 1 else cv2.INTER_LINEAR
        )
        transform = np.array([nw / W, nh / H, px, py], dtype=np.float64)
    else:
        shrink = w <= W and h <= H  # area averaging avoids aliasing when shrinking
        canvas = cv2.resize(
            image, (w, h), interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR
        )
        transform = np.array([w / W, h / H, 0.0, 0.0], dtype=np.float64)
    if pre.color == "bgr":
        canvas = canvas[..., ::-1]
    if np.dtype(dtype) == np.uint8:
        tensor = np.ascontiguousarray(canvas)
    else:
        mean = np.asarray(pre.mean, dtype=np.float32)
        std = np.asarray(pre.std, dtype=np.float32)
        tensor = ((canvas.astype(np.float32) * np.float32(pre.scale) - mean) / std).astype(dtype)
    if pre.layout == "nchw":
        tensor = tensor.transpose(2, 0, 1)
    return np.ascontiguousarray(tensor[None]), transform


@dataclass(frozen=True)
class Detections:
    """Boxes found in one image.

    Attributes
    ----------
    boxes : (B, 4) float ndarray
        ``x0, y0, x1, y1`` in image pixels.
    scores : (B,) float ndarray
        Confidences in [0, 1].
    labels : (B,) int ndarray
        Model class indices.
    """

    boxes: np.ndarray
    scores: np.ndarray
    labels: np.ndarray

    def __len__(self) -> int:
        return len(self.scores)


def _xywh_to_xyxy(b: np.ndarray) -> np.ndarray:
    half = b[:, 2:4] / 2
    return np.concatenate([b[:, :2] - half, b[:, :2] + half], axis=1)  # (B, 4)


def decode_detections(
    outputs: Sequence[np.ndarray],
    output_names: Sequence[str],
    *,
    num_labels: int | None = None,
    fmt: str = "auto",
    box_format: str = "xyxy",
    normalized: bool = False,
    input_size: tuple[int, int] = (1, 1),
) -> Detections:
    """Turn raw detector outputs into boxes in model-input pixels.

    Parameters
    ----------
    outputs : sequence of ndarray
        The model's outputs, in order.
    output_names : sequence of str
        Their names (used to find ``boxes``/``scores``/``labels`` in the generic format).
    num_labels : int, optional
        Number of model classes ``nc``; resolves the YOLO layouts.
    fmt : {"auto", "yolov8", "yolov5", "boxes_scores_labels", "ssd"}
        ``yolov8``: one output ``[1, 4 + nc, N]`` (cx, cy, w, h, class scores).
        ``yolov5``: one output ``[1, N, 5 + nc]`` (cx, cy, w, h, objectness, class scores;
        confidence = objectness x class score). ``boxes_scores_labels``: three outputs, boxes
        ``(N, 4)``, scores ``(N,)`` and labels ``(N,)`` (a leading batch axis of 1 is dropped).
        ``ssd``: the four outputs of TensorFlow Lite's ``TFLite_Detection_PostProcess``, boxes
        ``[1, N, 4]`` (``y0, x0, y1, x1`` in [0, 1] of the input), classes ``[1, N]``, scores
        ``[1, N]`` and the number of valid rows ``[1]``. ``auto`` picks by the number and
        shapes of the outputs.
    box_format : {"xyxy", "xywh"}
        Box encoding of the generic format (``xywh`` = centre, size).
    normalized : bool
        Generic-format boxes are in [0, 1] of the input size.
    input_size : (int, int)
        Model input (width, height), for ``normalized``.

    Returns
    -------
    Detections
        Every candidate (before thresholding and NMS), boxes in model-input pixels.

    Raises
    ------
    ValidationError
        If the outputs match none of the formats.
    """
    _choice("format", fmt, _DET_FORMAT)
    if fmt == "auto" and _looks_like_ssd(outputs):
        fmt = "ssd"
    if fmt == "ssd":
        return _decode_ssd(outputs, input_size)
    if fmt == "auto":
        fmt = "boxes_scores_labels" if len(outputs) >= 3 else ""
        if not fmt:
            out = np.asarray(outputs[0])
            if out.ndim != 3:
                raise ValidationError(
                    f"detection output: expected [1, 4+nc, N] or [1, N, 5+nc], got {out.shape}"
                )
            if num_labels is not None and out.shape[1] == 4 + num_labels:
                fmt = "yolov8"
            elif num_labels is not None and out.shape[2] == 5 + num_labels:
                fmt = "yolov5"
            else:
                fmt = "yolov8" if out.shape[1] < out.shape[2] else "yolov5"
    if fmt in ("yolov8", "yolov5"):
        out = np.asarray(outputs[0], dtype=np.float32)
        if out.ndim != 3 or out.shape[0] != 1:
            raise ValidationError(f"{fmt} output: expected a batch of one, got {out.shape}")
        rows = out[0].T if fmt == "yolov8" else out[0]  # (N, 4 + nc) or (N, 5 + nc)
        first = 4 if fmt == "yolov8" else 5
        if rows.shape[1] <= first:
            raise ValidationError(f"{fmt} output: too few values per box, got {out.shape}")
        class_scores = rows[:, first:]  # (N, nc)
        if num_labels is not None and class_scores.shape[1] != num_labels:
            raise ValidationError(
                f"{fmt} output {out.shape} has {class_scores.shape[1]} classes, but "
                f"{num_labels} labels were given"
            )
        labels = np.argmax(class_scores, axis=1)
        scores = class_scores[np.arange(len(rows)), labels]
        if fmt == "yolov5":
            scores = scores * rows[:, 4]
        return Detections(_xywh_to_xyxy(rows[:, :4].astype(np.float64)), scores, labels)
    # boxes / scores / labels, found by name, else by order.
    if len(outputs) < 3:
        raise ValidationError(
            f"boxes_scores_labels: expected 3 outputs, the model has {len(outputs)}"
        )
    order = {}
    for key, words in (
        ("boxes", ("box",)),
        ("scores", ("score", "conf")),
        ("labels", ("label", "class")),
    ):
        hits = [i for i, n in enumerate(output_names) if any(w in n.lower() for w in words)]
        if len(hits) == 1:
            order[key] = hits[0]
    if len(order) < 3:
        order = {"boxes": 0, "scores": 1, "labels": 2}
    boxes = np.asarray(outputs[order["boxes"]], dtype=np.float64)
    scores = np.asarray(outputs[order["scores"]], dtype=np.float64)
    labels = np.asarray(outputs[order["labels"]])
    if boxes.ndim == 3 and boxes.shape[0] == 1:
        boxes, scores, labels = boxes[0], scores.reshape(-1), labels.reshape(-1)
    boxes = check_array("boxes output", boxes, (None, 4), dtype=np.float64)
    scores = check_array("scores output", scores.reshape(-1), (len(boxes),), dtype=np.float64)
    labels = check_array("labels output", labels.reshape(-1), (len(boxes),), dtype=np.int64)
    if box_format == "xywh":
        boxes = _xywh_to_xyxy(boxes)
    if normalized:
        boxes = boxes * np.array([*input_size, *input_size], dtype=np.float64)
    return Detections(boxes, scores, labels)


def _looks_like_ssd(outputs: Sequence[np.ndarray]) -> bool:
    """Four outputs shaped like ``TFLite_Detection_PostProcess``: (1, N, 4), (1, N) x 2, (1,)."""
    if len(outputs) != 4:
        return False
    b, c, s, n = (np.shape(o) for o in outputs)
    return len(b) == 3 and b[0] == 1 and b[2] == 4 and c == s == (1, b[1]) and int(np.prod(n)) == 1


def _decode_ssd(outputs: Sequence[np.ndarray], input_size: tuple[int, int]) -> Detections:
    """Detections from the four ``TFLite_Detection_PostProcess`` outputs (model pixels)."""
    if not _looks_like_ssd(outputs):
        raise ValidationError(
            "ssd output: expected boxes [1, N, 4], classes [1, N], scores [1, N] and a count "
            f"[1], got shapes {[tuple(np.shape(o)) for o in outputs]}"
        )
    boxes = np.asarray(outputs[0], dtype=np.float64)[0]  # (N, 4) y0, x0, y1, x1 in [0, 1]
    classes = np.asarray(outputs[1], dtype=np.float64)[0]  # (N,)
    scores = np.asarray(outputs[2], dtype=np.float64)[0]  # (N,)
    n = int(np.clip(np.asarray(outputs[3]).reshape(-1)[0], 0, len(scores)))
    w, h = input_size
    xyxy = boxes[:n][:, [1, 0, 3, 2]] * np.array([w, h, w, h], dtype=np.float64)  # (n, 4)
    return Detections(xyxy, scores[:n], np.round(classes[:n]).astype(np.int64))


def suppress_detections(
    det: Detections, score_threshold: float, nms_threshold: float
) -> Detections:
    """Keep confident boxes and apply per-class non-maximum suppression.

    Parameters
    ----------
    det : Detections
        Candidates.
    score_threshold : float
        Minimum confidence.
    nms_threshold : float
        IoU above which the weaker of two same-class boxes is dropped
        (``cv2.dnn.NMSBoxesBatched``).

    Returns
    -------
    Detections
        The kept boxes, strongest first.
    """
    import cv2

    keep = det.scores >= score_threshold
    boxes, scores, labels = det.boxes[keep], det.scores[keep], det.labels[keep]
    if len(scores) == 0:
        return Detections(boxes.reshape(0, 4), scores, labels)
    xywh = np.concatenate([boxes[:, :2], boxes[:, 2:] - boxes[:, :2]], axis=1)  # (B, 4)
    idx = cv2.dnn.NMSBoxesBatched(
        xywh.tolist(), scores.tolist(), labels.astype(int).tolist(), score_threshold, nms_threshold
    )
    idx = np.asarray(idx, dtype=np.int64).reshape(-1)
    idx = idx[np.argsort(-scores[idx], kind="stable")]
    return Detections(boxes[idx], scores[idx], labels[idx])


def tile_windows(
    width: int, height: int, tiles: tuple[int, int], overlap: float
) -> list[tuple[int, int, int, int]]:
    """The whole image, then a grid of overlapping tiles (when ``tiles`` is not ``(1, 1)``).

    Parameters
    ----------
    width, height : int
        Image size in pixels.
    tiles : (int, int)
        ``(columns, rows)``.
    overlap : float
        Fraction of a tile's width (height) shared with its neighbour.

    Returns
    -------
    list of (int, int, int, int)
        Windows ``(x0, y0, x1, y1)`` in pixels (``x1``, ``y1`` exclusive).

    Examples
    --------
    >>> tile_windows(100, 50, (2, 1), 0.2)
    [(0, 0, 100, 50), (0, 0, 56, 50), (44, 0, 100, 50)]
    """
    windows = [(0, 0, width, height)]
    cols, rows = tiles
    if (cols, rows) == (1, 1):
        return windows

    def spans(size: int, n: int) -> list[tuple[int, int]]:
        if n == 1:
            return [(0, size)]
        length = min(size, round(size / (n - (n - 1) * overlap)))  # n tiles, shared overlap
        starts = (round(i * (size - length) / (n - 1)) for i in range(n))
        return [(start, start + length) for start in starts]

    for y0, y1 in spans(height, rows):
        for x0, x1 in spans(width, cols):
            windows.append((x0, y0, x1, y1))
    return windows


def map_shape(image_shape: tuple[int, ...], max_size: int) -> tuple[int, int]:
    """Shape (h, w) of a confidence map whose longer side is at most ``max_size``.

    Parameters
    ----------
    image_shape : tuple
        ``(H, W, ...)`` of the image.
    max_size : int
        Longest map side; images already smaller keep their size.

    Returns
    -------
    (int, int)
        ``(h, w)``.

    Examples
    --------
    >>> map_shape((1080, 1920, 3), 512)
    (288, 512)
    """
    H, W = image_shape[:2]
    s = min(1.0, max_size / max(H, W))
    return max(1, round(H * s)), max(1, round(W * s))


def boxes_to_confidence_maps(
    boxes: np.ndarray,
    scores: np.ndarray,
    channels: np.ndarray,
    num_channels: int,
    shape: tuple[int, int],
) -> np.ndarray:
    """Paint boxes into per-channel confidence maps.

    Every pixel whose centre lies in a box gets the box's score; where boxes of one channel
    overlap, the maximum.

    Parameters
    ----------
    boxes : (B, 4) float ndarray
        ``x0, y0, x1, y1`` in map pixels (pixel ``j`` covers ``[j, j + 1)``).
    scores : (B,) float ndarray
        Box confidences in [0, 1].
    channels : (B,) int ndarray
        Output channel of each box; negative = not painted.
    num_channels : int
        K.
    shape : (int, int)
        Map ``(h, w)``.

    Returns
    -------
    (h, w, K) float32 ndarray
        The maps.

    Examples
    --------
    >>> m = boxes_to_confidence_maps(np.array([[1, 0, 3, 2.0]]), np.array([0.5]),
    ...                              np.array([1]), 2, (3, 4))
    >>> m[..., 1]
    array([[0. , 0.5, 0.5, 0. ],
           [0. , 0.5, 0.5, 0. ],
           [0. , 0. , 0. , 0. ]], dtype=float32)
    """
    boxes = check_array("boxes", boxes, (None, 4), dtype=np.float64)
    scores = check_array("scores", scores, (len(boxes),), dtype=np.float32)
    channels = check_array("channels", channels, (len(boxes),), dtype=np.int64)
    h, w = shape
    maps = np.zeros((h, w, num_channels), dtype=np.float32)
    # Pixel j is inside [x0, x1) when its centre j + 0.5 is.
    lo = np.ceil(boxes[:, :2] - 0.5).astype(np.int64)  # (B, 2)
    hi = np.ceil(boxes[:, 2:] - 0.5).astype(np.int64)  # (B, 2)
    lo = np.clip(lo, 0, [w, h])
    hi = np.clip(hi, 0, [w, h])
    for (x0, y0), (x1, y1), s, c in zip(lo, hi, scores, channels):  # one slice per box
        if c < 0 or c >= num_channels or x1 <= x0 or y1 <= y0:
            continue
        np.maximum(maps[y0:y1, x0:x1, c], s, out=maps[y0:y1, x0:x1, c])
    return np.clip(maps, 0.0, 1.0, out=maps)


def resolve_mapping(
    labels: Sequence[str], class_names: Sequence[str], mapping: Mapping[str, str] | None
) -> np.ndarray:
    """Class index of each model label under ``mapping`` (-1 = unmapped).

    Parameters
    ----------
    labels : sequence of str
        The model's output names.
    class_names : sequence of str
        The label set's classes.
    mapping : mapping of str to str, optional
        Model name -> class name; default: labels that are class names map to themselves.

    Returns
    -------
    (L,) int ndarray
        Channel index per label.

    Raises
    ------
    ValidationError
        If the mapping names an unknown label or class.
    """
    index = {n: i for i, n in enumerate(class_names)}
    if mapping is None:
        mapping = {lab: lab for lab in labels if lab in index}
    label_set = set(labels)
    for src, dst in mapping.items():
        if src not in label_set:
            raise ValidationError(
                f"mapping: {src!r} is not an output of the recogniser; valid names: "
                f"{', '.join(labels)}"
            )
        if dst not in index:
            raise ValidationError(
                f"mapping: {src!r} -> {dst!r}, but {dst!r} is not a class; valid classes: "
                f"{', '.join(class_names)}"
            )
    return np.array(
        [index[mapping[lab]] if lab in mapping else -1 for lab in labels], dtype=np.int64
    )


def _check_image(image: np.ndarray) -> np.ndarray:
    image = check_array("image", image, (None, None, 3), dtype=None)
    if image.dtype != np.uint8:
        raise ValidationError(f"image: expected uint8 RGB, got {image.dtype}")
    return image


def _gather_channels(scores: np.ndarray, channels: np.ndarray, K: int) -> np.ndarray:
    """(h, w, L) model scores -> (h, w, K) class maps, max over labels mapped to one class."""
    out = np.zeros((*scores.shape[:2], K), dtype=np.float32)
    for k in np.unique(channels[channels >= 0]):
        out[..., k] = scores[..., channels == k].max(axis=2)
    return np.clip(out, 0.0, 1.0, out=out)
