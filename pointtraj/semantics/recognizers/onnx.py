"""Recognisers that run a user-supplied ONNX model with onnxruntime (CPU).

``onnx-segmentation`` turns per-pixel logits or probabilities into the (h, w, K) confidence map;
``onnx-detection`` turns boxes into confidence maps (every pixel of a box gets the box's
confidence, the maximum where boxes of a class overlap). Both share configurable
pre-processing: input size, letterbox or stretch resize, RGB or BGR, ``(x * scale - mean) / std``
normalisation and NCHW or NHWC layout. ``onnx-detection`` also runs TensorFlow Lite detectors
(a ``.tflite`` file, with the LiteRT interpreter of the ``ai-edge-litert`` package), such as
SSD models ending in the ``TFLite_Detection_PostProcess`` operator (``format="ssd"``).

The model's own output names (``labels``) are mapped to label-set classes by ``mapping``
(model name -> class name; by default every label that is also a class name maps to itself).
Classes that nothing maps to get zero confidence.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from ...errors import ValidationError, check_array
from .base import ImageContext, Recognizer

__all__ = [
    "OnnxSegmentationRecognizer",
    "OnnxDetectionRecognizer",
    "Preprocessing",
    "Detections",
    "prepare_input",
    "decode_detections",
    "suppress_detections",
    "boxes_to_confidence_maps",
    "map_shape",
    "tile_windows",
]

logger = logging.getLogger(__name__)

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


class _Model:
    """A model runtime on the CPU with its pre-processing settings.

    The base of the onnxruntime and LiteRT wrappers: both validate the same pre-processing
    options into :attr:`pre` and run an image through :func:`prepare_input`. Subclasses load
    the model (:meth:`_load`), settle the input size and layout from it (:meth:`_input_geometry`)
    and run one input tensor (:meth:`_invoke`).

    Attributes
    ----------
    pre : Preprocessing
        The validated recipe.
    dtype : numpy dtype
        Dtype of the model's input tensor.
    output_names : list of str
        The model's outputs, in the order :meth:`run` returns them.
    """

    pre: Preprocessing
    dtype: type | np.dtype
    output_names: list[str]

    def __init__(
        self,
        model: str | os.PathLike,
        *,
        input_size: tuple[int, int] | None,
        resize: str,
        color: str,
        mean: Sequence[float],
        std: Sequence[float],
        scale: float,
        layout: str,
        pad_value: float,
        threads: int,
    ) -> None:
        self._load(model, threads)
        size, layout = self._input_geometry(model, input_size, _choice("layout", layout, _LAYOUT))
        w, h = (int(v) for v in size)
        if w <= 0 or h <= 0:
            raise ValidationError(f"input_size: expected positive (width, height), got {size}")
        self.pre = Preprocessing(
            size=(w, h),
            resize=_choice("resize", resize, _RESIZE),
            color=_choice("color", color, _COLOR),
            mean=tuple(float(v) for v in check_array("mean", mean, (3,))),
            std=tuple(float(v) for v in check_array("std", std, (3,))),
            scale=float(scale),
            layout=layout,
            pad_value=float(pad_value),
        )

    def _load(self, model: str | os.PathLike, threads: int) -> None:
        """Load ``model`` and set :attr:`dtype` and :attr:`output_names`."""
        raise NotImplementedError

    def _input_geometry(
        self, model: str | os.PathLike, input_size: tuple[int, int] | None, layout: str
    ) -> tuple[tuple[int, int], str]:
        """The input (width, height) and layout ("nchw" or "nhwc") from the requested ones
        (``input_size`` None and ``layout`` "auto" ask the model)."""
        raise NotImplementedError

    def _invoke(self, tensor: np.ndarray) -> list[np.ndarray]:
        """The model's outputs for one input tensor."""
        raise NotImplementedError

    def run(self, image: np.ndarray) -> tuple[list[np.ndarray], np.ndarray]:
        """Pre-process and run one image.

        Parameters
        ----------
        image : (H, W, 3) uint8 ndarray
            RGB image.

        Returns
        -------
        outputs : list of ndarray
            The model's outputs, in :attr:`output_names` order.
        transform : (4,) float ndarray
            Image to model-input pixels, see :func:`prepare_input`.
        """
        tensor, transform = prepare_input(image, self.pre, self.dtype)
        return self._invoke(tensor), transform


