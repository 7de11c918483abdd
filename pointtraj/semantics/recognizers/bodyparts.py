"""Left/right body-part confidence maps from MediaPipe Pose (BlazePose GHUM, full model).

Pipeline for one image:

1. ``pose_detection.tflite`` (224x224, letterboxed, SSD with 2254 anchors) finds people; each
   detection's keypoints 0 (mid-hip) and 1 (full-body scale point) give a rotated square region
   of interest of side ``2.5 |k1 - k0|``, upright along ``k0 -> k1`` (MediaPipe's recipe). When
   nothing is detected the whole image is tried.
2. ``pose_landmark_full.tflite`` runs on the 256x256 crop of that region: 33 landmarks with
   visibility, a person-presence score and a person mask. With ``refine`` the region is
   recomputed from the model's own alignment landmarks (33, 34) and the model runs again.
3. Each body part is a skeleton element in the image: a bone segment (upper arm = shoulder to
   elbow, forearm = elbow to wrist, thigh = hip to knee, shin = knee to ankle) or a polygon
   (hand = wrist, pinky, index, thumb; foot = ankle, heel, foot index; head = face points;
   torso = shoulders and hips). Its confidence at a pixel is

   ``mask * visibility_part * exp(-((d_part - d_min) / (softness * L))**2)
   * exp(-(d_min / (reach * L))**2 / 2)``

   with ``d_part`` the distance to the part's skeleton element, ``d_min`` the distance to the
   nearest one, ``L`` the torso length (mid-shoulder to mid-hip) and ``visibility_part`` the
   mean landmark visibility. The nearest part thus gets the mask's confidence, the others fall
   off softly. Several people combine by maximum.
4. Every detected person is kept by default (``max_people = None``); :meth:`recognize_people`
   also gives a person-id map (the person whose mask is strongest, where it exceeds 0.5) for
   the labelling stage's instances.

"Left" is the person's own left, as in MediaPipe's landmark names. The model files come from
the ``mediapipe==0.10.21`` wheel on PyPI (Apache-2.0): ``pointtraj models fetch body-parts``.
They run with the LiteRT interpreter (package ``ai-edge-litert``): OpenCV 5.0's TFLite importer
cannot import the detector (no DENSIFY operator) and exposes only one output of the landmark
model.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from ...errors import ValidationError
from .base import ImageContext, Recognizer
from .processing import (
    Preprocessing,
    _check_image,
    _gather_channels,
    map_shape,
    prepare_input,
    resolve_mapping,
)
from .runtime import _litert_interpreter_class

__all__ = ["BodyPartRecognizer", "PersonPose", "BODY_PARTS", "LANDMARK_NAMES"]

logger = logging.getLogger(__name__)

#: The 33 MediaPipe Pose landmarks; "left" is the person's left.
LANDMARK_NAMES: tuple[str, ...] = (
    "nose",
    "left_eye_inner",
    "left_eye",
    "left_eye_outer",
    "right_eye_inner",
    "right_eye",
    "right_eye_outer",
    "left_ear",
    "right_ear",
    "mouth_left",
    "mouth_right",
    "left_shoulder",
    "right_shoulder",
    "left_elbow",
    "right_elbow",
    "left_wrist",
    "right_wrist",
    "left_pinky",
    "right_pinky",
    "left_index",
    "right_index",
    "left_thumb",
    "right_thumb",
    "left_hip",
    "right_hip",
    "left_knee",
    "right_knee",
    "left_ankle",
    "right_ankle",
    "left_heel",
    "right_heel",
    "left_foot_index",
    "right_foot_index",
)

#: Body part -> landmark indices of its skeleton element (2 = segment, more = convex polygon).
BODY_PARTS: dict[str, tuple[int, ...]] = {
    "head": tuple(range(11)),
    "torso": (11, 12, 24, 23),
    "left_upper_arm": (11, 13),
    "right_upper_arm": (12, 14),
    "left_forearm": (13, 15),
    "right_forearm": (14, 16),
    "left_hand": (15, 17, 19, 21),
    "right_hand": (16, 18, 20, 22),
    "left_thigh": (23, 25),
    "right_thigh": (24, 26),
    "left_shin": (25, 27),
    "right_shin": (26, 28),
    "left_foot": (27, 29, 31),
    "right_foot": (28, 30, 32),
}

_DET_SIZE = 224
_LMK_SIZE = 256


def _sigmoid(x: np.ndarray) -> np.ndarray:
    return 1.0 / (1.0 + np.exp(-np.clip(np.asarray(x, dtype=np.float64), -60.0, 60.0)))


def _pose_anchors() -> np.ndarray:
    """(2254, 2) anchor centres of the pose detector, in [0, 1] (MediaPipe SSD anchors)."""
    centres = []
    # strides 8, 16, 32 with 2, 2 and 6 anchors of fixed size per cell (5 layers, 3 merged).
    for stride, per_cell in ((8, 2), (16, 2), (32, 6)):
        n = int(np.ceil(_DET_SIZE / stride))
        ys, xs = np.meshgrid((np.arange(n) + 0.5) / n, (np.arange(n) + 0.5) / n, indexing="ij")
        cells = np.stack([xs.ravel(), ys.ravel()], axis=1)  # (n*n, 2)
        centres.append(np.repeat(cells, per_cell, axis=0))
    return np.concatenate(centres, axis=0)


@dataclass(frozen=True)
class PersonPose:
    """One person's landmarks and mask.

    Attributes
    ----------
    landmarks : (33, 2) float ndarray
        Landmark pixels in the image.
    visibility : (33,) float ndarray
        Landmark visibility in [0, 1].
    score : float
        Person-presence score of the landmark model.
    roi : (3, 2) float ndarray
        Region of interest: centre, up unit vector (hip to head), (side, 0), image pixels.
    crop_to_image : (2, 3) float ndarray
        Affine map from 256x256 crop pixels to image pixels.
    mask : (256, 256) float32 ndarray
        Person probability in the crop.
    """

    landmarks: np.ndarray
    visibility: np.ndarray
    score: float
    roi: np.ndarray
    crop_to_image: np.ndarray
    mask: np.ndarray


def _roi_affine(centre: np.ndarray, up: np.ndarray, side: float, n: int) -> np.ndarray:
    """(2, 3) affine from n x n crop pixels to image pixels for a rotated square ROI."""
    right = np.array([-up[1], up[0]])
    off = centre + side * (0.5 / n - 0.5) * (right - up)
    return np.stack([side / n * right, -side / n * up, off], axis=1)  # (2, 3)


def _roi_from_points(p0: np.ndarray, p1: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """MediaPipe's ROI from the hip centre and the scale point: centre, up vector, side."""
    v = p1 - p0
    length = float(np.hypot(*v))
    up = v / length if length > 0 else np.array([0.0, -1.0])
    return p0, up, 2.0 * length * 1.25


