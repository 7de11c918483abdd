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

The shared pre- and post-processing is in :mod:`.processing`, the model runtimes in
:mod:`.runtime`.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Mapping, Sequence

import numpy as np

from ...errors import ValidationError
from .base import ImageContext, Recognizer
from .processing import (
    _ACTIVATION,
    _DET_FORMAT,
    Detections,
    Preprocessing,
    _check_image,
    _choice,
    _gather_channels,
    boxes_to_confidence_maps,
    decode_detections,
    map_shape,
    prepare_input,
    resolve_mapping,
    suppress_detections,
    tile_windows,
)
from .runtime import _OnnxModel, _TfliteModel

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