class _OnnxModel(_Model):
    """An onnxruntime session on the CPU with pre-processing settings."""

    def _load(self, model: str | os.PathLike, threads: int) -> None:
        import onnxruntime as ort

        if not os.path.isfile(model):
            raise ValidationError(f"model: no such ONNX file {os.fspath(model)!r}")
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = threads
        opts.inter_op_num_threads = 1
        opts.log_severity_level = 3
        try:
            self.session = ort.InferenceSession(
                os.fspath(model), sess_options=opts, providers=["CPUExecutionProvider"]
            )
        except Exception as exc:  # onnxruntime raises its own exception types
            raise ValidationError(f"model: cannot load {os.fspath(model)!r}: {exc}") from None
        inp = self.session.get_inputs()[0]
        self.input_name = inp.name
        self.output_names = [o.name for o in self.session.get_outputs()]
        self.dtype = {"tensor(uint8)": np.uint8, "tensor(float16)": np.float16}.get(
            inp.type, np.float32
        )
        self._input_shape = list(inp.shape)

    def _input_geometry(
        self, model: str | os.PathLike, input_size: tuple[int, int] | None, layout: str
    ) -> tuple[tuple[int, int], str]:
        shape = self._input_shape
        if layout == "auto":
            layout = (
                "nhwc"
                if len(shape) == 4 and shape[3] in (1, 3) and shape[1] not in (3,)
                else "nchw"
            )
        if input_size is None:
            hw = shape[2:4] if layout == "nchw" else shape[1:3]
            if len(shape) != 4 or not all(isinstance(d, int) and d > 0 for d in hw):
                raise ValidationError(
                    f"input_size: the model's input {self.input_name!r} has shape {shape}; give "
                    "input_size=(width, height)"
                )
            input_size = (int(hw[1]), int(hw[0]))
        return input_size, layout

    def _invoke(self, tensor: np.ndarray) -> list[np.ndarray]:
        return self.session.run(None, {self.input_name: tensor})


def _litert_interpreter_class(user: str) -> type:
    """The LiteRT ``Interpreter`` class; ``user`` (who needs it) starts the error message.

    Raises
    ------
    ValidationError
        If the ``ai-edge-litert`` package is not installed.
    """
    try:
        from ai_edge_litert.interpreter import Interpreter
    except ImportError:
        raise ValidationError(
            f"{user} needs the LiteRT interpreter: pip install ai-edge-litert "
            "(or pointtraj[models])"
        ) from None
    return Interpreter