class BodyPartRecognizer(Recognizer):
    """Body-part confidence maps from MediaPipe Pose, run with LiteRT.

    Parameters
    ----------
    class_names : sequence of str
        The label set's K classes, in channel order.
    mapping : mapping of str to str, optional
        Body-part name (a key of :data:`BODY_PARTS`, or ``"person"`` for the whole mask) ->
        class name. Default: parts named like classes map to themselves.
    model_dir : path-like, optional
        Folder with ``pose_detection.tflite`` and ``pose_landmark_full.tflite``; default the
        ``body-parts`` entry of the model cache (:mod:`pointtraj.models`).
    fetch : bool
        Fetch the model files with pip when they are not cached (logged), instead of raising.
    max_people : int or None
        Most people per image (the strongest detections); None (default) keeps every person
        detected.
    detection_threshold : float
        Minimum pose-detector score.
    presence_threshold : float
        Minimum person-presence score of the landmark model.
    refine : bool
        Run the landmark model a second time on the region its own landmarks give.
    softness : float
        Width of the soft assignment between neighbouring parts, in torso lengths.
    reach : float
        Falloff of confidence away from every skeleton element, in torso lengths.
    map_size : int
        Longest side of the output map.
    threads : int
        LiteRT threads.
    """

    name = "body-parts"

    def __init__(
        self,
        class_names: Sequence[str],
        *,
        mapping: Mapping[str, str] | None = None,
        model_dir: str | None = None,
        fetch: bool = False,
        max_people: int | None = None,
        detection_threshold: float = 0.5,
        presence_threshold: float = 0.5,
        refine: bool = True,
        softness: float = 0.06,
        reach: float = 0.4,
        map_size: int = 512,
        threads: int = 1,
    ) -> None:
        from pathlib import Path

        from ...models import locate_model

        self.class_names = tuple(class_names)
        self.outputs = (*BODY_PARTS, "person")
        self.channels = resolve_mapping(self.outputs, self.class_names, mapping)
        for opt, value in (("softness", softness), ("reach", reach)):
            if not value > 0:
                raise ValidationError(f"{opt}: expected a positive number, got {value}")
        if (max_people is not None and max_people < 1) or map_size < 1:
            raise ValidationError(
                f"max_people and map_size must be positive, got {max_people} and {map_size}"
            )
        self.max_people = None if max_people is None else int(max_people)
        self.detection_threshold = float(detection_threshold)
        self.presence_threshold = float(presence_threshold)
        self.refine = bool(refine)
        self.softness = float(softness)
        self.reach = float(reach)
        self.map_size = int(map_size)
        if model_dir is None:
            files = locate_model("body-parts", fetch=fetch)
        else:
            files = {
                n: Path(model_dir) / n
                for n in ("pose_detection.tflite", "pose_landmark_full.tflite")
            }
            for path in files.values():
                if not path.is_file():
                    raise ValidationError(f"model_dir: {path} does not exist")
        self._detector = _interpreter(files["pose_detection.tflite"], threads)
        self._landmarker = _interpreter(files["pose_landmark_full.tflite"], threads)
        self._anchors = _pose_anchors()
        out = {d["name"]: d for d in self._landmarker.get_output_details()}
        # Outputs of the full landmark model, found by shape.
        self._lmk_out = {
            "landmarks": next(d["index"] for d in out.values() if tuple(d["shape"]) == (1, 195)),
            "flag": next(d["index"] for d in out.values() if tuple(d["shape"]) == (1, 1)),
            "mask": next(d["index"] for d in out.values() if tuple(d["shape"]) == (1, 256, 256, 1)),
        }
        det_out = self._detector.get_output_details()
        self._det_boxes = next(d["index"] for d in det_out if d["shape"][-1] == 12)
        self._det_scores = next(d["index"] for d in det_out if d["shape"][-1] == 1)

    # -- model stages ---------------------------------------------------------------------------

    def detect_people(self, image: np.ndarray) -> np.ndarray:
        """Pose-detector keypoints 0 and 1 of each person, strongest first.

        Parameters
        ----------
        image : (H, W, 3) uint8 ndarray
            RGB image.

        Returns
        -------
        (P, 5) float ndarray
            ``x0, y0, x1, y1, score``: mid-hip and scale point in image pixels, and the score.
        """
        import cv2

        image = _check_image(image)
        pre = Preprocessing(
            size=(_DET_SIZE, _DET_SIZE),
            resize="letterbox",
            mean=(1.0, 1.0, 1.0),
            scale=1.0 / 127.5,
            layout="nhwc",
            pad_value=127.5,
        )
        tensor, (sx, sy, px, py) = prepare_input(image, pre)
        det = self._detector
        det.set_tensor(det.get_input_details()[0]["index"], tensor)
        det.invoke()
        raw = det.get_tensor(self._det_boxes)[0].astype(np.float64)  # (2254, 12)
        scores = _sigmoid(det.get_tensor(self._det_scores)[0, :, 0].astype(np.float64))
        keep = np.flatnonzero(scores >= self.detection_threshold)
        if len(keep) == 0:
            return np.zeros((0, 5))
        anchors = self._anchors[keep]  # (B, 2)
        raw = raw[keep] / _DET_SIZE
        centre = raw[:, 0:2] + anchors
        size = raw[:, 2:4]
        kp = raw[:, 4:8].reshape(-1, 2, 2) + anchors[:, None, :]  # (B, 2, 2)
        boxes = np.concatenate([centre - size / 2, size], axis=1) * _DET_SIZE  # (B, 4) xywh
        idx = cv2.dnn.NMSBoxes(boxes.tolist(), scores[keep].tolist(), self.detection_threshold, 0.3)
        idx = np.asarray(idx, dtype=np.int64).reshape(-1)[: self.max_people]
        kp_img = (kp[idx] * _DET_SIZE - [px, py]) / [sx, sy]  # (P, 2, 2) image pixels
        return np.concatenate([kp_img.reshape(-1, 4), scores[keep][idx, None]], axis=1)

    def _landmarks(
        self, image: np.ndarray, centre: np.ndarray, up: np.ndarray, side: float
    ) -> PersonPose:
        import cv2

        A = _roi_affine(centre, up, side, _LMK_SIZE)
        crop = cv2.warpAffine(
            image,
            A,
            (_LMK_SIZE, _LMK_SIZE),
            flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
            borderMode=cv2.BORDER_CONSTANT,
        )
        lm = self._landmarker
        lm.set_tensor(
            lm.get_input_details()[0]["index"], (crop[None] / np.float32(255.0)).astype(np.float32)
        )
        lm.invoke()
        raw = lm.get_tensor(self._lmk_out["landmarks"])[0].reshape(39, 5).astype(np.float64)
        flag = float(lm.get_tensor(self._lmk_out["flag"])[0, 0])
        mask = _sigmoid(lm.get_tensor(self._lmk_out["mask"])[0, :, :, 0]).astype(np.float32)
        # Landmark (x, y) in [0, 256] -> image: centre + side * ((x/n - 0.5) right - (y/n - 0.5) up).
        right = np.array([-up[1], up[0]])
        rel = raw[:, :2] / _LMK_SIZE - 0.5  # (39, 2)
        pts = centre + side * (rel[:, :1] * right - rel[:, 1:2] * up)  # (39, 2)
        return PersonPose(
            landmarks=pts,
            visibility=_sigmoid(raw[:, 3]),
            score=flag,
            roi=np.array([centre, up, [side, 0.0]]),
            crop_to_image=A,
            mask=mask,
        )

    def estimate_poses(self, image: np.ndarray) -> list[PersonPose]:
        """Landmarks and masks of the people in an image.

        Parameters
        ----------
        image : (H, W, 3) uint8 ndarray
            RGB image.

        Returns
        -------
        list of PersonPose
            One per person whose presence score passes ``presence_threshold`` (``landmarks``
            has the 33 body landmarks only).
        """
        image = _check_image(image)
        H, W = image.shape[:2]
        people = self.detect_people(image)
        rois = [_roi_from_points(p[0:2], p[2:4]) for p in people]
        if not rois:
            logger.debug("pose detector found nobody: trying the whole image")
            rois = [(np.array([W / 2, H / 2]), np.array([0.0, -1.0]), float(max(W, H)))]
        poses = []
        for centre, up, side in rois:
            pose = self._landmarks(image, centre, up, side)
            if self.refine and pose.score >= self.presence_threshold:
                pose = self._landmarks(
                    image, *_roi_from_points(pose.landmarks[33], pose.landmarks[34])
                )
            if pose.score >= self.presence_threshold:
                poses.append(
                    PersonPose(
                        pose.landmarks[:33],
                        pose.visibility[:33],
                        pose.score,
                        pose.roi,
                        pose.crop_to_image,
                        pose.mask,
                    )
                )
        return poses

    # -- part maps --------------------------------------------------------------------------------

    def part_maps(self, pose: PersonPose, image_shape: tuple[int, ...]) -> np.ndarray:
        """Confidence maps of the body parts of one person.

        Parameters
        ----------
        pose : PersonPose
            The person.
        image_shape : tuple
            ``(H, W, ...)`` of the image.

        Returns
        -------
        (h, w, 15) float32 ndarray
            The 14 parts of :data:`BODY_PARTS` then the person mask, at :func:`map_shape`.
        """
        import cv2

        H, W = image_shape[:2]
        h, w = map_shape(image_shape, self.map_size)
        fx, fy = w / W, h / H
        # map pixel -> image pixel -> crop pixel, for warping the mask.
        B = np.array([[1 / fx, 0.0, 0.5 / fx - 0.5], [0.0, 1 / fy, 0.5 / fy - 0.5], [0, 0, 1]])
        A = np.vstack([pose.crop_to_image, [0, 0, 1]])
        M = (np.linalg.inv(A) @ B)[:2]
        mask = cv2.warpAffine(
            pose.mask, M, (w, h), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderValue=0.0
        )
        pts = (pose.landmarks + 0.5) * [fx, fy] - 0.5  # (33, 2) map pixels
        pts = np.clip(pts, -4 * max(h, w), 4 * max(h, w))
        torso = np.linalg.norm((pts[11] + pts[12]) / 2 - (pts[23] + pts[24]) / 2)
        torso = max(float(torso), 2.0)
        out = np.zeros((h, w, len(BODY_PARTS) + 1), dtype=np.float32)
        out[..., -1] = mask
        # Work inside the box holding the mask and the in-map landmarks (parts are 0 elsewhere).
        ys, xs = np.nonzero(mask > 1e-3)
        if len(ys) == 0:
            return out
        inside = pts[(pts[:, 0] >= 0) & (pts[:, 0] < w) & (pts[:, 1] >= 0) & (pts[:, 1] < h)]
        x0 = int(min(xs.min(), *np.floor(inside[:, 0]))) if len(inside) else int(xs.min())
        y0 = int(min(ys.min(), *np.floor(inside[:, 1]))) if len(inside) else int(ys.min())
        x1 = int(max(xs.max(), *np.ceil(inside[:, 0]))) + 1 if len(inside) else int(xs.max()) + 1
        y1 = int(max(ys.max(), *np.ceil(inside[:, 1]))) + 1 if len(inside) else int(ys.max()) + 1
        x1, y1 = min(x1, w), min(y1, h)
        rh, rw = y1 - y0, x1 - x0
        local = pts - [x0, y0]  # (33, 2) region pixels
        dist = np.empty((len(BODY_PARTS), rh, rw), dtype=np.float32)
        vis = np.empty(len(BODY_PARTS), dtype=np.float32)
        shift = 4  # sub-pixel drawing precision (bits)
        for i, idx in enumerate(BODY_PARTS.values()):
            canvas = np.full((rh, rw), 255, dtype=np.uint8)
            p = np.round(local[list(idx)] * (1 << shift)).astype(np.int32)
            if len(idx) == 2:
                cv2.line(canvas, tuple(p[0]), tuple(p[1]), 0, 1, cv2.LINE_8, shift)
            else:
                hull = cv2.convexHull(p)
                cv2.fillConvexPoly(canvas, hull, 0, cv2.LINE_8, shift)
                cv2.polylines(canvas, [hull], True, 0, 1, cv2.LINE_8, shift)
            dist[i] = cv2.distanceTransform(canvas, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
            vis[i] = pose.visibility[list(idx)].mean()
        d_min = dist.min(axis=0)  # (rh, rw)
        near = np.exp(-(((dist - d_min) / (self.softness * torso)) ** 2))  # (14, rh, rw)
        falloff = np.exp(-0.5 * (d_min / (self.reach * torso)) ** 2) * mask[y0:y1, x0:x1]
        parts = near * vis[:, None, None] * falloff  # (14, rh, rw)
        out[y0:y1, x0:x1, :-1] = parts.transpose(1, 2, 0)
        return out

    def recognize(self, image: np.ndarray, context: ImageContext | None = None) -> np.ndarray:
        """Body-part confidences, see :meth:`Recognizer.recognize` and ``map_size``."""
        return self.recognize_people(image, context)[0]

    def recognize_people(
        self, image: np.ndarray, context: ImageContext | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Body-part confidences and the person-id map, from one pose estimate.

        Returns
        -------
        L2D : (h, w, K) float32 ndarray
            As :meth:`recognize`.
        people : (h, w) int16 ndarray
            Index of the person (in :meth:`estimate_poses` order) whose mask is strongest at
            each cell, where it exceeds 0.5; -1 elsewhere.
        """
        image = _check_image(image)
        h, w = map_shape(image.shape, self.map_size)
        maps = np.zeros((h, w, len(self.outputs)), dtype=np.float32)
        best = np.full((h, w), 0.5, dtype=np.float32)
        people = np.full((h, w), -1, dtype=np.int16)
        for i, pose in enumerate(self.estimate_poses(image)):
            person = self.part_maps(pose, image.shape)
            np.maximum(maps, person, out=maps)
            stronger = person[..., -1] > best  # (h, w)
            people[stronger] = i
            best[stronger] = person[..., -1][stronger]
        return _gather_channels(maps, self.channels, len(self.class_names)), people


def _interpreter(path: object, threads: int):  # -> ai_edge_litert Interpreter
    """A LiteRT interpreter with allocated tensors."""
    Interpreter = _litert_interpreter_class("the body-parts recogniser")
    interp = Interpreter(model_path=str(path), num_threads=threads)
    interp.allocate_tensors()
    return interp
