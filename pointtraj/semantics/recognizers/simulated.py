"""A simulated recogniser for synthetic captures: ground-truth label maps plus realistic noise.

It reads the ground-truth label map of an image
(:func:`pointtraj.synth.groundtruth.load_label_map`, (H, W) int16, -1 = background) and turns it
into confidences L2D (h, w, K) that fail the way real recognisers do. Two noise models, chosen
by :attr:`SimulatedNoise.model` (``-o model=independent`` on the command line, ``model =
"independent"`` in a ``[semantics]`` options table):

- ``correlated`` (the default since issue 19): errors correlated the way the real
  ``body-parts`` recogniser's are, with rates fitted to it on the Pose2Sim demo
  (``benchmarks/study_recognizer_errors.py``; the table is in ``docs/recognizers.md``);
- ``independent`` (the default before): confusions drawn independently per camera, part and
  block of frames, at 8-pixel cells. Its output is unchanged, draw for draw.

The label maps are rendered front surfaces, so in both models the class reported at the
projection of a point hidden in a view is its occluder's (another part, the ball), as a real
recogniser sees it.

Steps, with the parameters of :class:`SimulatedNoise`:

1. **Per-view confusions** (decided once per camera and block of ``hold_frames`` frames, so
   they persist as a real recogniser's errors do while the pose changes little):

   - *(correlated)* each figure is reported left/right mirrored (every ``left_*`` class as its
     ``right_*`` twin and vice versa) with a probability that depends on the camera's viewing
     direction relative to the figure's facing direction: ``p_flip_front`` for a camera in
     front of it, ``p_flip_side`` at its side, ``p_flip_back`` behind it, linear in the cosine
     of the angle between (:meth:`SimulatedNoise.flip_probability`). The facing directions are
     the figures' torso axes in the ground truth (:func:`view_cosines`); figures are told
     apart by ``gt/instances``. With probability ``flip_coupling`` a view uses the draw shared
     by all views of the figure in that frame block (``frame // hold_frames``), so the views
     of one direction flip together; otherwise its own draw;
   - with probability ``p_flip`` the whole view is mirrored, whatever the direction;
   - per body part, with probability ``p_swap`` the part is reported as its left/right twin;
   - otherwise, per body part, with probability ``p_neighbour`` it is reported as a neighbouring
     part of the same side (upper arm <-> forearm <-> hand, thigh <-> shin <-> foot, torso <->
     upper arm / thigh / head);
   - per class, with probability ``p_miss`` the class is missed: its channel is zero in the view;
   - per class, the peak confidence is drawn uniformly from ``[peak_min, peak_max]``.

2. *(correlated)* **Part boundaries**, at image pixels:

   - *shifted*: a pixel of part p whose nearest neighbouring part q is within ``boundary_px *
     |g|`` pixels is reported as q, where g is a smooth random field in [-1, 1] (correlation
     length ``boundary_scale_px``) whose sign says which of the two parts encroaches on the
     other along that stretch of boundary. Confusions between neighbouring parts thus lie in
     a band along their boundary, as a segmenter's boundary placement errors do, never in
     whole parts;
   - *soft*: on the figure's pixels, each body part's confidence is ``exp(-(d / softness_px)^2)``
     with d the distance to that part's pixels (1 on the part), as the real recogniser's
     confidences fall off across a boundary.

3. **Coarse, blurred output**: the (relabelled) one-hot or soft map is area-averaged to
   ``ceil(H / downsample) x ceil(W / downsample)`` cells, then blurred by a Gaussian of
   ``blur_sigma`` cells, then scaled by the peak confidence.

4. **Objects as boxes** (classes of kind ``"object"``, e.g. ball): each connected blob of the
   class in the coarse map becomes its bounding box, its size and position jittered by
   ``box_jitter`` (relative standard deviation); every cell in the box gets the detection's
   confidence (uniform in ``[peak_min, peak_max]``), as a YOLO-style detector's box does, so the
   box also covers whatever lies around or in front of the object.

5. **False positives**: a Poisson(``fp_rate``) number of boxes per image, of a random class, at
   a random place, with sides of ``fp_size`` (fractions of the shorter image side) and
   confidence uniform in ``fp_conf``.

6. **Low overall noise**: ``|N(0, noise_std)|`` is added to every cell and class; the result is
   clipped to [0, 1].

Every draw comes from ``numpy.random.default_rng`` seeded by (``seed``, camera name, frame) (and
the frame block for the confusions), so the output is deterministic.

Presets of the correlated model (:data:`NOISE_PRESETS`, ``noise = "..."``):

============ ===== ===== ===== ======== ====== ====== ===== ====== ======= ======= ==== ====
preset       front side  back  coupling soft   bound  swap  p_miss fp_rate noise   peak ds
============ ===== ===== ===== ======== ====== ====== ===== ====== ======= ======= ==== ====
``none``     0     0     0     0        0      0      0     0      0       0       1    2
``low``      0.09  0     0     0        5.5    2.5    0.01  0.03   0.2     0.02    0.8  2
``default``  0.18  0     0     0        5.5    5.0    0.02  0.08   0.5     0.05    0.6  2
``high``     0.36  0     0     0        5.5    10.0   0.05  0.15   1.5     0.08    0.5  2
============ ===== ===== ===== ======== ====== ====== ===== ====== ======= ======= ==== ====

(front, side, back: ``p_flip_front``, ``p_flip_side``, ``p_flip_back``; soft, bound:
``softness_px``, ``boundary_px`` in pixels of an image whose longer side is 640 pixels
(``length_reference_px``; they scale with the image: twice as many pixels at 1280); peak: ``peak_min``, to ``peak_max`` = 1; ds:
``downsample``.) All have ``p_flip = p_neighbour = 0``, ``boundary_scale_px = 16``,
``blur_sigma = 1`` cell (1.5 in ``high``, 0 in ``none``) and ``hold_frames = 15``. Where the
``default`` values come from (``docs/recognizers.md`` has the measured table):

- ``p_flip_front``, ``p_flip_side``, ``p_flip_back``: the real recogniser's whole-figure flips
  on the Pose2Sim demo: 14 % of the front views (7 of 50, all in one camera and one run of
  frames, the other front camera never flipped at the same frames: hence ``flip_coupling =
  0``) and none of 49 back views. The demo has no side views, so the rate falls linearly from
  the front to 0 at the side; 0.18 gives the synthetic demo's front views (within 60 degrees,
  at cosines 0.5 - 1) the measured 14 % on average;
- ``softness_px``: the width of the band along the boundary between neighbouring parts where
  the runner-up's confidence exceeds half the winner's, 0.097 torso lengths for the real
  recogniser (8.6 px at the demo images' 640-pixel scale); 5.5 px gives the same share of the
  synthetic demo figure's torso;
- ``boundary_px``: the real recogniser places part boundaries from landmarks that its own
  triangulated skeleton reprojects to within 16 px at 1920 px (5.4 px at 640);
- ``downsample``: the real recogniser's map has 1.25-pixel cells at 640x512 (its 512-cell
  longer side); 2 is the nearest whole number that keeps the demo's maps small (320x256).

The independent model's presets (:data:`INDEPENDENT_PRESETS`, ``model = "independent"``), as
before issue 19:

============ ====== ====== ====== ====== ====== ======= ========= ==== =========
preset       p_flip p_swap p_nbr  p_miss fp_rate noise  peak      blur hold
============ ====== ====== ====== ====== ====== ======= ========= ==== =========
``none``     0      0      0      0      0      0       1 - 1     0    15
``low``      0.02   0.03   0.05   0.03   0.2    0.02    0.8 - 1   1.0  15
``default``  0.05   0.08   0.12   0.08   0.5    0.05    0.6 - 1   1.0  15
``high``     0.10   0.15   0.25   0.15   1.5    0.08    0.5 - 1   1.5  15
============ ====== ====== ====== ====== ====== ======= ========= ==== =========

All of them downsample by 8, jitter boxes by 0.1 and draw false-positive boxes with sides of
0.05 - 0.2 of the shorter image side and confidence 0.3 - 0.8. Its confusions are independent
per view, so averaging over views cancels them; the correlated model's do not cancel that way.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import zlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np

from ...errors import FileFormatError, ValidationError
from .base import ImageContext, Recognizer

__all__ = [
    "SimulatedNoise",
    "NOISE_PRESETS",
    "INDEPENDENT_PRESETS",
    "MODEL_PRESETS",
    "MODELS",
    "noise_preset",
    "lateral_sides",
    "view_cosines",
    "SimulatedRecognizer",
    "simulate_confidences",
    "confusion_tables",
]

logger = logging.getLogger(__name__)

#: The noise models: ``correlated`` (the default) and ``independent`` (before issue 19).
MODELS: tuple[str, ...] = ("correlated", "independent")
#: The correlated model's own parameters (zero in the independent model).
_CORRELATED_RATES = ("p_flip_front", "p_flip_side", "p_flip_back", "flip_coupling")
_CORRELATED_LENGTHS = ("softness_px", "boundary_px")


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
    model : str
        ``"correlated"`` or ``"independent"`` (:data:`MODELS`). The independent model refuses
        the correlated model's own parameters below (they must be 0).
    p_flip_front, p_flip_side, p_flip_back : float
        Probability per (view, figure) and frame block of a whole-figure left/right flip, for a
        camera in front of the figure, at its side, behind it (linear in the cosine between).
    flip_coupling : float
        Probability that a view's flip uses the draw shared by all views of the figure in the
        frame block (1: views flip together in order of their flip probability; 0: each view
        draws its own).
    softness_px : float
        Fall-off length of each body part's confidence outside the part (pixels of an image
        whose longer side is :data:`LENGTH_REFERENCE_PX`; scaled with the image).
    boundary_px : float
        Largest shift of a boundary between neighbouring parts (pixels, likewise scaled).
    boundary_scale_px : float
        Correlation length of the random boundary shift along the boundary (pixels, likewise).
    length_reference_px : float
        The image size (longer side, pixels) at which those three lengths are given; on
        another image they scale with its longer side, as a real recogniser's errors do with
        the image it is given (640: the demo's images, where they were measured). 0: they are
        the image's own pixels, whatever its size.

    Notes
    -----
    The field defaults are the independent model's ``default`` preset; the correlated model's
    presets are :data:`NOISE_PRESETS` (:func:`noise_preset`).
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
    model: str = "independent"
    p_flip_front: float = 0.0
    p_flip_side: float = 0.0
    p_flip_back: float = 0.0
    flip_coupling: float = 0.0
    softness_px: float = 0.0
    boundary_px: float = 0.0
    boundary_scale_px: float = 16.0
    length_reference_px: float = 640.0

    def __post_init__(self) -> None:
        if self.model not in MODELS:
            raise ValidationError(
                f"model: unknown noise model {self.model!r} (valid: {', '.join(MODELS)})"
            )
        if self.downsample < 1:
            raise ValidationError(f"downsample: must be >= 1, got {self.downsample}")
        if self.hold_frames < 1:
            raise ValidationError(f"hold_frames: must be >= 1, got {self.hold_frames}")
        for f in (
            "p_flip",
            "p_swap",
            "p_neighbour",
            "p_miss",
            "peak_min",
            "peak_max",
            *_CORRELATED_RATES,
        ):
            v = getattr(self, f)
            if not 0.0 <= v <= 1.0:
                raise ValidationError(f"{f}: must be in [0, 1], got {v}")
        if self.peak_min > self.peak_max:
            raise ValidationError("peak_min: must not exceed peak_max")
        for f in ("blur_sigma", "fp_rate", "box_jitter", "noise_std", *_CORRELATED_LENGTHS):
            if getattr(self, f) < 0:
                raise ValidationError(f"{f}: must be >= 0, got {getattr(self, f)}")
        if self.boundary_scale_px <= 0:
            raise ValidationError(f"boundary_scale_px: must be > 0, got {self.boundary_scale_px}")
        if not self.length_reference_px >= 0:
            raise ValidationError(
                f"length_reference_px: must be >= 0, got {self.length_reference_px}"
            )
        if self.model == "independent":
            used = [f for f in (*_CORRELATED_RATES, *_CORRELATED_LENGTHS) if getattr(self, f)]
            if used:
                raise ValidationError(
                    f"{used[0]}: a parameter of the correlated noise model, but model = "
                    f"'independent' (set model = 'correlated' or {used[0]} = 0)"
                )

    @property
    def correlated(self) -> bool:
        """Whether any of the correlated model's mechanisms is on."""
        return any(getattr(self, f) for f in (*_CORRELATED_RATES, *_CORRELATED_LENGTHS))

    def flip_probability(self, cos: np.ndarray) -> np.ndarray:
        """Probability of a whole-figure left/right flip given the viewing-direction cosine.

        Piecewise linear in ``cos``: ``p_flip_front`` at 1 (camera in front of the figure),
        ``p_flip_side`` at 0, ``p_flip_back`` at -1; NaN (direction unknown) gives
        ``p_flip_side``.

        Parameters
        ----------
        cos : array-like
            Cosines from :func:`view_cosines`.

        Returns
        -------
        float64 ndarray, the shape of ``cos``
        """
        c = np.clip(np.nan_to_num(np.asarray(cos, np.float64), nan=0.0), -1.0, 1.0)
        toward = np.where(c >= 0, self.p_flip_front, self.p_flip_back)
        return self.p_flip_side + np.abs(c) * (toward - self.p_flip_side)