class _TfliteModel(_Model):
    """A LiteRT interpreter (TensorFlow Lite model) with pre-processing settings.

    TensorFlow Lite images are NHWC. A ``uint8`` input gets raw pixels (quantised models such
    as the Coral SSD detectors fold the normalisation into the input's quantisation), a
    ``float32`` input gets ``(pixel * scale - mean) / std``.
    """

    def _load(self, model: str | os.PathLike, threads: int) -> None:
        if not os.path.isfile(model):
            raise ValidationError(f"model: no such TFLite file {os.fspath(model)!r}")
        Interpreter = _litert_interpreter_class(f"model: running {os.fspath(model)!r}")
        try:
            self.interpreter = Interpreter(model_path=os.fspath(model), num_threads=threads)
            self.interpreter.allocate_tensors()
        except (ValueError, RuntimeError) as exc:
            raise ValidationError(f"model: cannot load {os.fspath(model)!r}: {exc}") from None
        inp = self.interpreter.get_input_details()[0]
        self.input_index = inp["index"]
        self.outputs = self.interpreter.get_output_details()
        self.output_names = [d["name"] for d in self.outputs]
        shape = [int(v) for v in inp["shape"]]
        if len(shape) != 4 or shape[0] != 1 or shape[3] != 3:
            raise ValidationError(
                f"model: {os.fspath(model)!r} has input shape {shape}; expected [1, h, w, 3]"
            )
        self.dtype = np.dtype(inp["dtype"])
        if self.dtype not in (np.dtype(np.uint8), np.dtype(np.float32)):
            raise ValidationError(
                f"model: {os.fspath(model)!r} has a {self.dtype} input; supported: uint8, float32"
            )
        self._input_shape = shape

    def _input_geometry(
        self, model: str | os.PathLike, input_size: tuple[int, int] | None, layout: str
    ) -> tuple[tuple[int, int], str]:
        if layout == "nchw":
            raise ValidationError("layout: TensorFlow Lite models take NHWC images, not 'nchw'")
        size = (self._input_shape[2], self._input_shape[1])
        if input_size is not None and tuple(int(v) for v in input_size) != size:
            raise ValidationError(
                f"input_size: {os.fspath(model)!r} has a fixed {size[0]}x{size[1]} input, got "
                f"{tuple(input_size)}"
            )
        return size, "nhwc"

    def _invoke(self, tensor: np.ndarray) -> list[np.ndarray]:
        self.interpreter.set_tensor(self.input_index, tensor)
        self.interpreter.invoke()
        return [self.interpreter.get_tensor(d["index"]).copy() for d in self.outputs]


def _check_image(image: np.ndarray) -> np.ndarray:
    image = check_array("image", image, (None, None, 3), dtype=None)
    if image.dtype != np.uint8:
        raise ValidationError(f"image: expected uint8 RGB, got {image.dtype}")
    return image


