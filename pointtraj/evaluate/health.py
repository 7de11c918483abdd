"""The health of a run: cheap checks that say when the figures of a report hide a failure (#17).

A reconstruction can fail quietly: a rig whose camera pairs the connectivity drops, points
seen by two cameras only (whose reprojection error is near 0 by construction, so it verifies
nothing), points under the floor, a labelling that puts almost nothing on the classes. Each
check here turns one such symptom into a figure and, past its threshold, a one-line warning.
:func:`check_health` gathers the figures of a work folder; :func:`health_warnings` compares
figures with :class:`HealthThresholds` (every threshold lives there). The report puts the
warnings at its top (``report/index.md``, ``metrics.json`` ``health.warnings``), the library
logs them, and ``pointtraj run`` / ``demo`` print them last.
"""

from __future__ import annotations

import logging
import math
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..rig_analysis import format_length
from ..scale import SceneLength

__all__ = [
    "HealthThresholds",
    "VIEW_BINS",
    "observed_views",
    "pair_counts",
    "known_floor",
    "floor_from_feet",
    "check_health",
    "health_warnings",
    "health_lines",
]

logger = logging.getLogger(__name__)

#: Buckets of observed views per point-frame: label -> (lowest, highest) view count. A point
#: seen by at most 2 cameras is triangulated exactly from them, so its reprojection error says
#: nothing about its accuracy.
VIEW_BINS = {"1": (0, 1), "2": (2, 2), "3": (3, 3), "4+": (4, 1 << 30)}

#: The view buckets whose reprojection error verifies nothing: one view, or two (near 0 by
#: construction).
UNVERIFIABLE_BINS = ("1", "2")

#: The paper's connectivity rule: cameras whose optical axes are more than this apart are
#: unlikely to match (its Section 5), so such pairs are not counted as dropped.
PAPER_MAX_ANGLE_DEG = 90.0

#: Point-frames per chunk of the passes over a store (bounded memory).
_CHUNK = 1 << 20

#: Classes whose last word is one of these stand on the floor (the body-parts recogniser's
#: ``left_foot``, ``right_foot``; not ``football``): where a rig names no floor, theirs is
#: estimated from them.
FOOT_WORDS = ("foot", "feet")
#: Foot point-frames a floor estimate needs.
MIN_FOOT_POINTS = 50
#: The floor is the bottom of the lowest height bin that holds at least this share of the
#: fullest bin of foot heights: soles crowd at the floor, wrong points labelled foot (a ghost
#: floor under the real one) spread thin over metres.
FOOT_DENSITY = 0.25


@dataclass(frozen=True)
class HealthThresholds:
    """Every threshold of the health checks, in one place.

    Attributes
    ----------
    two_view_share : float
        Warn when more than this share of the point-frames is observed in at most 2 cameras.
    pairs_kept_share : float
        Warn when the connectivity graph keeps less than this share of the camera pairs whose
        optical axes are within 90 degrees (the paper's rule; thinning by
        ``max_pairs_per_camera`` is a choice and is not counted).
    camera_share : float
        Warn about each camera that observes less than this share of the point-frames.
    below_floor_m : float
        A point-frame is below the floor when it lies more than this under it (metres; only where
        the floor is known, :func:`known_floor`).
    below_feet_m : float
        Where the floor is estimated from the labelled feet (a real rig,
        :func:`floor_from_feet`), a point-frame is below it when it lies more than this under
        it: the feet may stand on a platform (a treadmill, a stage, a step) above the room's
        floor. On the Pose2Sim demo, where the subject walks on a treadmill, 11.4 % of the
        point-frames lie more than 0.5 m under the feet and 5.8 % more than 1 m.
    below_floor_share : float
        Warn when more than this share of the point-frames is below the floor.
    labelled_share : float
        Warn when less than this share of the trajectories gets one of the label set's classes
        from the graph cut ...
    labelled_per_frame : float
        ... or fewer than this many labelled points per frame.
    validity_share : float
        Warn when predictive validity compares less than this share of the trajectories it
        sampled (with the most labelling cameras).
    points_per_frame : float
        Warn when the reconstruction has fewer points per frame.
    """

    two_view_share: float = 0.5
    pairs_kept_share: float = 0.5
    camera_share: float = 0.01
    below_floor_m: float = SceneLength(0.05)
    below_feet_m: float = SceneLength(0.5)
    below_floor_share: float = 0.01
    labelled_share: float = 0.05
    labelled_per_frame: float = 20.0
    validity_share: float = 0.2
    points_per_frame: float = 50.0


