"""The rig's length scale: metre-based defaults that follow the size of what the cameras see.

Every length threshold of the defaults (depth ranges, occlusion tolerances, neighbour radii,
the affinity's ε and τ, ...) was tuned on human-sized stages, where the cameras' common view
(:func:`pointtraj.reconstruct.connectivity.common_view`) is a box about 1.5-4.4 m across
(caliscope's webcams 1.54 m, paper69 2.9 m, the demo's ring 3.4 m, lab4 3.6 m). A rig that
looks at a few millimetres needs them a thousand times smaller.

One factor, from one figure of the rig, scales them all (:func:`scene_scale`):

- the rig's **extent** ``L`` is the geometric mean of the common view's box sides (or of
  ``[reconstruct] capture_volume`` when it is set). It follows the scene, not the resolution:
  a rig's pixel footprint would move the values between human rigs that see the same stage at
  320x256 and at 1280x1024;
- ``L >= 1 m`` (**human-sized**, every rig the defaults were tuned on): factor 1, today's
  values exactly;
- ``L <= 0.3 m``: factor ``L / 3 m``, the extent against the 3 m of the human rigs the
  defaults were tuned on (``narrow7``: 11.6 mm, factor 0.0039; a subject scaled by 0.004
  gets the thresholds its human-sized original has);
- in between, geometric interpolation (0.1 at 0.3 m to 1 at 1 m), so the factor never jumps.

A length left at its default is a :class:`SceneLength` (a float that remembers its
human-scale value); :func:`scale_lengths` replaces those, and only those, by the scaled value:
a value the user sets (in TOML or in Python) is a plain float and always wins. The factor is
logged once per rig at INFO, and each stage logs the values it derived from it.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, TypeVar

import numpy as np

if TYPE_CHECKING:  # pragma: no cover
    from .camera import CameraRig

__all__ = [
    "HUMAN_EXTENT_M",
    "REFERENCE_EXTENT_M",
    "SMALL_EXTENT_M",
    "SceneLength",
    "SceneScale",
    "scale_factor",
    "scale_lengths",
    "scene_scale",
    "work_scene_scale",
]

logger = logging.getLogger(__name__)

T = TypeVar("T")

#: Extent (m) from which a rig is human-sized: its lengths keep their defaults (factor 1).
HUMAN_EXTENT_M = 1.0
#: Extent (m) up to which the factor is proportional to the extent.
SMALL_EXTENT_M = 0.3
#: The extent (m) of the human rigs the defaults were tuned on (paper69 2.9, the demo 3.4).
REFERENCE_EXTENT_M = 3.0


class SceneLength(float):
    """A default length (metres) that follows the rig's scale while it is left unset.

    It is a float (its value is the human-scale default until :func:`scale_lengths` scales
    it), and remembers the human-scale value in ``human``. Values read from TOML or set in
    Python are plain floats, which :func:`scale_lengths` leaves alone.

    Parameters
    ----------
    value : float
        Metres.
    human : float, optional
        The value on a human-sized rig (default: ``value``).
    """

    human: float

    def __new__(cls, value: float, human: float | None = None) -> SceneLength:
        obj = super().__new__(cls, value)
        obj.human = float(value if human is None else human)
        return obj

    def __reduce__(self) -> tuple:
        return (SceneLength, (float(self), self.human))


def scale_factor(extent_m: float) -> float:
    """The factor of the length defaults for a rig whose common view is ``extent_m`` across.

    Parameters
    ----------
    extent_m : float
        Geometric mean of the common view's box sides (metres).

    Returns
    -------
    float
        1 from :data:`HUMAN_EXTENT_M`, ``extent_m / REFERENCE_EXTENT_M`` up to
        :data:`SMALL_EXTENT_M`, geometric interpolation in between.
    """
    L = float(extent_m)
    if not np.isfinite(L) or L >= HUMAN_EXTENT_M:
        return 1.0
    if L <= SMALL_EXTENT_M:
        return max(L, 1e-12) / REFERENCE_EXTENT_M
    lo = math.log(SMALL_EXTENT_M / REFERENCE_EXTENT_M)  # log factor at SMALL_EXTENT_M
    w = math.log(L / SMALL_EXTENT_M) / math.log(HUMAN_EXTENT_M / SMALL_EXTENT_M)
    return math.exp(lo * (1.0 - w))


@dataclass(frozen=True)
class SceneScale:
    """The rig's length scale (:func:`scene_scale`).

    Attributes
    ----------
    factor : float
        Multiplies every length default (1 on human-sized rigs).
    extent_m : float
        Geometric mean of the box sides (metres).
    box : (2, 3) float ndarray
        The box it was measured on.
    source : str
        ``"common view"`` or ``"capture_volume"``.
    """

    factor: float
    extent_m: float
    box: np.ndarray
    source: str

    @property
    def human(self) -> bool:
        """True when the defaults are kept (factor 1)."""
        return self.factor == 1.0

    def summary(self) -> str:
        """One line: the extent, where it comes from, and the factor."""
        size = self.box[1] - self.box[0]
        kind = (
            f"human-sized (>= {HUMAN_EXTENT_M:g} m): lengths at their defaults"
            if self.human
            else f"lengths scaled by {self.factor:.4g} (extent / {REFERENCE_EXTENT_M:g} m below "
            f"{SMALL_EXTENT_M:g} m)"
        )
        return (
            f"scene scale: {self.source} {' x '.join(_fmt_length(s) for s in size)}, extent "
            f"{_fmt_length(self.extent_m)} (geometric mean), {kind}"
        )


def _fmt_length(m: float) -> str:
    from .rig_analysis import format_length  # the one length formatter

    return format_length(float(m))


_logged: set[object] = set()  # what was logged in this process (each once)


def scene_scale(
    rig: CameraRig,
    capture_volume: Any = None,
    *,
    log: bool = True,
) -> SceneScale:
    """The rig's length scale, from its common view or from a set capture volume.

    Parameters
    ----------
    rig : CameraRig
    capture_volume : ((3,), (3,)) sequence of float, optional
        ``[reconstruct] capture_volume`` when set; default the cameras' common view
        (:func:`~pointtraj.reconstruct.connectivity.common_view`, seeded: the same rig gives
        the same scale).
    log : bool
        Log the scale at INFO (once per rig and volume in a process).

    Returns
    -------
    SceneScale
    """
    if capture_volume is not None:
        box = np.asarray(capture_volume, float).reshape(2, 3)
        source = "capture_volume"
    else:
        from .reconstruct.connectivity import common_view

        box = common_view(rig).box
        source = "common view"
    size = np.maximum(box[1] - box[0], 1e-12)
    extent = float(np.exp(np.mean(np.log(size))))
    scale = SceneScale(scale_factor(extent), extent, box, source)
    key = (rig.C.round(9).tobytes(), box.round(12).tobytes())
    if log and key not in _logged:
        _logged.add(key)
        logger.info("%s", scale.summary())
    return scale


def scale_lengths(config: T, scale: SceneScale | float, where: str = "", *, log: bool = True) -> T:
    """``config`` with every length left at its default scaled to the rig.

    Every :class:`SceneLength` field (searched through nested dataclass configs) becomes its
    human-scale value times the factor; set values are kept. Idempotent.

    Parameters
    ----------
    config : dataclass instance
    scale : SceneScale or float
        The scale, or its factor.
    where : str
        How the log names the config (``"[reconstruct]"``).
    log : bool
        Log each derived value at INFO (when the factor is not 1).

    Returns
    -------
    The same type as ``config`` (``config`` itself when nothing changes).
    """
    factor = scale.factor if isinstance(scale, SceneScale) else float(scale)
    derived: list[str] = []
    out = _scaled(config, factor, where.strip("[]"), derived)
    if log and derived and factor != 1.0:
        message = (
            f"{where or type(config).__name__} lengths from the scene scale (x{factor:.4g}; "
            f"set a key to override): {', '.join(derived)}"
        )
        if message not in _logged:
            _logged.add(message)
            logger.info("%s", message)
    return out


def _scaled(config: T, factor: float, prefix: str, derived: list[str]) -> T:
    if not dataclasses.is_dataclass(config) or isinstance(config, type):
        return config
    changes: dict[str, Any] = {}
    for f in dataclasses.fields(config):
        value = getattr(config, f.name)
        name = f"{prefix}.{f.name}" if prefix else f.name
        if isinstance(value, SceneLength):
            new = SceneLength(value.human * factor, value.human)
            if float(new) != float(value):
                changes[f.name] = new
            derived.append(f"{name} = {_fmt_length(float(new))}")
        elif dataclasses.is_dataclass(value) and not isinstance(value, type):
            sub = _scaled(value, factor, name, derived)
            if sub is not value:
                changes[f.name] = sub
    return dataclasses.replace(config, **changes) if changes else config  # type: ignore[type-var]


def work_scene_scale(work: Any) -> SceneScale:
    """The length scale of a work folder's run: its capture's rig, and the capture volume that
    its reconstruction was given (``work.toml``).

    Parameters
    ----------
    work : path-like or WorkFolder

    Returns
    -------
    SceneScale
        Factor 1 (the defaults), without a log line, when ``work.toml`` records no capture.
    """
    from .rigio import load_rig
    from .workdir import WorkFolder

    wf = work if isinstance(work, WorkFolder) else WorkFolder(work)
    capture = wf.capture_path()
    if capture is None or not capture.is_dir():
        if capture is not None and ("missing", str(capture)) not in _logged:
            _logged.add(("missing", str(capture)))
            logger.warning(
                "scene scale: the capture %s that %s records is not there; lengths at their "
                "human-scale defaults",
                capture,
                wf.work_toml,
            )
        return SceneScale(1.0, float("nan"), np.full((2, 3), np.nan), "no capture")
    params = wf.run_identity().get("reconstruct")
    volume = params.get("capture_volume") if isinstance(params, dict) else None
    # The rig alone: opening the capture would read an image of every camera to check it.
    return scene_scale(load_rig(capture / "rig.toml", fmt="toml"), volume)