class OnnxSegmentationRecognizer(Recognizer):
    """Per-pixel class scores from any ONNX segmentation model.

    Parameters
    ----------
    class_names : sequence of str
        The label set's K classes, in channel order.
    model : path-like
        The ONNX file. Its first input is the image; its first output (or ``output``) is
        ``(1, L, h, w)`` (``output_layout="nchw"``) or ``(1, h, w, L)`` scores.
    labels : sequence of str, optional
        Names of the L model channels (default ``"0"``, ``"1"``, ...).
    mapping : mapping of str to str, optional
        Model channel name -> class name (default: channels named like classes).
    activation : {"none", "softmax", "sigmoid"}
        Turns logits into probabilities; ``none`` when the model outputs probabilities.
    input_size : (int, int), optional
        Model input (width, height); default from the model's input shape.
    resize, color, mean, std, scale, layout, pad_value
        Pre-processing, see :class:`Preprocessing` (``layout="auto"`` reads the model).
    output : str, optional
        Name of the output holding the scores.
    output_layout : {"nchw", "nhwc"}
        Layout of that output.
    threads : int
        onnxruntime intra-op threads.
    """

    name = "onnx-segmentation"

    def __init__(
        self,
        class_names: Sequence[str],
        *,
        model: str | os.PathLike,
        labels: Sequence[str] | None = None,
        mapping: Mapping[str, str] | None = None,
        activation: str = "none",
        input_size: tuple[int, int] | None = None,
        resize: str = "stretch",
        color: str = "rgb",
        mean: Sequence[float] = (0.0, 0.0, 0.0),
        std: Sequence[float] = (1.0, 1.0, 1.0),
        scale: float = 1.0 / 255.0,
        layout: str = "auto",
        pad_value: float = 0.0,
        output: str | None = None,
        output_layout: str = "nchw",
        threads: int = 1,
    ) -> None:
        self.class_names = tuple(class_names)
        self.activation = _choice("activation", activation, _ACTIVATION)
        self.output_layout = _choice("output_layout", output_layout, ("nchw", "nhwc"))
        self.net = _OnnxModel(
            model,
            input_size=input_size,
            resize=resize,
            color=color,
            mean=mean,
            std=std,
            scale=scale,
            layout=layout,
            pad_value=pad_value,
            threads=threads,
        )
        if output is not None and output not in self.net.output_names:
            raise ValidationError(
                f"output: the model has no output {output!r}; valid: {', '.join(self.net.output_names)}"
            )
        self.output_index = 0 if output is None else self.net.output_names.index(output)
        self.labels = tuple(labels) if labels is not None else None
        self._mapping = mapping
        self._channels = (
            resolve_mapping(self.labels, self.class_names, mapping) if self.labels else None
        )

    def recognize(self, image: np.ndarray, context: ImageContext | None = None) -> np.ndarray:
        """Per-pixel class confidences, see :meth:`Recognizer.recognize`.

        The map has the model's output resolution restricted to the image area (letterbox
        padding removed), shrunk to the image size if larger.
        """
        import cv2

        image = _check_image(image)
        outputs, (sx, sy, px, py) = self.net.run(image)
        scores = np.asarray(outputs[self.output_index], dtype=np.float32)
        if scores.ndim != 4 or scores.shape[0] != 1:
            raise ValidationError(
                f"segmentation output: expected (1, L, h, w) or (1, h, w, L), got {scores.shape}"
            )
        scores = scores[0] if self.output_layout == "nhwc" else scores[0].transpose(1, 2, 0)
        if self._channels is None:
            self.labels = tuple(str(i) for i in range(scores.shape[2]))
            self._channels = resolve_mapping(self.labels, self.class_names, self._mapping)
        if scores.shape[2] != len(self._channels):
            raise ValidationError(
                f"segmentation output has {scores.shape[2]} channels, but {len(self._channels)} "
                "labels were given"
            )
        if self.activation == "softmax":
            e = np.exp(scores - scores.max(axis=2, keepdims=True))
            scores = e / e.sum(axis=2, keepdims=True)
        elif self.activation == "sigmoid":
            scores = 1.0 / (1.0 + np.exp(-scores))
        # Crop the part of the output that covers the image (removes letterbox padding).
        H, W = image.shape[:2]
        oh, ow = scores.shape[:2]
        iw, ih = self.net.pre.size
        fx, fy = ow / iw, oh / ih
        x0, y0 = round(px * fx), round(py * fy)
        x1, y1 = round((px + W * sx) * fx), round((py + H * sy) * fy)
        scores = scores[y0:y1, x0:x1]
        if scores.shape[0] > H or scores.shape[1] > W:
            scores = cv2.resize(scores, (W, H), interpolation=cv2.INTER_AREA)
            scores = scores.reshape(H, W, -1)
        return _gather_channels(scores, self._channels, len(self.class_names))


def _gather_channels(scores: np.ndarray, channels: np.ndarray, K: int) -> np.ndarray:
    """(h, w, L) model scores -> (h, w, K) class maps, max over labels mapped to one class."""
    out = np.zeros((*scores.shape[:2], K), dtype=np.float32)
    for k in np.unique(channels[channels >= 0]):
        out[..., k] = scores[..., channels == k].max(axis=2)
    return np.clip(out, 0.0, 1.0, out=out)