def observed_views(visibility: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Observed views per point-frame and per camera, in bounded memory.

    A view is observed where the stored visibility reaches
    :data:`pointtraj.trajectories.OBSERVED_MIN` (:func:`pointtraj.trajectories.view_counts`).

    Parameters
    ----------
    visibility : (P, C) uint8 ndarray

    Returns
    -------
    per_point : (P,) int64 ndarray
    per_camera : (C,) int64 ndarray
        Point-frames each camera observes.
    """
    from ..trajectories import OBSERVED_MIN, view_counts

    P, C = visibility.shape
    per_point = np.zeros(P, np.int64)
    per_camera = np.zeros(C, np.int64)
    for a in range(0, P, _CHUNK):
        v = visibility[a : a + _CHUNK]
        per_point[a : a + len(v)] = view_counts(v)
        per_camera += np.count_nonzero(v >= OBSERVED_MIN, axis=0)
    return per_point, per_camera


def pair_counts(rig, max_angle_deg: float) -> dict[str, int]:
    """The camera pairs that the reconstruction matches, against those it could.

    Parameters
    ----------
    rig : CameraRig
        The reconstructed cameras.
    max_angle_deg : float
        The reconstruction's ``max_angle_deg``.

    Returns
    -------
    dict
        ``all``: C (C - 1) / 2; ``near``: pairs whose optical axes are within 90 degrees (the
        paper's rule); ``kept``: the connectivity graph's pairs
        (:func:`pointtraj.reconstruct.track.select_edges` without the per-camera thinning).
    """
    from ..geometry import axis_angles
    from ..reconstruct.track import select_edges

    C = len(rig)
    i, j = np.triu_indices(C, 1)
    near = int((axis_angles(rig)[i, j] <= PAPER_MAX_ANGLE_DEG + 1e-9).sum()) if C > 1 else 0
    kept = len(select_edges(rig, max_angle_deg, 0)) if C > 1 else 0
    return {"all": int(len(i)), "near": near, "kept": kept}


def known_floor(capture: str | os.PathLike) -> tuple[np.ndarray, float] | None:
    """The floor of a capture, where it is known.

    Only synthetic captures (``gt/synth.toml``) have a known floor: their world is z-up with the
    floor at z = 0 (a scaled scene's, ``pointtraj synth --scale``, where its stage centre's
    scaling puts it). A real rig's files name no floor, so none is assumed.

    Returns
    -------
    (up (3,) float ndarray, height float) or None
    """
    path = Path(capture) / "gt" / "synth.toml"
    if not path.is_file():
        return None
    from ..config import load_toml
    from ..synth.presets import PRESETS
    from ..synth.scenes import STAGE_CENTRE

    doc = load_toml(path)
    preset = PRESETS.get(str(doc.get("preset")))
    if "scale" not in doc or preset is None:  # the scene where it was made: floor at z = 0
        return np.array([0.0, 0.0, 1.0]), 0.0
    scale = float(doc["scale"])
    return np.array([0.0, 0.0, 1.0]), float(preset.target[2] - scale * STAGE_CENTRE[2])


def floor_from_feet(trajectories, labels, up: np.ndarray, bin_m: float) -> float | None:
    """The floor's height along ``up``, estimated from the points labelled as feet.

    For real rigs, whose files name no floor (:func:`known_floor`). The heights of the
    point-frames of trajectories whose class name ends with a word of :data:`FOOT_WORDS` are binned by
    ``bin_m``; the floor is the bottom of the lowest bin holding at least
    :data:`FOOT_DENSITY` times the fullest. On the Pose2Sim demo (floor at z = 0) this gives
    0.0 m from 4,857 foot point-frames, where their 2nd percentile is -6 mm and, on the synthetic
    ``lab4`` with its ghost floor, -6.5 m; on the demo (floor at 0) 2.5 cm.

    Parameters
    ----------
    trajectories : Trajectories
    labels : TrajectoryLabels
        One label per trajectory, with ``class_names``.
    up : (3,) float ndarray
        Unit up direction.
    bin_m : float
        Bin width (metres).

    Returns
    -------
    float or None
        None without a foot class or with fewer than :data:`MIN_FOOT_POINTS` foot
        point-frames.
    """
    names = list(labels.class_names)
    feet = [k for k, n in enumerate(names) if re.split(r"[_\W]+", n.lower())[-1] in FOOT_WORDS]
    lab = np.asarray(labels.labels)
    if not feet or len(lab) != trajectories.num_trajectories:
        return None
    on_foot = np.isin(lab, feet)  # (M,)
    rows = np.flatnonzero(on_foot[trajectories.row_track])  # (F,) foot point-frames
    if len(rows) < MIN_FOOT_POINTS:
        return None
    h = trajectories.xyz[rows].astype(np.float64) @ np.asarray(up, np.float64)  # (F,)
    low = float(np.floor(h.min() / bin_m) * bin_m)
    counts = np.bincount(((h - low) / bin_m).astype(np.int64))
    first = int(np.flatnonzero(counts >= FOOT_DENSITY * counts.max())[0])
    return low + first * bin_m


def _share(num: float, den: float) -> float:
    return float(num) / float(den) if den else float("nan")


def check_health(
    trajectories,
    rig,
    capture: str | os.PathLike | None,
    reconstruct_config=None,
    labels=None,
    thresholds: HealthThresholds | None = None,
    up: np.ndarray | None = None,
) -> dict[str, Any]:
    """The health figures of a reconstruction (and its labels).

    Parameters
    ----------
    trajectories : Trajectories
    rig : CameraRig
        The store's cameras, in its order.
    capture : path-like, optional
        The capture (for :func:`known_floor`).
    reconstruct_config : ReconstructConfig, optional
        The reconstruction's parameters (``work.toml``); without them (ground-truth
        trajectories) the connectivity check is skipped.
    labels : TrajectoryLabels, optional
        The graph cut's labels.
    thresholds : HealthThresholds, optional
    up : (3,) float ndarray, optional
        The world's up direction (``capture.toml`` ``up``) for the floor under the labelled
        feet; default: detected from the cameras (:func:`pointtraj.geometry.detect_up`).

    Returns
    -------
    dict
        Flat ``health.*`` figures (see ``data_specs/report.md``).
    """
    th = thresholds or HealthThresholds()
    P = trajectories.num_point_frames
    frames = max(len(trajectories.occupied_frames), 1)
    m: dict[str, Any] = {
        "health.point_frames": P,
        "health.points_per_frame": P / frames,
    }
    n, seen = observed_views(trajectories.visibility)
    m["health.two_view_share"] = _share(int((n <= 2).sum()), P)
    m["health.camera_share.min"] = _share(int(seen.min()) if len(seen) else 0, P)
    m["health.cameras_unused"] = [
        name for name, s in zip(trajectories.camera_names, seen) if _share(s, P) < th.camera_share
    ]
    if reconstruct_config is not None:
        pairs = pair_counts(rig, reconstruct_config.max_angle_deg)
        m.update({f"health.pairs.{k}": v for k, v in pairs.items()})
    floor = known_floor(capture) if capture is not None else None
    source = "synthetic"
    if floor is None and labels is not None and P:  # a real rig: the floor under the feet
        from ..geometry import detect_up

        if up is None:
            up, how = detect_up(rig)
        else:
            up = np.asarray(up, np.float64) / np.linalg.norm(up)
            how = "capture.toml up"
        height = floor_from_feet(trajectories, labels, up, th.below_floor_m / 2)
        if height is not None:
            floor, source = (up, height), "feet"
            logger.info(
                "health: the floor from the labelled feet, at %s along up (%s)",
                format_length(height),
                how,
            )
    if floor is not None and P:
        up, height = floor
        margin = th.below_floor_m if source == "synthetic" else th.below_feet_m
        m["health.floor"] = source
        m["health.floor_height_m"] = float(height)
        m["health.below_floor_m"] = float(margin)
        below = 0
        for a in range(0, P, _CHUNK):
            h = trajectories.xyz[a : a + _CHUNK].astype(np.float64) @ up
            below += int((h < height - margin).sum())
        m["health.below_floor_share"] = _share(below, P)
    if labels is not None and len(labels.labels) == trajectories.num_trajectories:
        on = np.asarray(labels.labels) >= 0  # (M,)
        m["health.labelled_share"] = _share(int(on.sum()), trajectories.num_trajectories)
        m["health.labelled_per_frame"] = float(trajectories.lengths[on].sum()) / frames
    return m


def health_warnings(
    metrics: dict[str, Any], thresholds: HealthThresholds | None = None
) -> list[str]:
    """One line per check past its threshold.

    Parameters
    ----------
    metrics : dict
        The report's flat metrics: the ``health.*`` figures of :func:`check_health` and
        ``validity.support.share`` when predictive validity ran.
    thresholds : HealthThresholds, optional

    Returns
    -------
    list of str
        Empty when all is well.
    """
    th = thresholds or HealthThresholds()

    def get(key: str) -> float:
        v = metrics.get(key)
        return float(v) if isinstance(v, (int, float)) and math.isfinite(v) else float("nan")

    out = []
    ppf = get("health.points_per_frame")
    if ppf < th.points_per_frame:
        out.append(
            f"only {ppf:.0f} points per frame (fewer than {th.points_per_frame:g}): the "
            "reconstruction found little to track"
        )
    two = get("health.two_view_share")
    if two > th.two_view_share:
        out.append(
            f"{100 * two:.1f} % of the point-frames are seen by at most 2 cameras: their "
            "reprojection error is near 0 by construction and verifies nothing"
        )
    kept, near = get("health.pairs.kept"), get("health.pairs.near")
    if near > 0 and kept < th.pairs_kept_share * near:
        out.append(
            f"the connectivity kept {kept:.0f} of the {near:.0f} camera pairs within 90 degrees "
            "of each other: most of the rig is never matched (check the capture volume and "
            "`[reconstruct] max_angle_deg`)"
        )
    unused = metrics.get("health.cameras_unused") or []
    if unused:
        out.append(
            f"cameras {', '.join(unused)} observe under {100 * th.camera_share:g} % of the "
            "point-frames"
        )
    below = get("health.below_floor_share")
    if below > th.below_floor_share:
        feet = metrics.get("health.floor") == "feet"
        margin = get("health.below_floor_m")
        margin = margin if math.isfinite(margin) else th.below_floor_m
        where = (
            f" (the floor under the labelled feet, at {format_length(get('health.floor_height_m'))}"
            " along up): wrong matches, such as ghost surfaces on repeated texture"
            if feet
            else ""
        )
        out.append(
            f"{100 * below:.1f} % of the point-frames lie more than "
            f"{format_length(margin)} below the floor{where}"
        )
    share, per_frame = get("health.labelled_share"), get("health.labelled_per_frame")
    if share < th.labelled_share or per_frame < th.labelled_per_frame:
        out.append(
            f"few points on the labelled classes: {100 * share:.1f} % of the trajectories, "
            f"{per_frame:.0f} points per frame"
        )
    vshare = get("validity.support.share")
    if vshare < th.validity_share:
        out.append(
            f"predictive validity compares only {100 * vshare:.1f} % of the sampled "
            f"trajectories ({metrics.get('validity.support.point_frames')} point-frames): "
            "its figures rest on few points"
        )
    return out


def health_lines(metrics: dict[str, Any]) -> list[str]:
    """The health block for the end of ``pointtraj run`` / ``demo`` / ``evaluate``.

    Parameters
    ----------
    metrics : dict
        ``metrics.json`` of a report.

    Returns
    -------
    list of str
        ``health: no warnings``, or a count and one ``  warning: ...`` line each; empty for a
        report of an older version (no ``health.warnings``).
    """
    warnings = metrics.get("health.warnings")
    if warnings is None:
        return []
    if not warnings:
        return ["health: no warnings"]
    n = len(warnings)
    return [f"health: {n} warning{'s' if n > 1 else ''}"] + [f"  warning: {w}" for w in warnings]