#: Today's independent presets by name (the ``model = "independent"`` table of the docstring).
INDEPENDENT_PRESETS: dict[str, SimulatedNoise] = {
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

_CORRELATED_DEFAULT = SimulatedNoise(
    model="correlated",
    downsample=2,
    blur_sigma=1.0,
    peak_min=0.6,
    p_flip=0.0,
    p_swap=0.02,
    p_neighbour=0.0,
    p_miss=0.08,
    p_flip_front=0.18,
    p_flip_side=0.0,
    p_flip_back=0.0,
    flip_coupling=0.0,
    softness_px=5.5,
    boundary_px=5.0,
)

#: Presets of the correlated model (the default model) by name; see the module docstring.
NOISE_PRESETS: dict[str, SimulatedNoise] = {
    "none": dataclasses.replace(
        INDEPENDENT_PRESETS["none"], model="correlated", downsample=_CORRELATED_DEFAULT.downsample
    ),
    "low": dataclasses.replace(
        _CORRELATED_DEFAULT,
        peak_min=0.8,
        p_swap=0.01,
        p_miss=0.03,
        fp_rate=0.2,
        noise_std=0.02,
        p_flip_front=_CORRELATED_DEFAULT.p_flip_front / 2,
        p_flip_side=_CORRELATED_DEFAULT.p_flip_side / 2,
        p_flip_back=_CORRELATED_DEFAULT.p_flip_back / 2,
        boundary_px=_CORRELATED_DEFAULT.boundary_px / 2,
    ),
    "default": _CORRELATED_DEFAULT,
    "high": dataclasses.replace(
        _CORRELATED_DEFAULT,
        blur_sigma=1.5,
        peak_min=0.5,
        p_swap=0.05,
        p_miss=0.15,
        fp_rate=1.5,
        noise_std=0.08,
        p_flip_front=min(1.0, 2 * _CORRELATED_DEFAULT.p_flip_front),
        p_flip_side=min(1.0, 2 * _CORRELATED_DEFAULT.p_flip_side),
        p_flip_back=min(1.0, 2 * _CORRELATED_DEFAULT.p_flip_back),
        boundary_px=2 * _CORRELATED_DEFAULT.boundary_px,
    ),
}

#: Preset tables by noise model.
MODEL_PRESETS: dict[str, dict[str, SimulatedNoise]] = {
    "correlated": NOISE_PRESETS,
    "independent": INDEPENDENT_PRESETS,
}


def noise_preset(name: str, model: str = "correlated") -> SimulatedNoise:
    """The preset ``name`` of noise model ``model``.

    Parameters
    ----------
    name : str
        ``none``, ``low``, ``default`` or ``high``.
    model : str
        ``correlated`` (the default model) or ``independent`` (the model before issue 19).

    Returns
    -------
    SimulatedNoise

    Raises
    ------
    ValidationError
        On an unknown model or preset (the valid names are listed).

    Examples
    --------
    >>> noise_preset("default").model, noise_preset("low", "independent").p_flip
    ('correlated', 0.02)
    """
    if model not in MODEL_PRESETS:
        raise ValidationError(f"model: unknown noise model {model!r} (valid: {', '.join(MODELS)})")
    presets = MODEL_PRESETS[model]
    if name not in presets:
        raise ValidationError(f"noise: unknown preset {name!r} (valid: {', '.join(presets)})")
    return presets[name]


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


def lateral_sides(class_names: Sequence[str]) -> np.ndarray:
    """+1 for ``left_*`` classes, -1 for ``right_*`` ones, 0 for the others.

    Parameters
    ----------
    class_names : sequence of K str

    Returns
    -------
    (K,) int64 ndarray

    Examples
    --------
    >>> lateral_sides(["torso", "left_hand", "right_foot"]).tolist()
    [0, 1, -1]
    """
    side = {"left": 1, "right": -1, None: 0}
    return np.array([side[_split_side(n)[0]] for n in class_names], dtype=np.int64)


def view_cosines(forward: np.ndarray, centre: np.ndarray, rig: Any, up: np.ndarray) -> np.ndarray:
    """Cosine of each camera's viewing direction relative to each figure's facing direction.

    The angle is between the figure's facing direction and the direction from its centre to
    the camera centre, both projected onto the plane orthogonal to ``up``: 1 for a camera in
    front of the figure, -1 behind it, 0 at its side.

    Parameters
    ----------
    forward : (..., 3) float ndarray
        Facing directions (need not be unit or horizontal).
    centre : (..., 3) float ndarray
        Figure centres (pelvis), same leading shape.
    rig : CameraRig
        C cameras (their centres ``C``).
    up : (3,) float ndarray
        World up.

    Returns
    -------
    (..., C) float64 ndarray
        NaN where a direction is degenerate (vertical) or an input is NaN.

    Examples
    --------
    >>> from pointtraj.camera import Camera, CameraRig
    >>> rig = CameraRig([Camera.look_at(n, (x, 0, 1), (0, 0, 1), (64, 48), 500.0)
    ...                  for n, x in (("front", 3), ("back", -3))])
    >>> view_cosines(np.array([1.0, 0, 0]), np.zeros(3), rig, np.array([0, 0, 1.0])).round(3)
    array([ 1., -1.])
    """
    up = np.asarray(up, np.float64) / np.linalg.norm(up)
    cams = np.stack([np.asarray(cam.C, np.float64) for cam in rig])  # (C, 3)
    f = np.asarray(forward, np.float64)
    f = f - (f @ up)[..., None] * up
    to_cam = cams - np.asarray(centre, np.float64)[..., None, :]  # (..., C, 3)
    to_cam = to_cam - (to_cam @ up)[..., None] * up
    with np.errstate(invalid="ignore", divide="ignore"):
        num = np.einsum("...k,...ck->...c", f, to_cam)
        den = np.linalg.norm(f, axis=-1)[..., None] * np.linalg.norm(to_cam, axis=-1)
        return num / np.where(den > 1e-12, den, np.nan)


def _seed(seed: int, camera: str, *parts: int) -> np.random.Generator:
    key = zlib.crc32(camera.encode("utf-8"))
    return np.random.default_rng(np.random.SeedSequence([seed, key, *parts]))


@lru_cache(maxsize=8)
def _cell_index(H: int, W: int, h: int, w: int) -> np.ndarray:
    rows = (np.arange(H, dtype=np.int64) * h) // H
    cols = (np.arange(W, dtype=np.int64) * w) // W
    return (rows[:, None] * w + cols[None, :]).ravel()  # (H * W,)


def _resolve_noise(noise: SimulatedNoise | str) -> SimulatedNoise:
    """A preset name of :data:`NOISE_PRESETS` (the correlated model) or the parameters."""
    return noise_preset(noise) if isinstance(noise, str) else noise


def _confusion_lut(
    flip: bool,
    u: np.ndarray,
    pick: np.ndarray,
    noise: SimulatedNoise,
    mirror: np.ndarray,
    neighbours: list[list[int]],
    is_object: np.ndarray,
) -> np.ndarray:
    """(K,) class each class is reported as: the whole-view flip, then per-part confusions."""
    lut = np.arange(len(mirror), dtype=np.int64)
    for k in np.flatnonzero(~is_object):
        target = mirror[k] if flip else k
        if u[k, 0] < noise.p_swap and mirror[target] != target:
            target = mirror[target]
        elif u[k, 1] < noise.p_neighbour and neighbours[target]:
            target = neighbours[target][pick[k] % len(neighbours[target])]
        lut[k] = target
    return lut


def _figure_flips(
    noise: SimulatedNoise,
    facing: Mapping[int, float] | None,
    instances: np.ndarray | None,
    *,
    seed: int,
    camera: str,
    block: int,
    frame: int,
) -> dict[int, bool]:
    """Whole-figure flips by viewing direction, per figure instance id (see the docstring).

    Figures are those of ``facing`` and of ``instances``; without either, one figure (id 0)
    seen from an unknown direction.
    """
    ids = set(facing or {})
    if instances is not None:
        ids.update(int(i) for i in _present(instances))
    if not ids:
        ids = {0}
    flips = {}
    for fig in sorted(ids):
        cos = np.nan if facing is None else facing.get(fig, np.nan)
        p = float(noise.flip_probability(cos))
        shared = _seed(seed, "", fig, int(frame) // noise.hold_frames, 3).random()
        own, coupled = _seed(seed, camera, block, 3, fig).random(2)
        flips[fig] = bool((shared if coupled < noise.flip_coupling else own) < p)
    return flips


def _at_image_size(noise: SimulatedNoise, H: int, W: int) -> SimulatedNoise:
    """``noise`` with its lengths scaled from ``length_reference_px`` to an (H, W) image."""
    if noise.length_reference_px == 0:
        return noise
    s = max(H, W) / noise.length_reference_px
    if s == 1:
        return noise
    return dataclasses.replace(
        noise,
        softness_px=noise.softness_px * s,
        boundary_px=noise.boundary_px * s,
        boundary_scale_px=noise.boundary_scale_px * s,
    )


def _present(values: np.ndarray) -> np.ndarray:
    """Sorted distinct values >= 0 of a small-integer array (-1: none), like ``np.unique``."""
    v = values.ravel()
    if v.size == 0:
        return np.zeros(0, np.int64)
    hi = int(v.max())
    if hi < 0:
        return np.zeros(0, np.int64)
    if hi > 1 << 20 or int(v.min()) < -1:  # large ids (bincount's size) or other negatives
        u = np.unique(v)
        return u[u >= 0].astype(np.int64)
    return np.flatnonzero(np.bincount((v + 1).astype(np.intp), minlength=hi + 2)[1:])


def _class_box(lab: np.ndarray, k: int, reach: int) -> tuple[slice, slice]:
    """The bounding box of class ``k``'s pixels in ``lab`` (h, w), widened by ``reach`` pixels."""
    mask = lab == k
    rows = np.flatnonzero(mask.any(axis=1))
    cols = np.flatnonzero(mask.any(axis=0))
    h, w = lab.shape
    return (
        slice(max(0, int(rows[0]) - reach), min(h, int(rows[-1]) + reach + 1)),
        slice(max(0, int(cols[0]) - reach), min(w, int(cols[-1]) + reach + 1)),
    )


def _class_distance(lab: np.ndarray, k: int, reach: int) -> tuple[tuple[slice, slice], np.ndarray]:
    """Distance to class ``k``'s pixels, in its bounding box widened by ``reach`` pixels.

    Returns the box and the (bh, bw) float32 distances in it: those of
    ``cv2.distanceTransform(lab != k, DIST_L2, 5)`` on the whole of ``lab`` (the box holds
    every pixel of k, and a 5x5 chamfer path stays in the box of its two ends), equal or, where
    two paths of the same length add their steps in another order, one float32 rounding apart
    (about 4e-6 px at 30 px). Outside the box the distance is at least ``reach`` (a chamfer
    distance is at least the larger coordinate difference).
    """
    import cv2

    box = _class_box(lab, k, reach)
    d = cv2.distanceTransform((lab[box] != k).astype(np.uint8), cv2.DIST_L2, 5)
    return box, d


#: float32 ``exp(-x)`` is exactly 0 for x >= 104; soft confidences are cut at this exponent.
_EXP_ZERO = 105.0


def _shift_boundaries(
    lab: np.ndarray,
    body: np.ndarray,
    neighbour: np.ndarray,
    noise: SimulatedNoise,
    rng: np.random.Generator,
    full_shape: tuple[int, int],
    origin: tuple[int, int],
) -> np.ndarray:
    """Move part boundaries between neighbouring parts by a smooth random field.

    ``lab`` (h, w) is a crop at ``origin`` (row, col) of a ``full_shape`` label map. A pixel of
    part p whose nearest neighbouring part q lies within ``boundary_px * |g|`` is reported as
    q where the field g (smooth, in [-1, 1], correlation length ``boundary_scale_px``) has the
    sign of the pair (p, q) (+ when p < q), so along each stretch of boundary one part
    encroaches on the other. Of equally near parts, the first in class order.

    Distances are computed only within ``boundary_px`` of each part (:func:`_class_distance`):
    no pixel farther from every neighbouring part can move.
    """
    import cv2

    H, W = full_shape
    sc = noise.boundary_scale_px
    coarse = rng.standard_normal((int(np.ceil(H / sc)) + 2, int(np.ceil(W / sc)) + 2))
    field = cv2.resize(coarse.astype(np.float32), (W, H), interpolation=cv2.INTER_CUBIC)
    y0, x0 = origin
    g = np.clip(field[y0 : y0 + lab.shape[0], x0 : x0 + lab.shape[1]], -1.0, 1.0)  # (h, w)
    present = [int(k) for k in _present(lab) if body[k]]
    if len(present) < 2:
        return lab
    own = np.where(lab >= 0, lab, 0)
    is_body = (lab >= 0) & body[own]
    reach = int(np.ceil(noise.boundary_px)) + 1
    dq = np.full(lab.shape, np.inf, np.float32)  # distance to the nearest neighbouring part
    q = np.zeros(lab.shape, np.int64)  # ... and that part
    for k in present:  # in class order, so ties keep the first part
        box, d = _class_distance(lab, k, reach)
        nearer = neighbour[own[box], k] & (d < dq[box])
        dq[box][nearer] = d[nearer]
        q[box][nearer] = k
    sign = np.where(own < q, 1.0, -1.0)
    move = is_body & np.isfinite(dq) & (sign * g > 0) & (dq < noise.boundary_px * np.abs(g))
    out = lab.copy()
    out[move] = q[move]
    return out


def simulate_confidences(
    label_map: np.ndarray,
    class_names: Sequence[str],
    kinds: Sequence[str] | None = None,
    noise: SimulatedNoise | str = "default",
    *,
    camera: str = "cam",
    frame: int = 0,
    seed: int = 0,
    instances: np.ndarray | None = None,
    facing: Mapping[int, float] | None = None,
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
        Noise parameters or a preset name of :data:`NOISE_PRESETS` (the correlated model;
        :func:`noise_preset` gives the independent model's).
    camera, frame, seed
        Seed the random draws, so the same image always gets the same output.
    instances : (H, W) int ndarray, optional
        Instance id per pixel (-1: none), for figures flipped one by one (correlated model).
    facing : mapping of int to float, optional
        Figure instance id -> cosine of this camera's viewing direction relative to the
        figure's facing direction (:func:`view_cosines`); figures not in it, or all without
        it, are seen from an unknown direction (flip probability ``p_flip_side``).

    Returns
    -------
    (h, w, K) float32 ndarray
        Confidences in [0, 1], ``h = ceil(H / downsample)``, ``w = ceil(W / downsample)``.

    Raises
    ------
    ValidationError
        On a bad label map (wrong shape, class indices outside -1..K-1), instance map or
        noise preset.

    Examples
    --------
    >>> lab = np.full((16, 16), -1, np.int16); lab[:8] = 0; lab[8:, :8] = 1
    >>> L = simulate_confidences(lab, ["torso", "head"], noise=noise_preset("none", "independent"))
    >>> L.shape, L[0, 0].tolist(), L[1, 0].tolist(), L[1, 1].tolist()
    ((2, 2, 2), [1.0, 0.0], [0.0, 1.0], [0.0, 0.0])
    """
    import cv2

    noise = _resolve_noise(noise)
    lab = np.asarray(label_map)
    if lab.ndim != 2 or not np.issubdtype(lab.dtype, np.integer):
        raise ValidationError(
            f"label_map: expected an (H, W) integer array, got {lab.dtype} {lab.shape}"
        )
    if instances is not None:
        instances = np.asarray(instances)
        if instances.shape != lab.shape or not np.issubdtype(instances.dtype, np.integer):
            raise ValidationError(
                f"instances: expected an {lab.shape} integer array, got "
                f"{instances.dtype} {instances.shape}"
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
    lut = _confusion_lut(flip, u, pick, noise, mirror, neighbours, is_object)
    missed = u[:, 2] < noise.p_miss  # (K,)
    peak = (noise.peak_min + (noise.peak_max - noise.peak_min) * u[:, 3]).astype(np.float32)

    # 2. Relabel, then area-average the one-hot map into coarse cells.
    lut1 = np.concatenate([[0], lut + 1])  # background stays 0
    lab64 = lab.ravel().astype(np.int64) + 1
    if noise.correlated:
        flips = _figure_flips(
            noise, facing, instances, seed=seed, camera=camera, block=block, frame=frame
        )
        lut_flip = _confusion_lut(not flip, u, pick, noise, mirror, neighbours, is_object)
        lut_flip1 = np.concatenate([[0], lut_flip + 1])
        flipped = sorted(i for i, f in flips.items() if f)
        if instances is None:
            code = (lut_flip1 if flips[min(flips)] else lut1)[lab64]  # (H * W,) in 0..K
        elif not flipped:
            code = lut1[lab64]
        else:
            code = np.where(np.isin(instances.ravel(), flipped), lut_flip1[lab64], lut1[lab64])
    else:
        code = lut1[lab64]  # (H * W,) in 0..K
    cell = _cell_index(H, W, h, w)
    soft = None
    if noise.correlated and (noise.boundary_px > 0 or noise.softness_px > 0):
        code, soft = _soft_boundaries(
            code, (H, W), ~is_object, neighbours, _at_image_size(noise, H, W), seed, camera, block
        )
    # Each cell's share of each class: its pixel count over the cell's pixels, or with soft
    # boundaries the mean of the part's soft confidence. The soft sums are taken in pixel
    # order and divided in float64, then rounded to float32, in the cells of the rows that
    # hold the parts (outside them, a part's soft confidence and pixel count are both 0).
    counts = np.bincount(cell * (K + 1) + code, minlength=h * w * (K + 1))
    per_cell = np.bincount(cell, minlength=h * w).astype(np.float32)
    frac = counts.reshape(h * w, K + 1)[:, 1:].astype(np.float32)
    frac /= per_cell[:, None]  # (h * w, K)
    if soft:
        rows = (np.array([[b[0], b[1] - 1] for _, b, _ in soft]) * h) // H  # cell rows
        n0, n1 = int(rows[:, 0].min()) * w, (int(rows[:, 1].max()) + 1) * w
        cells = cell.reshape(H, W)
        bins = [cells[r0:r1, c0:c1].ravel() * K + (k - n0 * K) for k, (r0, r1, c0, c1), _ in soft]
        sums = np.bincount(
            np.concatenate(bins),
            weights=np.concatenate([conf.ravel() for *_, conf in soft]),
            minlength=(n1 - n0) * K,
        ).reshape(n1 - n0, K)
        is_soft = np.zeros(K, bool)
        is_soft[[k for k, *_ in soft]] = True
        frac[n0:n1] = np.where(is_soft, sums / per_cell[n0:n1, None], frac[n0:n1])
    frac = frac.reshape(h, w, K)  # (h, w, K)

    # Body parts: blurred, scaled by their peak. Objects: 0 here, boxes below. (The blur
    # treats channels one by one, so blurring the objects' too changes no body channel.)
    gain = np.where(is_object, np.float32(0.0), peak)  # (K,)
    if noise.blur_sigma > 0 and not is_object.all():
        out = cv2.GaussianBlur(frac, (0, 0), noise.blur_sigma, borderType=cv2.BORDER_REPLICATE)
        out = out.reshape(h, w, K)
        out *= gain
    else:
        out = frac * gain

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
        z = px.standard_normal((h, w, K), dtype=np.float32)
        np.abs(z, out=z)
        z *= np.float32(noise.noise_std)
        out += z
    np.clip(out, 0.0, 1.0, out=out)
    return out


def _soft_boundaries(
    code: np.ndarray,
    shape: tuple[int, int],
    body: np.ndarray,
    neighbours: list[list[int]],
    noise: SimulatedNoise,
    seed: int,
    camera: str,
    block: int,
) -> tuple[np.ndarray, list[tuple[int, tuple[int, int, int, int], np.ndarray]] | None]:
    """Shifted part boundaries and the body parts' soft confidences, inside the figures' box.

    Parameters
    ----------
    code : (H * W,) int64 ndarray
        Reported class + 1 per pixel (0: background). Changed in place by the shift.

    Returns
    -------
    code : (H * W,) int64 ndarray
        After :func:`_shift_boundaries`.
    soft : list of (int, (r0, r1, c0, c1), (r1 - r0, c1 - c0) float32 ndarray) or None
        For each body class k present, in class order: k, a box of image rows and columns
        and, in it, ``exp(-(d_k / softness_px)^2)`` on body pixels (``d_k`` the distance to
        class k's pixels, 0 inside). Outside its box the value is 0 (it underflows there, as
        float32 does beyond ``d_k = sqrt(104) softness_px``). None without softness or body
        pixels.
    """
    H, W = shape
    lab = code.reshape(H, W)  # class + 1: a view, so the shift below changes ``code``
    is_body = np.concatenate([[False], body])[lab]
    rows = np.flatnonzero(is_body.any(axis=1))
    if rows.size == 0:
        return code, None
    cols = np.flatnonzero(is_body.any(axis=0))
    pad = int(np.ceil(noise.boundary_px + 3 * noise.softness_px)) + 2
    y0, y1 = max(0, int(rows[0]) - pad), min(H, int(rows[-1]) + pad + 1)
    x0, x1 = max(0, int(cols[0]) - pad), min(W, int(cols[-1]) + pad + 1)
    sub = lab[y0:y1, x0:x1] - 1
    if noise.boundary_px > 0:
        K = len(body)
        neighbour = np.zeros((K, K), bool)
        for k, js in enumerate(neighbours):
            neighbour[k, js] = True
        rng = _seed(seed, camera, block, 4)
        sub = _shift_boundaries(sub, body, neighbour, noise, rng, (H, W), (y0, x0))
        lab[y0:y1, x0:x1] = sub + 1
    if noise.softness_px <= 0:
        return code, None
    own = np.where(sub >= 0, sub, 0)
    sub_body = (sub >= 0) & body[own]
    inv = np.float32(1.0 / noise.softness_px)
    reach = int(np.ceil(np.sqrt(_EXP_ZERO) * noise.softness_px)) + 1
    soft = []
    for k in _present(sub):
        if not body[k]:
            continue
        (rs, cs), d = _class_distance(sub, int(k), reach)
        conf = np.where(sub_body[rs, cs], np.exp(-np.square(d * inv)), 0.0)
        box = (y0 + rs.start, y0 + rs.stop, x0 + cs.start, x0 + cs.stop)
        soft.append((int(k), box, conf))
    return code, soft


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
        A preset (``none``, ``low``, ``default``, ``high``) of the noise model named by the
        ``model`` override (default ``correlated``: :data:`NOISE_PRESETS`; ``independent``:
        :data:`INDEPENDENT_PRESETS`), or explicit parameters.
    capture : path-like, optional
        Capture folder with ``gt/``; otherwise taken from each call's :class:`ImageContext`.
    seed : int
        Seed of the noise.
    **overrides
        Fields of :class:`SimulatedNoise` overriding the preset, e.g. ``downsample=4`` or
        ``model="independent"``.

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
            noise = noise_preset(noise, str(overrides.get("model", "correlated")))
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
        instances, facing = None, None
        if self.noise.correlated:
            from ...synth.groundtruth import instance_map_path, load_instance_map

            if instance_map_path(capture, context.camera, context.frame).is_file():
                instances = load_instance_map(capture, context.camera, context.frame)
                if instances.shape != label_map.shape:
                    raise FileFormatError(
                        instance_map_path(capture, context.camera, context.frame),
                        f"is {instances.shape}, the label map {label_map.shape}",
                    )
            if "torso" in self.class_names:
                torso = self.class_names.index("torso")
                facing = _view_facing(capture, torso, context.camera, context.frame)
        try:
            return simulate_confidences(
                label_map,
                self.class_names,
                self.kinds,
                self.noise,
                camera=context.camera,
                frame=context.frame,
                seed=self.seed,
                instances=instances,
                facing=facing,
            )
        except ValidationError as exc:  # e.g. a class index beyond labels.toml's classes
            raise FileFormatError(
                label_map_path(capture, context.camera, context.frame),
                f"{exc} (labels.toml has {len(self.class_names)} classes)",
            ) from None


def _view_facing(capture: str, torso: int, camera: str, frame: int) -> dict[int, float] | None:
    """Figure instance id -> viewing-direction cosine of ``camera`` at ``frame``, or None.

    ``torso`` is the torso's class index (labels.toml order).
    """
    table = _facing_table(capture, torso, _stamp(os.path.join(capture, "gt", "synth.toml")))
    if table is None:
        return None
    cameras, cosines = table
    if camera not in cameras:
        return None
    c = cameras.index(camera)
    return {fig: float(cos[frame, c]) for fig, cos in cosines.items() if 0 <= frame < len(cos)}


def _stamp(path: str) -> tuple[int, int] | None:
    try:
        st = os.stat(path)
    except OSError:
        return None
    return st.st_size, st.st_mtime_ns


@lru_cache(maxsize=4)
def _facing_table(
    capture: str, torso: int, stamp: tuple[int, int] | None
) -> tuple[list[str], dict[int, np.ndarray]] | None:
    """Camera names and, per figure, (T, C) viewing-direction cosines of a synthetic capture.

    The figures' facing directions are their torsos' local x axes (the figure frame of
    :mod:`pointtraj.synth.figure`: x forward, z up), from the exact part poses that
    :func:`pointtraj.synth.groundtruth.segment_ground_truth` rebuilds from ``gt/synth.toml``;
    the camera centres come from ``rig.toml``. ``stamp`` (size and time of ``gt/synth.toml``)
    keys the cache. None, with a logged warning, when either is missing or the capture has no
    torso: every view is then seen from an unknown direction (flip probability
    ``p_flip_side``).
    """
    from ...errors import PointtrajError
    from ...rigio import load_rig
    from ...synth.groundtruth import segment_ground_truth

    try:
        seg = segment_ground_truth(capture)
        rig = load_rig(os.path.join(capture, "rig.toml"))
    except (PointtrajError, OSError) as exc:
        logger.warning(
            "simulated recogniser: no figure facing directions for %s (%s); left/right flips "
            "use p_flip_side in every view",
            capture,
            exc,
        )
        return None
    up = np.array([0.0, 0.0, 1.0])
    cosines = {
        int(seg.part_instance[g]): view_cosines(
            seg.part_poses[g, :, :3, 0], seg.part_poses[g, :, :3, 3], rig, up
        )  # (T, C)
        for g in np.flatnonzero(seg.part_label == torso)
    }
    if not cosines:
        logger.warning(
            "simulated recogniser: %s has no torso to face with; left/right flips use "
            "p_flip_side in every view",
            capture,
        )
        return None
    return list(rig.names), cosines