class OnnxDetectionRecognizer(Recognizer):
    """Box confidence maps from any ONNX (or TensorFlow Lite) object detector.

    Parameters
    ----------
    class_names : sequence of str
        The label set's K classes, in channel order.
    model : path-like
        The ONNX file, or a ``.tflite`` file (run with LiteRT; NHWC input of fixed size);
        outputs in one of the layouts of :func:`decode_detections`.
    labels : sequence of str, optional
        Names of the model's classes (default ``"0"``, ``"1"``, ...).
    label_ids : sequence of int, optional
        The model's class index of each ``labels`` entry, for models whose class indices are
        not ``0 .. L-1`` (e.g. the 90 sparse COCO ids); boxes of other indices are dropped.
        Default: entry ``i`` is class ``i``.
    mapping : mapping of str to str, optional
        Model class name -> class name (default: model classes named like classes).
    format : {"auto", "yolov8", "yolov5", "boxes_scores_labels", "ssd"}
        Output layout, see :func:`decode_detections`.
    box_format : {"xyxy", "xywh"}
        Box encoding of the ``boxes_scores_labels`` format.
    normalized_boxes : bool
        ``boxes_scores_labels`` boxes are in [0, 1] of the input size.
    score_threshold : float
        Minimum box confidence.
    nms_threshold : float
        IoU threshold of the per-class non-maximum suppression.
    map_size : int
        Longest side of the output map (images smaller than this keep their size).
    tiles : (int, int)
        ``(columns, rows)``: besides the whole image, also run the detector on this grid of
        overlapping tiles and merge all boxes with NMS, so that objects too small at the
        model's input size are found (cost: ``columns x rows + 1`` runs). ``(1, 1)`` (default)
        runs on the whole image only.
    tile_overlap : float
        Fraction of a tile's width (height) shared with its neighbour, in [0, 1).
    input_size, resize, color, mean, std, scale, layout, pad_value, threads
        Pre-processing and runtime threads (onnxruntime or LiteRT), as in
        :class:`OnnxSegmentationRecognizer` (defaults suit YOLO models: letterbox, RGB,
        [0, 1]).
    """

    name = "onnx-detection"

    def __init__(
        self,
        class_names: Sequence[str],
        *,
        model: str | os.PathLike,
        labels: Sequence[str] | None = None,
        label_ids: Sequence[int] | None = None,
        mapping: Mapping[str, str] | None = None,
        format: str = "auto",
        box_format: str = "xyxy",
        normalized_boxes: bool = False,
        score_threshold: float = 0.25,
        nms_threshold: float = 0.45,
        map_size: int = 512,
        tiles: tuple[int, int] = (1, 1),
        tile_overlap: float = 0.25,
        input_size: tuple[int, int] | None = None,
        resize: str = "letterbox",
        color: str = "rgb",
        mean: Sequence[float] = (0.0, 0.0, 0.0),
        std: Sequence[float] = (1.0, 1.0, 1.0),
        scale: float = 1.0 / 255.0,
        layout: str = "auto",
        pad_value: float = 114.0,
        threads: int = 1,
    ) -> None:
        self.class_names = tuple(class_names)
        self.format = _choice("format", format, _DET_FORMAT)
        self.box_format = _choice("box_format", box_format, ("xyxy", "xywh"))
        self.normalized_boxes = bool(normalized_boxes)
        if not 0.0 <= score_threshold <= 1.0 or not 0.0 <= nms_threshold <= 1.0:
            raise ValidationError(
                f"score_threshold and nms_threshold must be in [0, 1], got {score_threshold} "
                f"and {nms_threshold}"
            )
        if map_size < 1:
            raise ValidationError(f"map_size: expected a positive integer, got {map_size}")
        self.score_threshold = float(score_threshold)
        self.nms_threshold = float(nms_threshold)
        self.map_size = int(map_size)
        cols, rows = (int(v) for v in tiles)
        if cols < 1 or rows < 1:
            raise ValidationError(f"tiles: expected (columns, rows) >= 1, got {tuple(tiles)}")
        if not 0.0 <= tile_overlap < 1.0:
            raise ValidationError(f"tile_overlap: expected a value in [0, 1), got {tile_overlap}")
        self.tiles = (cols, rows)
        self.tile_overlap = float(tile_overlap)
        runtime = _TfliteModel if os.fspath(model).lower().endswith(".tflite") else _OnnxModel
        self.net = runtime(
            model,
            input_size=input_size,
            resize=resize,
            color=color,
            mean=mean,
            std=std,
            scale=scale,
            layout=layout,
            pad_value=pad_value,
            threads=threads,
        )
        self.labels = tuple(labels) if labels is not None else None
        self._label_index: dict[int, int] | None = None
        if label_ids is not None:
            if self.labels is None:
                raise ValidationError("label_ids: needs 'labels' (one id per label)")
            ids = [int(i) for i in label_ids]
            if len(ids) != len(self.labels) or len(set(ids)) != len(ids) or min(ids) < 0:
                raise ValidationError(
                    f"label_ids: expected {len(self.labels)} distinct non-negative integers "
                    f"(one per label), got {len(ids)}"
                )
            self._label_index = {model_id: i for i, model_id in enumerate(ids)}
        self._mapping = mapping
        self._numeric_keys: list[str] = []
        if self.labels is not None:
            resolve_mapping(self.labels, self.class_names, mapping)  # fail early
        elif mapping is not None:
            bad = [k for k in mapping if not k.isdigit()]
            if bad:
                raise ValidationError(
                    f"mapping: {bad[0]!r} is not a model class; without 'labels' the model's "
                    "classes are named by index ('0', '1', ...)"
                )
            self._numeric_keys = list(mapping)

    def detect(self, image: np.ndarray) -> Detections:
        """Boxes in one image after thresholding and NMS.

        Parameters
        ----------
        image : (H, W, 3) uint8 ndarray
            RGB image.

        Returns
        -------
        Detections
            Boxes in image pixels, strongest first; ``labels`` index :attr:`labels` (the model's
            class indices translated through ``label_ids`` when given).
        """
        image = _check_image(image)
        H, W = image.shape[:2]
        parts = [
            self._detect_window(image, x0, y0, x1, y1)
            for x0, y0, x1, y1 in tile_windows(W, H, self.tiles, self.tile_overlap)
        ]
        det = Detections(
            np.concatenate([d.boxes for d in parts]),
            np.concatenate([d.scores for d in parts]),
            np.concatenate([d.labels for d in parts]),
        )
        det = suppress_detections(det, self.score_threshold, self.nms_threshold)
        if self._label_index is not None:
            index = self._label_index
            labels = np.array([index.get(int(i), -1) for i in det.labels], dtype=np.int64)
            known = labels >= 0
            det = Detections(det.boxes[known], det.scores[known], labels[known])
        boxes = np.clip(det.boxes, 0.0, [W, H, W, H])
        return Detections(boxes, det.scores, det.labels)

    def _detect_window(self, image: np.ndarray, x0: int, y0: int, x1: int, y1: int) -> Detections:
        """Confident boxes (model class indices) of one image window, in image pixels."""
        outputs, (sx, sy, px, py) = self.net.run(image[y0:y1, x0:x1])
        det = decode_detections(
            outputs,
            self.net.output_names,
            num_labels=len(self.labels) if self.labels and self._label_index is None else None,
            fmt=self.format,
            box_format=self.box_format,
            normalized=self.normalized_boxes,
            input_size=self.net.pre.size,
        )
        keep = det.scores >= self.score_threshold
        boxes = (det.boxes[keep] - [px, py, px, py]) / [sx, sy, sx, sy] + [x0, y0, x0, y0]
        return Detections(boxes.reshape(-1, 4), det.scores[keep], det.labels[keep].astype(np.int64))

    def recognize(self, image: np.ndarray, context: ImageContext | None = None) -> np.ndarray:
        """Box confidence maps, see :meth:`Recognizer.recognize` and ``map_size``."""
        det = self.detect(image)
        names = self.labels
        if names is None:  # unnamed model classes are "0", "1", ...
            n = max(
                [int(det.labels.max()) + 1 if len(det) else 0]
                + [int(k) + 1 for k in self._numeric_keys]
            )
            names = tuple(str(i) for i in range(n))
        channels = resolve_mapping(names, self.class_names, self._mapping)
        labels = det.labels.astype(np.int64)
        box_channels = np.full(len(labels), -1, dtype=np.int64)
        valid = (labels >= 0) & (labels < len(channels))
        box_channels[valid] = channels[labels[valid]]
        H, W = image.shape[:2]
        h, w = map_shape(image.shape, self.map_size)
        boxes = det.boxes * [w / W, h / H, w / W, h / H]
        return boxes_to_confidence_maps(
            boxes, det.scores, box_channels, len(self.class_names), (h, w)
        )
