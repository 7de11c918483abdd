"""A simulated recogniser for synthetic captures: ground-truth label maps plus realistic noise.

It reads the ground-truth label map of an image
(:func:`pointtraj.synth.groundtruth.load_label_map`, (H, W) int16, -1 = background) and turns it
into confidences L2D (h, w, K) that fail the way real recognisers do. The noise model, with the
parameters of :class:`SimulatedNoise`:

1. **Per-view confusions** (decided once per camera and block of ``hold_frames`` frames, so
   they persist as a real recogniser's errors do while the pose changes little):

   - with probability ``p_flip`` the whole view is left/right mirrored (every ``left_*`` class is
     reported as its ``right_*`` twin and vice versa, as pose estimators do on back views);
   - per body part, with probability ``p_swap`` the part is reported as its left/right twin;
   - otherwise, per body part, with probability ``p_neighbour`` it is reported as a neighbouring
     part of the same side (upper arm <-> forearm <-> hand, thigh <-> shin <-> foot, torso <->
     upper arm / thigh / head);
   - per class, with probability ``p_miss`` the class is missed: its channel is zero in the view;
   - per class, the peak confidence is drawn uniformly from ``[peak_min, peak_max]``.

2. **Coarse, blurred output**: the (relabelled) one-hot map is area-averaged to
   ``ceil(H / downsample) x ceil(W / downsample)`` cells, then blurred by a Gaussian of
   ``blur_sigma`` cells, then scaled by the peak confidence.

3. **Objects as boxes** (classes of kind ``"object"``, e.g. ball): each connected blob of the
   class in the coarse map becomes its bounding box, its size and position jittered by
   ``box_jitter`` (relative standard deviation); every cell in the box gets the detection's
   confidence (uniform in ``[peak_min, peak_max]``), as a YOLO-style detector's box does, so the
   box also covers whatever lies around or in front of the object.

4. **False positives**: a Poisson(``fp_rate``) number of boxes per image, of a random class, at
   a random place, with sides of ``fp_size`` (fractions of the shorter image side) and
   confidence uniform in ``fp_conf``.

5. **Low overall noise**: ``|N(0, noise_std)|`` is added to every cell and class; the result is
   clipped to [0, 1].

Every draw comes from ``numpy.random.default_rng`` seeded by (``seed``, camera name, frame) (and
the frame block for the confusions), so the output is deterministic. The presets
(:data:`NOISE_PRESETS`):

============ ====== ====== ====== ====== ====== ======= ========= ==== =========
preset       p_flip p_swap p_nbr  p_miss fp_rate noise  peak      blur hold
============ ====== ====== ====== ====== ====== ======= ========= ==== =========
``none``     0      0      0      0      0      0       1 - 1     0    15
``low``      0.02   0.03   0.05   0.03   0.2    0.02    0.8 - 1   1.0  15
``default``  0.05   0.08   0.12   0.08   0.5    0.05    0.6 - 1   1.0  15
``high``     0.10   0.15   0.25   0.15   1.5    0.08    0.5 - 1   1.5  15
============ ====== ====== ====== ====== ====== ======= ========= ==== =========

All presets downsample by 8, jitter boxes by 0.1 and draw false-positive boxes with sides of
0.05 - 0.2 of the shorter image side and confidence 0.3 - 0.8.

This is the regime where view pooling matters: an error in one view (a swapped or confused part,
a box that covers the hand dribbling the ball, a false-positive box) is a vote that averaging
mixes into every point it touches, while the visibility-weighted medoid over many views picks a
view that agrees with the majority and leaves the outlier out.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import zlib
from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np

from ...errors import FileFormatError, ValidationError
from .base import ImageContext, Recognizer

__all__ = [
    "SimulatedNoise",
    "NOISE_PRESETS",
    "SimulatedRecognizer",
    "simulate_confidences",
    "confusion_tables",
]

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class SimulatedNoise:
    """Parameters of the simulated recogniser's noise model (see the module docstring).

    Attributes
    ----------
    downsample : int
        Output cells are ``downsample`` image pixels on a side.
    blur_sigma : float
        Gaussian blur of the body-part confidences, in output cells.
    peak_min, peak_max : float
        Range of the per-(view, class) peak confidence and of object detection confidences.
    p_flip : float
        Probability per view and frame block of a whole-figure left/right swap.
    p_swap : float
        Probability per (view, part) and frame block of a left/right swap of that part.
    p_neighbour : float
        Probability per (view, part) and frame block of reporting a neighbouring part.
    p_miss : float
        Probability per (view, class) and frame block that the class is not detected.
    fp_rate : float
        Mean number of false-positive boxes per image.
    fp_size : (float, float)
        Range of false-positive box sides, as fractions of the shorter image side.
    fp_conf : (float, float)
        Range of false-positive confidences.
    box_jitter : float
        Relative standard deviation of object box size and position.
    noise_std : float
        Standard deviation of the absolute Gaussian noise added everywhere.
    hold_frames : int
        Length of the frame blocks over which per-view confusions persist.
    """

    downsample: int = 8
    blur_sigma: float = 1.0
    peak_min: float = 0.6
    peak_max: float = 1.0
    p_flip: float = 0.05
    p_swap: float = 0.08
    p_neighbour: float = 0.12
    p_miss: float = 0.08
    fp_rate: float = 0.5
    fp_size: tuple[float, float] = (0.05, 0.2)
    fp_conf: tuple[float, float] = (0.3, 0.8)
    box_jitter: float = 0.1
    noise_std: float = 0.05
    hold_frames: int = 15

    def __post_init__(self) -> None:
        if self.downsample < 1:
            raise ValidationError(f"downsample: must be >= 1, got {self.downsample}")
        if self.hold_frames < 1:
            raise ValidationError(f"hold_frames: must be >= 1, got {self.hold_frames}")
        for f in ("p_flip", "p_swap", "p_neighbour", "p_miss", "peak_min", "peak_max"):
            v = getattr(self, f)
            if not 0.0 <= v <= 1.0:
                raise ValidationError(f"{f}: must be in [0, 1], got {v}")
        if self.peak_min > self.peak_max:
            raise ValidationError("peak_min: must not exceed peak_max")
        for f in ("blur_sigma", "fp_rate", "box_jitter", "noise_std"):
            if getattr(self, f) < 0:
                raise ValidationError(f"{f}: must be >= 0, got {getattr(self, f)}")


#: Noise presets by name (see the table in the module docstring).
NOISE_PRESETS: dict[str, SimulatedNoise] = {
    "none": SimulatedNoise(
        blur_sigma=0.0,
        peak_min=1.0,
        p_flip=0.0,
        p_swap=0.0,
        p_neighbour=0.0,
        p_miss=0.0,
        fp_rate=0.0,
        box_jitter=0.0,
        noise_std=0.0,
    ),
    "low": SimulatedNoise(
        peak_min=0.8,
        p_flip=0.02,
        p_swap=0.03,
        p_neighbour=0.05,
        p_miss=0.03,
        fp_rate=0.2,
        noise_std=0.02,
    ),
    "default": SimulatedNoise(),
    "high": SimulatedNoise(
        blur_sigma=1.5,
        peak_min=0.5,
        p_flip=0.10,
        p_swap=0.15,
        p_neighbour=0.25,
        p_miss=0.15,
        fp_rate=1.5,
        noise_std=0.08,
    ),
}

# Adjacent body parts (suffixes after "left_"/"right_"); same side, or either side-less.
_ADJACENT = {
    frozenset(p)
    for p in (
        ("upper_arm", "forearm"),
        ("forearm", "hand"),
        ("thigh", "shin"),
        ("shin", "foot"),
        ("torso", "upper_arm"),
        ("torso", "thigh"),
        ("head", "torso"),
    )
}


def _split_side(name: str) -> tuple[str | None, str]:
    for side in ("left", "right"):
        if name.startswith(side + "_"):
            return side, name[len(side) + 1 :]
    return None, name


def confusion_tables(class_names: Sequence[str]) -> tuple[np.ndarray, list[list[int]]]:
    """Left/right twins and neighbouring parts of each class, from the class names.

    Parameters
    ----------
    class_names : sequence of K str

    Returns
    -------
    mirror : (K,) int64 ndarray
        Index of each class's left/right twin (itself if it has none).
    neighbours : list of K lists of int
        Classes that a recogniser may confuse with each class.

    Examples
    --------
    >>> mirror, nbr = confusion_tables(["torso", "left_hand", "right_hand", "left_forearm"])
    >>> mirror.tolist(), nbr
    ([0, 2, 1, 3], [[], [3], [], [1]])
    """
    names = list(class_names)
    index = {n: i for i, n in enumerate(names)}
    mirror = np.arange(len(names), dtype=np.int64)
    parsed = [_split_side(n) for n in names]
    for i, (side, part) in enumerate(parsed):
        if side is not None:
            other = ("right" if side == "left" else "left") + "_" + part
            mirror[i] = index.get(other, i)
    neighbours: list[list[int]] = []
    for side, part in parsed:
        nbr = [
            j
            for j, (s2, p2) in enumerate(parsed)
            if frozenset((part, p2)) in _ADJACENT
            and part != p2
            and (side is None or s2 is None or side == s2)
        ]
        neighbours.append(nbr)
    return mirror, neighbours


def _seed(seed: int, camera: str, *parts: int) -> np.random.Generator:
    key = zlib.crc32(camera.encode("utf-8"))
    return np.random.default_rng(np.random.SeedSequence([seed, key, *parts]))


@lru_cache(maxsize=8)
def _cell_index(H: int, W: int, h: int, w: int) -> np.ndarray:
    rows = (np.arange(H, dtype=np.int64) * h) // H
    cols = (np.arange(W, dtype=np.int64) * w) // W
    return (rows[:, None] * w + cols[None, :]).ravel()  # (H * W,)


def simulate_confidences(
    label_map: np.ndarray,
    class_names: Sequence[str],
    kinds: Sequence[str] | None = None,
    noise: SimulatedNoise | str = "default",
    *,
    camera: str = "cam",
    frame: int = 0,
    seed: int = 0,
) -> np.ndarray:
    """Simulated recogniser output for one ground-truth label map.

    Parameters
    ----------
    label_map : (H, W) int ndarray
        Class index per pixel, -1 for background.
    class_names : sequence of K str
        The label set's classes (their names define left/right twins and neighbours).
    kinds : sequence of K str, optional
        ``"body"``, ``"object"`` or ``"instance"`` per class; objects become boxes
        (default: all body).
    noise : SimulatedNoise or str
        Noise parameters or a preset name of :data:`NOISE_PRESETS`.
    camera, frame, seed
        Seed the random draws, so the same image always gets the same output.

    Returns
    -------
    (h, w, K) float32 ndarray
        Confidences in [0, 1], ``h = ceil(H / downsample)``, ``w = ceil(W / downsample)``.

    Raises
    ------
    ValidationError
        On a bad label map (wrong shape, class indices outside -1..K-1) or noise preset.

    Examples
    --------
    >>> lab = np.full((16, 16), -1, np.int16); lab[:8] = 0; lab[8:, :8] = 1
    >>> L = simulate_confidences(lab, ["torso", "head"], noise="none")
    >>> L.shape, L[0, 0].tolist(), L[1, 0].tolist(), L[1, 1].tolist()
    ((2, 2, 2), [1.0, 0.0], [0.0, 1.0], [0.0, 0.0])
    """
    import cv2

    if isinstance(noise, str):
        if noise not in NOISE_PRESETS:
            raise ValidationError(
                f"noise: unknown preset {noise!r} (valid: {', '.join(NOISE_PRESETS)})"
            )
        noise = NOISE_PRESETS[noise]
    lab = np.asarray(label_map)
    if lab.ndim != 2 or not np.issubdtype(lab.dtype, np.integer):
        raise ValidationError(
            f"label_map: expected an (H, W) integer array, got {lab.dtype} {lab.shape}"
        )
    names = list(class_names)
    K = len(names)
    kinds = tuple(kinds) if kinds is not None else ("body",) * K
    if len(kinds) != K:
        raise ValidationError(f"kinds: expected {K} values, got {len(kinds)}")
    lo, hi = (int(lab.min()), int(lab.max())) if lab.size else (-1, -1)
    if lo < -1 or hi >= K:
        raise ValidationError(f"label_map: class indices must be in -1..{K - 1}, found {lo}..{hi}")
    H, W = lab.shape
    ds = noise.downsample
    h, w = max(1, -(-H // ds)), max(1, -(-W // ds))
    is_object = np.array([k == "object" for k in kinds], dtype=bool)

    # 1. Per-view confusions, held for a block of frames.
    key = zlib.crc32(camera.encode("utf-8"))
    block = (int(frame) + key % noise.hold_frames) // noise.hold_frames
    ev = _seed(seed, camera, block, 0)
    flip = ev.random() < noise.p_flip
    u = ev.random((K, 4))
    pick = ev.integers(0, 1 << 30, K)
    mirror, neighbours = confusion_tables(names)
    lut = np.arange(K, dtype=np.int64)
    for k in np.flatnonzero(~is_object):
        target = mirror[k] if flip else k
        if u[k, 0] < noise.p_swap and mirror[target] != target:
            target = mirror[target]
        elif u[k, 1] < noise.p_neighbour and neighbours[target]:
            target = neighbours[target][pick[k] % len(neighbours[target])]
        lut[k] = target
    missed = u[:, 2] < noise.p_miss  # (K,)
    peak = (noise.peak_min + (noise.peak_max - noise.peak_min) * u[:, 3]).astype(np.float32)

    # 2. Relabel, then area-average the one-hot map into coarse cells.
    lut1 = np.concatenate([[0], lut + 1])  # background stays 0
    code = lut1[lab.ravel().astype(np.int64) + 1]  # (H * W,) in 0..K
    cell = _cell_index(H, W, h, w)
    counts = np.bincount(cell * (K + 1) + code, minlength=h * w * (K + 1))
    per_cell = np.bincount(cell, minlength=h * w).astype(np.float32)
    frac = counts.reshape(h * w, K + 1)[:, 1:].astype(np.float32) / per_cell[:, None]
    frac = frac.reshape(h, w, K)  # (h, w, K)

    out = np.zeros((h, w, K), dtype=np.float32)
    body = np.flatnonzero(~is_object)
    if body.size:
        dense = np.ascontiguousarray(frac[:, :, body])
        if noise.blur_sigma > 0:
            dense = cv2.GaussianBlur(
                dense, (0, 0), noise.blur_sigma, borderType=cv2.BORDER_REPLICATE
            ).reshape(h, w, body.size)
        out[:, :, body] = dense * peak[body]

    px = _seed(seed, camera, int(frame), 1)

    # 3. Objects as jittered bounding boxes, every cell at the detection's confidence.
    for k in np.flatnonzero(is_object):
        mask = (frac[:, :, k] > 0).astype(np.uint8)
        if not mask.any():
            continue
        n, _, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
        for x0, y0, bw, bh, _area in stats[1:n]:
            jitter = px.normal(0.0, noise.box_jitter, 4) if noise.box_jitter > 0 else np.zeros(4)
            cx = x0 + bw / 2 + jitter[0] * bw
            cy = y0 + bh / 2 + jitter[1] * bh
            bw2 = bw * np.exp(jitter[2])
            bh2 = bh * np.exp(jitter[3])
            conf = px.uniform(noise.peak_min, noise.peak_max)
            _fill_box(out[:, :, k], cx - bw2 / 2, cy - bh2 / 2, cx + bw2 / 2, cy + bh2 / 2, conf)

    # Missed detections.
    out[:, :, missed] = 0.0

    # 4. False-positive boxes.
    n_fp = px.poisson(noise.fp_rate) if noise.fp_rate > 0 else 0
    side = min(h, w)
    for _ in range(n_fp):
        k = int(px.integers(0, K))
        bw = side * px.uniform(*noise.fp_size)
        bh = side * px.uniform(*noise.fp_size)
        x0 = px.uniform(-bw / 2, w - bw / 2)
        y0 = px.uniform(-bh / 2, h - bh / 2)
        _fill_box(out[:, :, k], x0, y0, x0 + bw, y0 + bh, px.uniform(*noise.fp_conf))

    # 5. Low overall noise.
    if noise.noise_std > 0:
        out += np.abs(px.standard_normal((h, w, K), dtype=np.float32)) * np.float32(noise.noise_std)
    np.clip(out, 0.0, 1.0, out=out)
    return out


def _fill_box(channel: np.ndarray, x0: float, y0: float, x1: float, y1: float, conf: float) -> None:
    """Raise the cells of ``channel`` (h, w) covered by box [x0, x1) x [y0, y1) to ``conf``."""
    h, w = channel.shape
    c0, c1 = max(0, int(np.floor(x0))), min(w, int(np.ceil(x1)))
    r0, r1 = max(0, int(np.floor(y0))), min(h, int(np.ceil(y1)))
    if c1 > c0 and r1 > r0:
        np.maximum(channel[r0:r1, c0:c1], np.float32(conf), out=channel[r0:r1, c0:c1])


class SimulatedRecognizer(Recognizer):
    """Recogniser for synthetic captures: ground-truth label maps with realistic noise.

    Parameters
    ----------
    class_names : sequence of K str
        The capture's classes (labels.toml order, which the label maps index).
    kinds : sequence of K str, optional
        Class kinds; ``"object"`` classes are reported as boxes.
    noise : str or SimulatedNoise
        A preset of :data:`NOISE_PRESETS` (``none``, ``low``, ``default``, ``high``) or
        explicit parameters.
    capture : path-like, optional
        Capture folder with ``gt/``; otherwise taken from each call's :class:`ImageContext`.
    seed : int
        Seed of the noise.
    **overrides
        Fields of :class:`SimulatedNoise` overriding the preset, e.g. ``downsample=4``.

    Notes
    -----
    The image itself is not used, so :attr:`needs_image` is False and callers may pass ``None``.
    """

    name = "simulated"
    #: The image is not looked at; callers may skip decoding it.
    needs_image = False

    def __init__(
        self,
        class_names: Sequence[str],
        kinds: Sequence[str] | None = None,
        *,
        noise: str | SimulatedNoise = "default",
        capture: str | os.PathLike | None = None,
        seed: int = 0,
        **overrides: Any,
    ) -> None:
        if isinstance(noise, str):
            if noise not in NOISE_PRESETS:
                raise ValidationError(
                    f"noise: unknown preset {noise!r} (valid: {', '.join(NOISE_PRESETS)})"
                )
            noise = NOISE_PRESETS[noise]
        valid = {f.name for f in dataclasses.fields(SimulatedNoise)}
        bad = sorted(set(overrides) - valid)
        if bad:
            raise ValidationError(
                f"simulated recogniser: unknown option {bad[0]!r} "
                f"(valid: capture, kinds, noise, seed, {', '.join(sorted(valid))})"
            )
        self.noise = dataclasses.replace(noise, **overrides) if overrides else noise
        self.class_names = tuple(class_names)
        self.kinds = tuple(kinds) if kinds is not None else ("body",) * len(self.class_names)
        if len(self.kinds) != len(self.class_names):
            raise ValidationError(
                f"kinds: expected {len(self.class_names)} values, got {len(self.kinds)}"
            )
        self.capture = None if capture is None else os.fspath(capture)
        self.seed = int(seed)

    @classmethod
    def from_labelset(cls, labelset: Any, **options: Any) -> SimulatedRecognizer:
        """Build for a :class:`~pointtraj.labelset.LabelSet` (class names and kinds)."""
        options.setdefault("kinds", labelset.kinds)
        return cls(labelset.names, **options)

    def recognize(
        self, image: np.ndarray | None, context: ImageContext | None = None
    ) -> np.ndarray:
        """Simulated confidences (h, w, K) for the image named by ``context``.

        Raises
        ------
        ValidationError
            Without a context, or without a capture folder in the context or constructor.
        FileFormatError
            If the ground-truth label map cannot be read.
        """
        capture = self._capture(context)
        from ...synth.groundtruth import load_label_map

        label_map = load_label_map(capture, context.camera, context.frame)
        return self._confidences(capture, context, image, label_map)

    def recognize_people(
        self, image: np.ndarray | None, context: ImageContext | None = None
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """Simulated confidences and person-id map for the image named by ``context``.

        The person-id map is the ground-truth instance map (``gt/instances``) on the body
        classes' pixels, at the confidences' coarse grid (each cell takes its centre pixel's
        person), with ids renumbered per image (first seen, first numbered) so they carry no
        ground truth across images. Per (view, frame block, person), with probability
        ``p_miss`` the person is missed (-1), as a detector misses a person. None for a
        capture without instance maps (rendered before they existed).
        """
        capture = self._capture(context)
        from ...synth.groundtruth import instance_map_path, load_instance_map, load_label_map

        label_map = load_label_map(capture, context.camera, context.frame)
        L2D = self._confidences(capture, context, image, label_map)
        if not instance_map_path(capture, context.camera, context.frame).is_file():
            return L2D, None
        inst = load_instance_map(capture, context.camera, context.frame)  # (H, W)
        if inst.shape != label_map.shape:
            raise FileFormatError(
                instance_map_path(capture, context.camera, context.frame),
                f"is {inst.shape}, the label map {label_map.shape}",
            )
        body = np.array([k == "body" for k in self.kinds] + [False])  # index -1: background
        h, w = L2D.shape[:2]
        H, W = label_map.shape
        rows = np.minimum(((np.arange(h) + 0.5) * H / h).astype(np.int64), H - 1)
        cols = np.minimum(((np.arange(w) + 0.5) * W / w).astype(np.int64), W - 1)
        cell_inst = inst[np.ix_(rows, cols)].astype(np.int64)  # (h, w)
        cell_body = body[label_map[np.ix_(rows, cols)].astype(np.int64)]  # (h, w)
        cell_inst[~cell_body] = -1
        key = zlib.crc32(context.camera.encode("utf-8"))
        block = (int(context.frame) + key % self.noise.hold_frames) // self.noise.hold_frames
        present = np.unique(cell_inst[cell_inst >= 0])
        if present.size:
            miss = _seed(self.seed, context.camera, block, 2).random(int(present.max()) + 1)
            cell_inst[np.isin(cell_inst, present[miss[present] < self.noise.p_miss])] = -1
        people = np.full((h, w), -1, np.int16)
        seen = cell_inst >= 0
        if seen.any():  # renumber 0, 1, ... in raster order of first appearance
            uniq, first, inv = np.unique(cell_inst[seen], return_index=True, return_inverse=True)
            rank = np.argsort(np.argsort(first))
            people[seen] = rank[inv].astype(np.int16)
        return L2D, people

    def _capture(self, context: ImageContext | None) -> str:
        """The capture folder of ``context`` (or the constructor's)."""
        if context is None:
            raise ValidationError("simulated recogniser: needs an ImageContext (camera, frame)")
        capture = context.capture or self.capture
        if capture is None:
            raise ValidationError(
                "simulated recogniser: no capture folder (pass capture= or ImageContext.capture)"
            )
        return capture

    def _confidences(
        self, capture: str, context: ImageContext, image: np.ndarray | None, label_map: np.ndarray
    ) -> np.ndarray:
        """:func:`simulate_confidences` of one image's label map."""
        from ...synth.groundtruth import label_map_path

        if image is not None and np.shape(image)[:2] != np.shape(label_map):
            raise ValidationError(
                f"image of {context.camera} frame {context.frame} is {np.shape(image)[:2]}, "
                f"its label map {np.shape(label_map)}"
            )
        try:
            return simulate_confidences(
                label_map,
                self.class_names,
                self.kinds,
                self.noise,
                camera=context.camera,
                frame=context.frame,
                seed=self.seed,
            )
        except ValidationError as exc:  # e.g. a class index beyond labels.toml's classes
            raise FileFormatError(
                label_map_path(capture, context.camera, context.frame),
                f"{exc} (labels.toml has {len(self.class_names)} classes)",
            ) from None
