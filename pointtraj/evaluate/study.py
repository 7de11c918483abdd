"""``pointtraj evaluate WORK``: the paper's three studies and the ground-truth metrics of a work folder.

:func:`evaluate_work` gathers the inputs of :mod:`pointtraj.evaluate.metrics` and
:mod:`pointtraj.evaluate.validity` from a work folder (and its capture), and writes
``WORK/report/`` with :func:`pointtraj.evaluate.report.write_report`:

* **health** (first): cheap checks that warn when the figures below hide a failure
  (:mod:`pointtraj.evaluate.health`, issue #17);
* **summary**: trajectories, their lengths and density, reprojection errors by the number of
  observing cameras (two-view ones marked unverifiable);
* **ground truth** (synthetic captures only): 3D error against the rendered surface, and label
  accuracy (overall, per class, confusion) of the graph cut and of the argmax of each pooling;
* **views** (synthetic captures only): the cameras that keep each point against those that
  see it (:mod:`pointtraj.evaluate.views`, issue #20);
* **temporal consistency** of the semantic map (the paper's Table 1);
* **affinity effectiveness** (the paper's Figure 6): label disagreement of neighbour pairs by
  distance, all ε_s-neighbours against SE(3)-affinity neighbours;
* **predictive validity** (the paper's Figure 7): agreement with the recogniser in held-out
  cameras against the number of labelling cameras, view against average pooling, with the
  point-frames and trajectories it compared;
* **timing** of every stage (``WORK/timings.json``).

Every study is skipped, with a line in the report saying why, when its inputs are missing.
"""

from __future__ import annotations

import json
import logging
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import FileFormatError, ValidationError
from ..rig_analysis import format_length
from ..scale import SceneLength, scale_lengths, work_scene_scale
from ..workdir import WorkFolder, locked
from . import paper
from .report import (
    Section,
    plot_confusion,
    plot_disagreement,
    plot_temporal,
    plot_validity,
    temporal_table,
    write_report,
)

__all__ = ["EvaluateConfig", "evaluate_work", "affinity_effectiveness", "headline"]

logger = logging.getLogger(__name__)

#: The paper's lags of Table 1, seconds.
PAPER_SECONDS = (1, 3, 5, 7, 9, 11, 13, 15)
#: The ground-truth section says in bold when more than this share of the point-frames is off
#: the surface (``EvaluateConfig.off_surface_m``).
OFF_SURFACE_WARN = 0.10


@dataclass(frozen=True)
class EvaluateConfig:
    """Parameters of the evaluation (table ``[evaluate]`` of a pipeline).

    Attributes
    ----------
    validity_tracks : int
        Trajectories sampled for predictive validity (all when there are fewer).
    validity_frames : int
        Frames used for predictive validity, spread evenly over the capture (each costs one
        recogniser call per camera).
    validity_draws : int
        Random camera subsets per held-out camera and subset size.
    validity_poolings : tuple of str
        Poolings compared in the validity study (:data:`~pointtraj.semantics.pooling.POOLINGS`):
        by default the paper's two (``view``; ``average``, over all cameras in whose image the
        point falls), ours (``view_soft``) and the average over the visible cameras.
    affinity_radius : float
        Largest pair distance in the affinity study (m); the paper's Figure 6 goes to 1 m.
    affinity_draws : int
        Random partners drawn per trajectory in that ball (the paper's drop-out draws).
    affinity_threshold : float
        A pair counts as an SE(3)-affinity neighbour when ``A > affinity_threshold``.
    affinity_bin : float
        Width of the distance bins (m).
    off_surface_m : float
        A point-frame farther than this from the ground-truth surface (or with no surface near
        it at all) is off the surface: the report gives the share by number of observed views,
        so that wrong two-view matches, whose reprojection error is 0 by construction, show.
    seed : int
    """

    validity_tracks: int = 3000
    validity_frames: int = 30
    validity_draws: int = 3
    validity_poolings: tuple[str, ...] = ("view", "view_soft", "average", "average_visible")
    affinity_radius: float = SceneLength(1.0)
    affinity_draws: int = 16
    affinity_threshold: float = 0.5
    affinity_bin: float = SceneLength(0.1)
    off_surface_m: float = SceneLength(0.05)
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("validity_tracks", "validity_frames", "validity_draws"):
            if getattr(self, name) < 1:
                raise ValidationError(f"evaluate.{name} must be >= 1")
        from ..semantics.pooling import POOLINGS

        bad = [p for p in self.validity_poolings if p not in POOLINGS]
        if bad or not self.validity_poolings:
            raise ValidationError(
                f"evaluate.validity_poolings: unknown {bad[0] if bad else 'empty list'!r} "
                f"(valid: {', '.join(POOLINGS)})"
            )
        if self.affinity_draws < 1:
            raise ValidationError("evaluate.affinity_draws must be >= 1")
        if not 0 < self.affinity_bin <= self.affinity_radius:
            raise ValidationError("evaluate.affinity_bin must be in (0, affinity_radius]")
        if not 0 <= self.affinity_threshold < 1:
            raise ValidationError("evaluate.affinity_threshold must be in [0, 1)")
        if not self.off_surface_m > 0:
            raise ValidationError("evaluate.off_surface_m must be > 0")


def _tick(progress, label: str, total: int):
    """A ``step(n=1)`` callable that advances ``progress(label, done, total)``."""
    done = [0]

    def step(n: int = 1) -> None:
        done[0] += n
        if progress is not None:
            progress(label, done[0], total)

    return step


def _q(a: np.ndarray, p: float) -> float:
    return float(np.percentile(a, p)) if len(a) else float("nan")


def _fmt(x: float | None, digits: int = 3) -> str:
    return "n/a" if x is None or not math.isfinite(x) else f"{x:.{digits}f}"


def _mm(x: float | None) -> str:
    return _fmt(None if x is None else 1000 * x, 1)


# -- studies ------------------------------------------------------------------------------------
def affinity_effectiveness(
    trajectories,
    labels: np.ndarray,
    affinity_config=None,
    radius: float = 1.0,
    draws: int = 16,
    threshold: float = 0.5,
    bin_width: float = 0.1,
    seed: int = 0,
    executor=None,
) -> dict[str, Any]:
    """The paper's affinity study: label disagreement of neighbour pairs by distance.

    Pairs are drawn uniformly in a ``radius`` ball around every trajectory (the paper's random
    drop-out, :func:`pointtraj.affinity.candidate_pairs`); a pair's distance is its largest over
    the shared lifetime, so a pair in bin ``[d, d + bin_width)`` is an ε_s-neighbour for
    ``ε_s = d + bin_width``. Among all pairs of a bin (ε_s) and among those with SE(3) affinity
    ``A > threshold`` (same τ and error mode as the affinity stage), the fraction whose labels
    differ is reported.

    Parameters
    ----------
    trajectories : Trajectories
    labels : (M,) int ndarray
        Label per trajectory (negative: left out).
    affinity_config : AffinityConfig, optional
        ε, τ, mode and RANSAC settings of the local transforms (default: the stage's defaults).
    radius, draws, threshold, bin_width, seed
        As :class:`EvaluateConfig`'s ``affinity_*``.
    executor : Executor, optional
        Where the local rigid fits run (default: serially, here; the same on any executor).

    Returns
    -------
    dict
        ``bins`` (B + 1,) edges; ``eps_s`` and ``se3`` (B,) fractions (NaN for empty bins);
        ``eps_s_count`` and ``se3_count`` (B,) pairs; ``se3_recall`` (B,) the share of a bin's
        same-label pairs that the SE(3) test keeps (a test that keeps few pairs has a trivially
        low disagreement).
    """
    from ..affinity import (
        AffinityConfig,
        candidate_pairs,
        local_transforms,
        pair_errors,
        symmetric_affinity,
    )
    from .metrics import disagreement_by_distance

    cfg = affinity_config or AffinityConfig()
    rng = np.random.default_rng([seed, 0])
    tf = local_transforms(trajectories, cfg, rng, executor=executor)
    i, j, d = candidate_pairs(trajectories, radius, 0, draws, rng)
    labels = np.asarray(labels, np.int64)
    ok = (labels[i] >= 0) & (labels[j] >= 0)
    i, j, d = i[ok], j[ok], d[ok]
    A = symmetric_affinity(
        pair_errors(trajectories, tf, i, j, cfg.mode),
        pair_errors(trajectories, tf, j, i, cfg.mode),
        cfg.tau,
        cfg.symmetrize,
    )
    keep = np.nan_to_num(A) > threshold  # untestable pairs are not SE(3) neighbours
    bins = np.round(np.arange(0.0, radius + 1e-9, bin_width), 6)
    li, lj = labels[i], labels[j]
    eps_s, eps_count = disagreement_by_distance(d, li, lj, bins)
    se3, se3_count = disagreement_by_distance(d[keep], li[keep], lj[keep], bins)
    same = li == lj
    _, same_all = disagreement_by_distance(d[same], li[same], lj[same], bins)
    _, same_kept = disagreement_by_distance(d[same & keep], li[same & keep], lj[same & keep], bins)
    with np.errstate(invalid="ignore", divide="ignore"):
        recall = np.where(same_all > 0, same_kept / np.maximum(same_all, 1), np.nan)
    return {
        "bins": bins,
        "eps_s": eps_s,
        "eps_s_count": eps_count,
        "se3": se3,
        "se3_count": se3_count,
        "se3_recall": recall,
    }


def _longest_lag(smap) -> int:
    """Frames between the first and last sample of the longest sampled trajectory (-1: none)."""
    return int(np.diff(smap.sample_offsets).max(initial=0)) - 1


def _temporal_lags(smap, fps: float) -> list[tuple[str, int]]:
    """``(name, lag in frames)``: the paper's lags that the samples cover, else the longest ones."""
    longest = _longest_lag(smap)
    lags = [(f"{s}s", int(round(s * fps))) for s in PAPER_SECONDS if round(s * fps) <= longest]
    if not lags and longest >= 2:  # a short capture: half and all of its longest lifetime
        for n in sorted({longest // 2, longest}):
            lags.append((f"{n / fps:.2g}s", n))
    return lags


# -- the report ---------------------------------------------------------------------------------
def _load_optional(path: Path, loader, what: str, notes: list[str]):
    if not path.is_file():
        notes.append(f"No `{path.name}`: {what} skipped (run its stage first).")
        return None
    return loader(path)


def _check_classes(labels_toml: Path, made: list[tuple[Path, Any]]) -> None:
    """Refuse a semantic map or labels whose classes are not those of the capture's labels.toml.

    Parameters
    ----------
    labels_toml : pathlib.Path
        The capture's label set (nothing is checked without one).
    made : list of (path, SemanticMap or TrajectoryLabels or None)
        The loaded files (None: absent).
    """
    from ..labelset import LabelSet, check_class_names

    if not labels_toml.is_file():
        return
    names = LabelSet.load(labels_toml).names
    for path, obj in made:
        if obj is not None:
            check_class_names(labels_toml, names, path, obj.class_names)


def _summary_section(traj, metrics: dict) -> Section:
    from .health import UNVERIFIABLE_BINS, VIEW_BINS, observed_views

    lengths = traj.lengths
    frames = len(traj.occupied_frames)  # a reconstruction of frames A:B: only those count
    seconds = frames / traj.fps if traj.fps > 0 else float("nan")
    err = traj.reprojection_error
    finite = np.isfinite(err)
    views, _ = observed_views(traj.visibility)  # (P,)
    metrics.update(
        {
            "trajectories.count": traj.num_trajectories,
            "trajectories.point_frames": traj.num_point_frames,
            "trajectories.frames": frames,
            "trajectories.cameras": traj.num_cameras,
            "trajectories.per_second": traj.num_trajectories / seconds,
            "trajectories.length.mean": float(lengths.mean()) if len(lengths) else float("nan"),
            "trajectories.length.p10": _q(lengths, 10),
            "trajectories.length.median": _q(lengths, 50),
            "trajectories.length.p90": _q(lengths, 90),
            "trajectories.points_per_frame": traj.num_point_frames / max(frames, 1),
            "reprojection_px.median": _q(err[finite], 50),
            "reprojection_px.p90": _q(err[finite], 90),
        }
    )
    rows = []
    for name, (lo, hi) in VIEW_BINS.items():
        sel = (views >= lo) & (views <= hi)
        e = err[sel & finite]
        share = float(sel.mean()) if len(sel) else float("nan")
        metrics[f"trajectories.views.{name}.share"] = share
        metrics[f"reprojection_px.views.{name}.median"] = _q(e, 50)
        metrics[f"reprojection_px.views.{name}.p90"] = _q(e, 90)
        metrics[f"reprojection_px.views.{name}.support"] = int(sel.sum())
        label = "at most 1" if name == "1" else name
        note = {"1": " (unverifiable: one view)", "2": " (unverifiable: near 0 by construction)"}
        note = note.get(name, " (unverifiable)") if name in UNVERIFIABLE_BINS else ""
        rows.append(
            f"| {label}{note} | {int(sel.sum())} ({_fmt(100 * share, 1)} %) | "
            f"{_fmt(_q(e, 50), 2)} | {_fmt(_q(e, 90), 2)} |"
        )
    body = (
        f"{traj.num_trajectories} trajectories ({metrics['trajectories.per_second']:.0f} per "
        f"second), {traj.num_point_frames} point-frames over {frames} frames "
        f"({traj.fps:g} Hz) from {traj.num_cameras} cameras: "
        f"{metrics['trajectories.points_per_frame']:.0f} points per frame.\n\n"
        "| | p10 | median | p90 | mean |\n|---|---|---|---|---|\n"
        f"| trajectory length (frames) | {_fmt(metrics['trajectories.length.p10'], 0)} | "
        f"{_fmt(metrics['trajectories.length.median'], 0)} | "
        f"{_fmt(metrics['trajectories.length.p90'], 0)} | "
        f"{_fmt(metrics['trajectories.length.mean'], 1)} |\n\n"
        "Reprojection error by the number of cameras that observe the point-frame. A point "
        "seen by 2 cameras is triangulated exactly from them, so its error is near 0 whatever "
        "its accuracy, and one seen by 1 has nothing to check it: only the rows of 3 and more "
        "views verify anything.\n\n"
        "| observed views | point-frames | median (px) | p90 (px) |\n|---|---|---|---|\n"
        + "\n".join(rows)
        + "\n\nThe paper's trajectories are fragments too: they emerge and dissolve as points "
        "become visible and are lost (its Section 5)."
    )
    return Section("Trajectories", body)


def _error_by_views(
    err: np.ndarray, views: np.ndarray, off_m: float, metrics: dict
) -> tuple[list[str], float]:
    """Rows of the 3D-error table by observed views, and the share of all point-frames off the
    surface (farther than ``off_m``, or NaN: no surface near). ``err`` (P,) metres, ``views``
    (P,) observed views per point-frame; the figures go into ``metrics``."""
    from .health import UNVERIFIABLE_BINS, VIEW_BINS

    with np.errstate(invalid="ignore"):
        off = ~(err <= off_m)  # NaN (no surface near) counts as off
    rows = []
    for name, (lo, hi) in VIEW_BINS.items():
        sel = (views >= lo) & (views <= hi)
        e = err[sel & np.isfinite(err)]
        share = float(off[sel].mean()) if sel.any() else float("nan")
        metrics[f"gt.error_m.views.{name}.median"] = _q(e, 50)
        metrics[f"gt.error_m.views.{name}.p90"] = _q(e, 90)
        metrics[f"gt.error_m.views.{name}.support"] = int(sel.sum())
        metrics[f"gt.off_surface.views.{name}.share"] = share
        label = "at most 1" if name == "1" else name
        note = " (unverifiable by reprojection)" if name in UNVERIFIABLE_BINS else ""
        rows.append(
            f"| {label}{note} | {int(sel.sum())} | {_mm(_q(e, 50))} | {_mm(_q(e, 90))} | "
            f"{_fmt(100 * share, 1)} % |"
        )
    total = float(off.mean()) if len(off) else float("nan")
    metrics["gt.off_surface.share"] = total
    metrics["gt.off_surface_m"] = float(off_m)
    return rows, total


def _actor_error(err: np.ndarray, truth: np.ndarray, metrics: dict) -> str:
    """The 3D error of the point-frames on the figures and objects, as a report line.

    ``err`` (P,) metres (NaN: no surface near), ``truth`` (P,) the true label of each
    point-frame's trajectory (>= 0 a part; -1 background; -2 never seen). The floor and the
    room (the background) are measured by the figure above but are not what a user tracks;
    this is the figure on what is labelled, with its support. The figures go into ``metrics``.
    """
    on = truth >= 0
    e = err[on & np.isfinite(err)]
    median, p90, background = _q(e, 50), _q(e, 90), int((truth == -1).sum())
    metrics["gt.error_m.actors.median"] = median
    metrics["gt.error_m.actors.p90"] = p90
    metrics["gt.error_m.actors.support"] = int(len(e))
    metrics["gt.error_m.background.support"] = background
    if not len(e):
        return "No point-frame lies on a trajectory of the figures and objects."
    return (
        "On the figures and objects alone (the point-frames of trajectories whose true label "
        f"is a part; {int(on.sum())} of {len(err)}, {background} on the background): median "
        f"**{_mm(median)} mm**, 90th percentile **{_mm(p90)} mm**."
    )


def _ground_truth_section(
    capture: Path,
    traj,
    truth,
    source: str,
    smap,
    labels,
    folder: Path,
    metrics: dict,
    progress,
    off_surface_m: float,
    executor=None,
) -> Section:
    from ..session import Capture
    from .groundtruth import surface_errors
    from .health import observed_views
    from .metrics import label_accuracy

    rig = Capture.open(capture).rig.subset(traj.camera_names)
    step = _tick(progress, "evaluate: 3D error", traj.num_frames)
    err = surface_errors(capture, rig, traj, progress=step, executor=executor)
    views, _ = observed_views(traj.visibility)  # (P,) in the store's order
    rows = [traj.frame_rows(t) for t in range(traj.num_frames)]  # err is in frame order
    order = np.concatenate(rows) if rows else np.zeros(0, np.int64)
    views = views[order]
    view_rows, off_share = _error_by_views(err, views, off_surface_m, metrics)
    actor_line = _actor_error(err, truth[traj.row_track[order]], metrics)
    none = ~np.isfinite(err)  # no ground-truth surface near the point in any camera
    err = err[~none]
    metrics.update(
        {
            "gt.error_m.median": _q(err, 50),
            "gt.error_m.p90": _q(err, 90),
            "gt.error_m.support": int(len(err)),
            "gt.no_surface": int(none.sum()),
            "gt.no_surface.share": float(none.mean()) if len(none) else float("nan"),
        }
    )
    lines = [
        "3D error: the distance of every point-frame to the rendered ground-truth surface of "
        "its frame, the smallest over the cameras it projects into (in each: to the patch of "
        "the depth map's pixels on the surface where the point projects, among the 3x3 around "
        "it, never across a silhouette; to the nearest of the 3x3 pixels where that is closer): "
        f"median **{_mm(metrics['gt.error_m.median'])} mm**, 90th percentile "
        f"**{_mm(metrics['gt.error_m.p90'])} mm** over {len(err)} point-frames "
        "(the paper has no ground truth; our goals are 5 mm and 2 cm). "
        f"{int(none.sum())} point-frames ({_fmt(100 * metrics['gt.no_surface.share'], 2)} %) "
        "have no ground-truth surface in the 3x3 pixels around their projection in any "
        "camera: they are far from every surface, and counted here instead of in the "
        "percentiles.",
        "",
        f"By observed views, with the share of point-frames off the surface (more than "
        f"{format_length(off_surface_m)} from it, or with none near). A wrong two-view match "
        "has a reprojection error near 0 and can lie metres away: only this column shows it.",
        "",
        "| observed views | point-frames | median (mm) | p90 (mm) | off the surface |",
        "|---|---|---|---|---|",
        *view_rows,
        "",
        actor_line,
        "",
    ]
    if off_share > OFF_SURFACE_WARN:
        lines += [
            f"**{_fmt(100 * off_share, 1)} % of the point-frames are off the surface** (above "
            f"{_fmt(100 * OFF_SURFACE_WARN, 0)} %): look at the rows above for the views they "
            "have.",
            "",
        ]
    fg = truth >= 0
    names = list(smap.class_names) if smap is not None else list(labels.class_names)
    K = len(names)
    preds: dict[str, np.ndarray] = {}
    if labels is not None:
        preds["graphcut"] = labels.labels
    if smap is not None:
        for p in smap.poolings:
            preds[f"{p}_argmax"] = smap.argmax_labels(p)
    if not fg.any() or not preds:
        lines.append("No labelled trajectory on a ground-truth part: label accuracy skipped.")
        return Section("Ground truth", "\n".join(lines))
    how = (
        "each trajectory is a ground-truth surface point with its part's label"
        if source == "ground truth"
        else "a trajectory's true label is the majority of the ground-truth label maps at its "
        "visible projections"
    )
    lines += [
        f"Label accuracy over the {int(fg.sum())} trajectories on the figures and objects "
        f"({how}; {int((truth == -1).sum())} on the background and {int((truth == -2).sum())} "
        "never seen are left out):",
        "",
        "| labels | accuracy |",
        "|---|---|",
    ]
    acc: dict[str, Any] = {}
    for name, pred in preds.items():
        acc[name] = label_accuracy(pred[fg], truth[fg], K)
        metrics[f"gt.accuracy.{name}"] = acc[name].overall
        lines.append(f"| {name.replace('_', ' ')} | {100 * acc[name].overall:.1f} % |")
    lines += ["", "Per class (recall, %):", ""]
    cols = list(preds)
    lines.append("| class | trajectories | " + " | ".join(c.replace("_", " ") for c in cols) + " |")
    lines.append("|---|---|" + "---|" * len(cols))
    ref = acc[cols[0]]
    for k, n in enumerate(names):
        if ref.support[k] == 0:
            continue
        cells = [_fmt(100 * acc[c].per_class[k], 1) for c in cols]
        lines.append(f"| {n} | {int(ref.support[k])} | " + " | ".join(cells) + " |")
        metrics[f"gt.per_class.{cols[0]}.{n}"] = acc[cols[0]].per_class[k]
    figures = []
    name = cols[0]
    plot_confusion(acc[name].confusion, names, folder / "confusion.png", f"{name}: true vs label")
    figures.append("confusion.png")
    return Section("Ground truth", "\n".join(lines), figures)


#: Keys of the view audit (:mod:`pointtraj.evaluate.views`) that the report keeps.
VIEW_KEYS = (
    "recall",
    "precision",
    "true_per_point",
    "observed_per_point",
    "per_point",
    "three_view_share",
    "three_view_truth",
    "surface_three_view",
    "two_view_share",
    "trajectory_length.median",
    "trajectory_length",
    "visible_run.median",
    "visible_run",
    "radius_m",
    "depth_tol_m",
    "visibility_threshold",
)


def _views_section(capture: Path, traj, metrics: dict, progress) -> Section:
    """Issue #20's view audit: the cameras kept for each point against those that see it.

    Adds ``gt.views.<key>`` and ``gt.views.<key>.support`` for the keys of :data:`VIEW_KEYS`.
    """
    from ..reconstruct.config import ReconstructConfig
    from ..synth.groundtruth import capture_scale
    from .views import view_audit

    step = _tick(progress, "evaluate: view audit", traj.num_frames)
    k = capture_scale(capture)  # a scaled synthetic scene: its tolerances scale with it
    audit = view_audit(
        capture,
        traj,
        radius=0.03 * k,
        depth_tol=0.01 * k,
        visibility_threshold=ReconstructConfig().visibility_threshold,
        progress=step,
        errors=False,
    )
    full = audit.to_metrics()
    keep = {f"gt.views.{k}" for k in VIEW_KEYS} | {f"gt.views.{k}.support" for k in VIEW_KEYS}
    m = {k: v for k, v in full.items() if k in keep}
    metrics.update(m)
    body = (
        "Which cameras keep each point, against the cameras that see it (issue #20). A "
        f"point-frame is on an actor when its nearest ground-truth surface sample is within "
        f"{100 * audit.radius:.0f} cm; a view is truly visible when the camera's depth map sees "
        f"that sample (within {100 * audit.depth_tol:.0f} cm at its pixel), and observed when "
        f"the point's visibility there exceeds {audit.visibility_threshold:g}.\n\n"
        "| figure | value | support |\n|---|---|---|\n"
        f"| view recall (observed of truly visible views) | {_fmt(m['gt.views.recall'], 3)} | "
        f"{m['gt.views.recall.support']} views |\n"
        f"| view precision (truly visible of observed views) | "
        f"{_fmt(m['gt.views.precision'], 3)} | {m['gt.views.precision.support']} views |\n"
        f"| cameras per actor point-frame: true / observed | "
        f"{_fmt(m['gt.views.true_per_point'], 2)} / {_fmt(m['gt.views.observed_per_point'], 2)}"
        f" | {m['gt.views.per_point.support']} point-frames |\n"
        f"| observed in >= 3 cameras, of those truly visible in >= 3 | "
        f"{_fmt(100 * m['gt.views.three_view_share'], 1)} % | "
        f"{m['gt.views.three_view_share.support']} point-frames |\n"
        f"| truly visible in >= 3 cameras, of the actor point-frames | "
        f"{_fmt(100 * m['gt.views.three_view_truth'], 1)} % | "
        f"{m['gt.views.three_view_truth.support']} point-frames |\n"
        f"| what the rig allows: ground-truth surface in >= 3 cameras, of that in >= 2 | "
        f"{_fmt(100 * m['gt.views.surface_three_view'], 1)} % | "
        f"{m['gt.views.surface_three_view.support']} sample-frames |\n"
        f"| observed in exactly 2 cameras, of all point-frames | "
        f"{_fmt(100 * m['gt.views.two_view_share'], 1)} % | "
        f"{m['gt.views.two_view_share.support']} point-frames |\n"
        f"| median length of trajectories on the actors (frames) | "
        f"{_fmt(m['gt.views.trajectory_length.median'], 0)} | "
        f"{m['gt.views.trajectory_length.support']} trajectories |\n"
        f"| median ground-truth run visible in >= 2 cameras (frames) | "
        f"{_fmt(m['gt.views.visible_run.median'], 0)} | "
        f"{m['gt.views.visible_run.support']} runs |\n"
    )
    return Section("Views", body)


def _pooling_section(smap, labels, chosen: str, metrics: dict) -> Section:
    """Which pooling the labels use, and what each pooling of the semantic map pools over."""
    from ..semantics.pooling import POOLING_DESCRIPTIONS

    metrics["semantics.label_pooling"] = chosen
    metrics["semantics.poolings"] = list(smap.poolings)
    who = (
        "The labels (the graph cut) use"
        if labels is not None
        else "No labels yet; the semantic map's default (first) pooling is"
    )
    rows = ["| pooling | what it pools over |", "|---|---|"]
    for p in smap.poolings:
        rows.append(f"| {_pooling_cell(p, chosen)} | {POOLING_DESCRIPTIONS.get(p, p)} |")
    body = "\n".join(
        [
            f"{who} **{chosen}** pooling (`[label] pooling`). The semantic map "
            f"(`semantic_map.npz`, recogniser `{smap.recognizer}`, ε_e = {smap.eps_e:g}) holds "
            "these poolings; the tables below show each, the labels' in bold:",
            "",
            *rows,
        ]
    )
    return Section("Pooling", body)


def _temporal_section(
    smap, folder: Path, metrics: dict, labelled=None, chosen: str | None = None
) -> Section:
    """The paper's Table 1; over the labelled trajectories when ``labelled`` (M,) is given.

    Every pooling of the map is shown beside the paper's (its ``view`` and ``average`` are the
    paper's two; ``chosen``, the pooling the labels use, is marked), then whether view pooling
    stays above the paper's average baseline at every lag, and the order of the others.
    """
    fps = smap.fps
    lags = _temporal_lags(smap, fps)
    if not lags or not smap.samples:
        return Section(
            "Temporal consistency of the 3D semantic map",
            "The semantic map keeps no trajectory long enough for a lag (the paper's Table 1 "
            "needs at least 1 s).",
        )
    ours: dict[str, dict[int, tuple[float, float, int]]] = {}
    means: dict[str, dict[str, float]] = {}
    body_rows = ["| pooling | " + " | ".join(n for n, _ in lags) + " |"]
    body_rows.append("|---|" + "---|" * len(lags))
    for p in smap.samples:
        row = []
        ours[p], means[p] = {}, {}
        for name, lag in lags:
            m, s, n = smap.temporal_consistency(lag, p, labelled)
            metrics[f"temporal_nc.{p}.{name}"] = m
            metrics[f"temporal_nc.{p}.{name}.support"] = n
            means[p][name] = m
            if labelled is not None:
                metrics[f"temporal_nc_all.{p}.{name}"] = smap.temporal_consistency(lag, p)[0]
            row.append(f"{_fmt(m, 2)} ± {_fmt(s, 2)} (n={n})")
            if name.endswith("s") and name[:-1].isdigit():
                ours[p][int(name[:-1])] = (m, s, n)
        body_rows.append(f"| {_pooling_cell(p, chosen)} | " + " | ".join(row) + " |")
    who = "sampled trajectories"
    if labelled is not None:
        who = (
            "sampled trajectories the graph cut labels (the others, walls and floor, have "
            "confidences of noise only; over all of them: "
            + ", ".join(
                f"{p} {_fmt(metrics[f'temporal_nc_all.{p}.{name}'], 2)} at {name}"
                for p in smap.samples
                for name, _ in lags[:1]
            )
            + ")"
        )
    text = [
        "NC between a trajectory's pooled confidences at its first frame and a lag later, "
        f"averaged over the {who} that live that long (the paper's Table 1; n: trajectories).",
        "",
        *body_rows,
        "",
        *_temporal_verdicts(means, [n for n, _ in lags], metrics),
    ]
    figures = []
    paper_ours = {p: d for p, d in ours.items() if d}
    if paper_ours:
        text += [
            "Beside the paper's Table 1 (its average pooling is our `average`: over every camera "
            "in whose image the point falls):",
            "",
            temporal_table(paper_ours),
            "",
        ]
        plot_temporal(paper_ours, folder / "temporal.png")
        figures.append("temporal.png")
    else:
        text.append(
            f"This capture is {_longest_lag(smap) / smap.fps:.2g} s long, shorter than the paper's "
            "shortest lag (1 s); the paper's view pooling keeps 0.96 at 1 s and 0.79 at 15 s, "
            "its average pooling about 0.43."
        )
    return Section("Temporal consistency of the 3D semantic map", "\n".join(text), figures)


def _pooling_cell(p: str, chosen: str | None) -> str:
    """A pooling's name in a table, marked when it is the one the labels use."""
    return f"**{p}** (labels)" if p == chosen else p


def _temporal_verdicts(means: dict[str, dict[str, float]], lags: list[str], metrics: dict):
    """Lines: view against the paper's average baseline at every lag; the order of the others.

    Adds ``temporal_nc.view_minus_average.min`` (the smallest margin over the lags).
    """
    lines = []
    if "view" in means and "average" in means:
        gap = {n: means["view"][n] - means["average"][n] for n in lags}
        finite = {n: g for n, g in gap.items() if math.isfinite(g)}
        if finite:
            low = min(finite, key=finite.get)
            metrics["temporal_nc.view_minus_average.min"] = finite[low]
            below = [n for n, g in finite.items() if g <= 0]
            if not below:
                verdict = f"**yes**, by at least {finite[low]:.3f} (at {low})"
            elif len(below) == len(finite):
                verdict = f"**no**, below it at every lag, by up to {-finite[low]:.3f} (at {low})"
            else:
                verdict = (
                    f"**no**: not at {', '.join(below)}; below it by up to {-finite[low]:.3f} "
                    f"(at {low})"
                )
            lines.append(
                "View pooling above the paper's average baseline (`average`, all cameras in "
                f"whose image the point falls) at every lag: {verdict}."
            )
    trio = [p for p in ("view", "view_soft", "average_visible") if p in means]
    if len(trio) > 1:
        orders = []
        for n in lags:
            vals = {p: means[p][n] for p in trio if math.isfinite(means[p][n])}
            ranked = sorted(vals, key=lambda p: -vals[p])
            orders.append((n, " > ".join(f"{p} {_fmt(vals[p], 3)}" for p in ranked), tuple(ranked)))
        if orders:
            same = len({o[2] for o in orders}) == 1
            lines.append(
                "Order of "
                + ", ".join(f"`{p}`" for p in trio)
                + (
                    f" at every lag: {' > '.join(orders[0][2])} (at {orders[0][0]}: "
                    f"{orders[0][1]})."
                    if same
                    else " by lag: " + "; ".join(f"{n}: {o}" for n, o, _ in orders) + "."
                )
            )
    return [x for line in lines for x in (line, "")]


def _affinity_section(
    traj, labels_for_study, source: str, cfg, aff_cfg, folder, metrics, executor=None
):
    res = affinity_effectiveness(
        traj,
        labels_for_study,
        aff_cfg,
        radius=cfg.affinity_radius,
        draws=cfg.affinity_draws,
        threshold=cfg.affinity_threshold,
        bin_width=cfg.affinity_bin,
        seed=cfg.seed,
        executor=executor,
    )
    bins = res["bins"]
    names = [f"{100 * a:.0f}-{100 * b:.0f}" for a, b in zip(bins[:-1], bins[1:])]
    for n, e, s, r in zip(names, res["eps_s"], res["se3"], res["se3_recall"]):
        metrics[f"affinity.disagreement.eps_s.{n}cm"] = e
        metrics[f"affinity.disagreement.se3.{n}cm"] = s
        metrics[f"affinity.recall.se3.{n}cm"] = r
    head = "| distance (cm) | " + " | ".join(names) + " |"
    rows = [head, "|---|" + "---|" * len(names)]

    def cells(frac, count):
        return " | ".join(_fmt(f, 2) if c >= 10 else "-" for f, c in zip(frac, count))

    rows.append(f"| ε_s-neighbours | {cells(res['eps_s'], res['eps_s_count'])} |")
    rows.append(
        f"| SE(3) affinity > {cfg.affinity_threshold:g} | {cells(res['se3'], res['se3_count'])} |"
    )
    rows.append(
        "| SE(3): same-label pairs kept | "
        + " | ".join(_fmt(r, 2) for r in res["se3_recall"])
        + " |"
    )
    rows.append(
        "| pairs (ε_s / SE(3)) | "
        + " | ".join(f"{a}/{b}" for a, b in zip(res["eps_s_count"], res["se3_count"]))
        + " |"
    )
    plot_disagreement(
        bins,
        {
            "ε_s-neighbours": res["eps_s"],
            f"SE(3) affinity > {cfg.affinity_threshold:g}": res["se3"],
        },
        folder / "affinity.png",
    )
    body = "\n".join(
        [
            "The fraction of neighbour pairs whose labels differ, by their largest distance over "
            f"the shared lifetime ({source} labels; bins with fewer than 10 pairs show -).",
            "",
            *rows,
            "",
            f"Paper (Figure 6): {paper.AFFINITY_TEXT}",
        ]
    )
    return Section("Affinity effectiveness", body, ["affinity.png"])


def recorded_semantics_config(smap):
    """The semantics stage's configuration that a semantic map records: its recogniser, the
    recogniser's options and ε_e (what predictive validity runs again without a pipeline file).

    Parameters
    ----------
    smap : SemanticMap

    Returns
    -------
    SemanticsStageConfig
        Unscaled: apply the work folder's scene scale (:func:`~pointtraj.scale.scale_lengths`).
    """
    from ..stages import SemanticsStageConfig

    return SemanticsStageConfig(
        recognizer=smap.recognizer, options=dict(smap.recognizer_options), eps_e=smap.eps_e
    )


def _validity_stride(traj, cfg: EvaluateConfig) -> int:
    """Predictive validity samples every this many frames: ``cfg.validity_frames`` over the
    frames where the store has points (a reconstruction of frames A:B lives only there)."""
    return max(1, math.ceil(len(traj.occupied_frames) / cfg.validity_frames))


def validity_samples(
    capture, traj, rig, semantics_cfg, cfg: EvaluateConfig, progress=None, executor=None
):
    """The per-camera samples of predictive validity, as the report draws them.

    Parameters
    ----------
    capture : Capture
        The open capture.
    traj : Trajectories
    rig : CameraRig
        The store's cameras, in its order.
    semantics_cfg : SemanticsStageConfig
        The recogniser, ε_e and visibility the semantic map was made with.
    cfg : EvaluateConfig
        ``validity_tracks``, ``validity_frames`` and ``seed``.
    progress : callable, optional
        ``progress(label, done, total)``.
    executor : Executor, optional
        Where each sampled frame's images are recognised (default: serially, here).

    Returns
    -------
    CameraSamples
    """
    from ..stages import stage_recognizer_spec
    from .validity import CaptureRecognizer, collect_camera_samples

    spec = stage_recognizer_spec(semantics_cfg, capture)
    local = executor is None or executor.local
    recognizer = spec.make() if local else spec  # a worker makes its own, once
    stride = _validity_stride(traj, cfg)

    visibility = None
    if semantics_cfg.visibility == "geometric":  # the visibility the semantic map pooled with
        from ..semantics.semantic_map import geometric_visibility

        def visibility(xyz: np.ndarray, V: np.ndarray) -> np.ndarray:
            return geometric_visibility(rig, xyz, V, semantics_cfg)

    span = len(traj.occupied_frames)
    step = _tick(progress, "evaluate: predictive validity", math.ceil(span / stride))
    return collect_camera_samples(
        traj,
        rig,
        CaptureRecognizer(capture, rig.names, recognizer),
        len(recognizer.class_names),
        max_tracks=cfg.validity_tracks,
        frame_stride=stride,
        seed=cfg.seed,
        progress=step,
        visibility=visibility,
        executor=executor,
    )


def _validity_section(
    capture, traj, semantics_cfg, cfg, folder, metrics, progress, chosen=None, executor=None
):
    from ..session import Capture
    from .validity import camera_counts, predictive_validity

    cap = Capture.open(capture)
    rig = cap.rig.subset(traj.camera_names)
    if len(rig) < 2:
        return Section("Predictive validity", "Needs at least 2 cameras.")
    samples = validity_samples(cap, traj, rig, semantics_cfg, cfg, progress, executor)
    stride = _validity_stride(traj, cfg)
    counts = camera_counts(len(rig))
    support: dict[int, dict[str, int]] = {}
    res = predictive_validity(
        samples,
        semantics_cfg.eps_e,
        poolings=cfg.validity_poolings,
        counts=counts,
        draws=cfg.validity_draws,
        seed=cfg.seed,
        support=support,
    )
    rows = ["| cameras used | " + " | ".join(str(n) for n in counts) + " |"]
    rows.append("|---|" + "---|" * len(counts))
    for p, d in res.items():
        rows.append(
            f"| {_pooling_cell(p, chosen)} pooling | "
            + " | ".join(_fmt(d[n], 3) for n in counts)
            + " |"
        )
        for n in counts:
            metrics[f"validity.{p}.{n}cams"] = d[n]
    sampled_pf, sampled_tracks = len(samples.track), len(np.unique(samples.track))
    rows.append(
        "| point-frames compared | "
        + " | ".join(str(support[n]["point_frames"]) for n in counts)
        + " |"
    )
    rows.append(
        "| trajectories compared (%) | "
        + " | ".join(
            _fmt(100 * support[n]["trajectories"] / max(sampled_tracks, 1), 1) for n in counts
        )
        + " |"
    )
    top = support[counts[-1]]
    metrics.update(
        {
            "validity.support.point_frames": top["point_frames"],
            "validity.support.trajectories": top["trajectories"],
            "validity.support.comparisons": top["comparisons"],
            "validity.support.sampled_point_frames": sampled_pf,
            "validity.support.sampled_trajectories": sampled_tracks,
            "validity.support.share": top["trajectories"] / max(sampled_tracks, 1),
            "validity.support.all_trajectories": traj.num_trajectories,
        }
    )
    plot_validity(
        counts, {f"{p} pooling": [res[p][n] for n in counts] for p in res}, folder / "validity.png"
    )
    body = "\n".join(
        [
            "Each held-out camera in turn: label the trajectories (argmax of the pooled, "
            "time-averaged confidences) from n other cameras, project them into the held-out "
            "camera, and count how often the label agrees with the recogniser there "
            f"({sampled_pf} point-frames of {sampled_tracks} trajectories sampled, of "
            f"{traj.num_trajectories}; "
            f"{'every frame' if stride == 1 else f'one frame in {stride}'}, "
            f"{cfg.validity_draws} random camera subsets per size). "
            "No ground truth is used. A sample is compared only where the held-out camera sees "
            "the point and its recogniser finds a class there, and every pooling labels the "
            "trajectory (so every pooling rests on the same samples): the last rows say how "
            "many were, a figure on few of them says little. "
            f"With {counts[-1]} cameras: {top['point_frames']} point-frames of "
            f"{top['trajectories']} trajectories "
            f"(**{_fmt(100 * metrics['validity.support.share'], 1)} %** of those sampled).",
            "",
            *rows,
            "",
            f"Paper (Figure 7): {paper.VALIDITY_TEXT}",
        ]
    )
    return Section("Predictive validity", body, ["validity.png"])


def _reconstruct_config(wf: WorkFolder):
    """The reconstruction's parameters from ``work.toml`` (None: none recorded, or unreadable)."""
    from ..config import from_mapping
    from ..reconstruct.config import ReconstructConfig

    table = wf.read_toml().get("reconstruct")
    if not isinstance(table, dict):
        return None
    try:
        return from_mapping(ReconstructConfig, table, where=f"{wf.work_toml} [reconstruct]")
    except (ValueError, TypeError) as exc:  # a work folder of another version
        logger.info("health: connectivity check skipped (%s)", exc)
        return None


def _health_section(wf: WorkFolder, cap: Path, traj, labels, metrics: dict) -> Section:
    """The health block (:mod:`pointtraj.evaluate.health`): warnings first, then the figures."""
    from ..session import Capture
    from .health import HealthThresholds, check_health, health_warnings, known_floor

    th = scale_lengths(HealthThresholds(), work_scene_scale(wf), "[health]")
    capture = Capture.open(cap)
    rig = capture.rig.subset(traj.camera_names)
    rc = _reconstruct_config(wf)
    metrics.update(check_health(traj, rig, cap, rc, labels, th, up=capture.up))
    warnings = health_warnings(metrics, th)
    metrics["health.warnings"] = warnings
    for w in warnings:  # the CLI lists them at the end instead (it drops these records)
        logger.warning("health: %s", w, extra={"health_warning": True})
    m = metrics.get
    lines = (
        [f"- **warning**: {w}" for w in warnings]
        if warnings
        else ["No warnings: none of the checks below is past its threshold."]
    )
    rows = [
        "| check | value | warns when |",
        "|---|---|---|",
        f"| points per frame | {_fmt(m('health.points_per_frame'), 0)} | "
        f"< {th.points_per_frame:g} |",
        f"| point-frames seen by at most 2 cameras | "
        f"{_fmt(100 * m('health.two_view_share'), 1)} % | > {100 * th.two_view_share:g} % |",
    ]
    if "health.pairs.kept" in metrics:
        rows.append(
            f"| camera pairs matched, of those within 90 degrees (of all) | "
            f"{m('health.pairs.kept')} of {m('health.pairs.near')} ({m('health.pairs.all')}) | "
            f"< {100 * th.pairs_kept_share:g} % |"
        )
    else:
        rows.append("| camera pairs matched | n/a (no reconstruction parameters) | |")
    rows.append(
        f"| least-used camera: share of point-frames it observes | "
        f"{_fmt(100 * m('health.camera_share.min'), 1)} % | < {100 * th.camera_share:g} % |"
    )
    if "health.below_floor_share" in metrics:
        floor = (
            f"under the labelled feet: {format_length(m('health.floor_height_m'))}"
            if m("health.floor") == "feet"
            else "z = 0"
        )
        rows.append(
            f"| point-frames more than {format_length(m('health.below_floor_m'))} below the floor "
            f"({floor}) | {_fmt(100 * m('health.below_floor_share'), 2)} % | "
            f"> {100 * th.below_floor_share:g} % |"
        )
    elif known_floor(cap) is None:
        rows.append(
            "| points below the floor | n/a (the rig names no floor and no feet are labelled) | |"
        )
    if "health.labelled_share" in metrics:
        rows.append(
            f"| trajectories on a labelled class; labelled points per frame | "
            f"{_fmt(100 * m('health.labelled_share'), 1)} %; "
            f"{_fmt(m('health.labelled_per_frame'), 0)} | < {100 * th.labelled_share:g} %; "
            f"< {th.labelled_per_frame:g} |"
        )
    if "validity.support.share" in metrics:
        rows.append(
            f"| predictive validity: sampled trajectories compared | "
            f"{_fmt(100 * m('validity.support.share'), 1)} % | < {100 * th.validity_share:g} % |"
        )
    body = "\n".join(
        [
            *lines,
            "",
            "Cheap checks of what can go wrong unseen (thresholds: "
            "`pointtraj.evaluate.health.HealthThresholds`):",
            "",
            *rows,
        ]
    )
    return Section("Health", body)


def _timing_section(wf: WorkFolder, metrics: dict) -> Section:
    if not wf.timings.is_file():
        return Section("Timing", "No `timings.json` (the stages were run one by one).")
    try:
        timings = json.loads(wf.timings.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as exc:
        raise FileFormatError(wf.timings, f"unreadable ({exc})") from None
    rows = ["| stage | seconds |", "|---|---|"]
    for k, v in timings.items():
        metrics[f"timing.{k}_s"] = float(v)
        rows.append(f"| {k} | {float(v):.1f} |")
    return Section(
        "Timing", "Wall time of each stage's last run on this machine.\n\n" + "\n".join(rows)
    )


def _software_section() -> Section:
    """The library versions of the environment that wrote the report."""
    from ..versions import library_versions

    rows = ["| library | version |", "|---|---|"]
    rows += [f"| {k} | {v} |" for k, v in library_versions().items()]
    return Section(
        "Software",
        "The libraries of the environment that wrote this report. The results depend on their "
        "versions: another one can round a value differently, and the tracker's decisions and "
        "the figures follow. `scripts/constraints.txt` holds those that the documented figures "
        "were measured with.\n\n" + "\n".join(rows),
    )


@locked("pointtraj evaluate")
def evaluate_work(
    work: str | os.PathLike,
    config: EvaluateConfig | None = None,
    capture: str | os.PathLike | None = None,
    *,
    affinity_config=None,
    semantics_config=None,
    title: str | None = None,
    progress=None,
    executor=None,
) -> dict[str, Any]:
    """Evaluate a work folder and write ``WORK/report/`` (``index.md``, PNG plots, ``metrics.json``).

    Parameters
    ----------
    work : path-like
        A work folder with at least ``trajectories.npz``.
    config : EvaluateConfig, optional
    capture : path-like, optional
        Default: the capture that ``work.toml`` records.
    affinity_config : AffinityConfig, optional
        Local-transform settings of the affinity study (default: those in ``affinity.npz``,
        else the defaults).
    semantics_config : SemanticsStageConfig, optional
        Recogniser of the validity study (default: the one ``semantic_map.npz`` names).
    title : str, optional
    progress : callable, optional
        ``progress(label, done, total)``.
    executor : Executor, optional
        Where the per-frame work of the 3D error and of predictive validity's recognition, and
        the affinity study's local rigid fits, run (default: serially, here). The figures are
        the same on any executor.

    Returns
    -------
    dict
        The flat metrics written to ``metrics.json`` (keys as ``data_specs/report.md``).

    Raises
    ------
    FileFormatError
        If ``trajectories.npz`` is missing or an input is malformed.
    """
    from ..affinity import AffinityConfig
    from ..labelfile import load_labels
    from ..semantics.semantic_map import SemanticMap
    from ..session import Capture
    from ..trajectories import Trajectories
    from .groundtruth import has_ground_truth, true_labels

    wf = WorkFolder(work)
    if not wf.trajectories.is_file():
        raise FileFormatError(wf.trajectories, "no such file (run `pointtraj reconstruct` first)")
    scale = work_scene_scale(wf)
    cfg = scale_lengths(config or EvaluateConfig(), scale, "[evaluate]")
    cap = wf.require_capture(capture)
    folder = wf.report
    folder.mkdir(parents=True, exist_ok=True)
    traj = Trajectories.load(wf.trajectories)
    traj.check_cameras(Capture.open(cap), wf.trajectories)
    notes: list[str] = []
    smap = _load_optional(wf.semantic_map, SemanticMap.load, "semantic-map studies", notes)
    labels = _load_optional(wf.labels, load_labels, "graph-cut accuracy", notes)
    _check_classes(Path(cap) / "labels.toml", [(wf.semantic_map, smap), (wf.labels, labels)])
    for name, obj in (("semantic_map.npz", smap), ("labels.npz", labels)):
        n = None if obj is None else (obj.num_trajectories if name[0] == "s" else len(obj))
        if n is not None and n != traj.num_trajectories:
            raise FileFormatError(
                wf.path / name, f"has {n} trajectories, trajectories.npz {traj.num_trajectories}"
            )
    metrics: dict[str, Any] = {}
    sections = [_summary_section(traj, metrics)]
    gt = has_ground_truth(cap)
    truth, source = None, ""
    if gt:
        step = _tick(progress, "evaluate: true labels", traj.num_frames)
        truth, source = true_labels(cap, traj, progress=step)
    if source == "ground truth":
        notes.append(
            "The trajectories are the capture's ground-truth trajectories (pipeline key "
            '`trajectories = "ground_truth"`), not reconstructed ones: the figures measure the '
            "semantic map, the affinity and the labelling alone."
        )
    if gt and (smap is not None or labels is not None):
        sections.append(
            _ground_truth_section(
                cap,
                traj,
                truth,
                source,
                smap,
                labels,
                folder,
                metrics,
                progress,
                cfg.off_surface_m,
                executor,
            )
        )
    elif not gt:
        notes.append(
            "The capture has no ground truth (a real capture): ground-truth metrics skipped."
        )
    if labels is not None:  # people as instances (pointtraj.evaluate.people)
        section = _people(cap, traj, labels, (truth, source) if gt else None, metrics)
        if section is not None:
            sections.append(section)
    if gt:
        sections.append(_views_section(cap, traj, metrics, progress))
    chosen = None
    if smap is not None:
        chosen = labels.pooling if labels is not None else smap.poolings[0]
        sections.insert(1, _pooling_section(smap, labels, chosen, metrics))
        labelled = None
        if labels is not None and len(labels.labels) == smap.num_trajectories:
            labelled = labels.labels >= 0
        sections.append(_temporal_section(smap, folder, metrics, labelled, chosen))
    # Affinity study: ground-truth labels where there are some, else the graph cut's.
    study_labels, study_source = None, ""
    if truth is not None:
        study_labels, study_source = truth, "ground-truth"
    elif labels is not None:
        study_labels, study_source = labels.labels, "graph-cut"
    if study_labels is not None and traj.num_trajectories > 1:
        if affinity_config is None and wf.affinity.is_file():
            from ..affinity import load_affinity
            from ..config import from_mapping

            params = load_affinity(wf.affinity).params or {}
            try:
                affinity_config = from_mapping(AffinityConfig, dict(params), where="affinity.npz")
            except (ValueError, TypeError):
                affinity_config = None
        sections.append(
            _affinity_section(
                traj,
                study_labels,
                study_source,
                cfg,
                affinity_config or scale_lengths(AffinityConfig(), scale, "[affinity]"),
                folder,
                metrics,
                executor,
            )
        )
    if smap is not None:
        if semantics_config is None:
            semantics_config = recorded_semantics_config(smap)
        semantics_config = scale_lengths(semantics_config, scale, "[semantics]")
        try:
            sections.append(
                _validity_section(
                    cap, traj, semantics_config, cfg, folder, metrics, progress, chosen, executor
                )
            )
        except ValidationError as exc:
            notes.append(f"Predictive validity skipped: {exc}")
    sections.append(_timing_section(wf, metrics))
    sections.append(_software_section())
    sections.insert(0, _health_section(wf, Path(cap), traj, labels, metrics))
    if notes:
        sections.insert(2, Section("Notes", "\n".join(f"- {n}" for n in notes)))
    write_report(folder, title or f"pointtraj report: {wf.path.name}", sections, metrics)
    logger.info("wrote %s", folder / "index.md")
    return metrics


def _people(cap, traj, labels, truth, metrics: dict) -> Section | None:
    """The "People" section (:func:`pointtraj.evaluate.people.people_section`)."""
    from ..instances import person_classes
    from ..labelset import LabelSet
    from .groundtruth import true_instances
    from .people import people_section

    toml = Path(cap) / "labels.toml"
    kinds = LabelSet.load(toml).kinds if toml.is_file() else None
    people = person_classes(labels.class_names, kinds)
    persons = None if truth is None else true_instances(cap, traj, truth=truth)[0]
    return people_section(labels, people, persons, metrics)


#: The poolings of the headline, in its order, with the names it gives them.
HEADLINE_NAMES = {
    "view": "view pooling",
    "average": "average pooling over all cameras (the paper's)",
    "average_visible": "average pooling over visible cameras",
}


def headline(metrics: dict[str, Any]) -> list[str]:
    """A few lines of the report's main figures, for the end of ``pointtraj demo``.

    Parameters
    ----------
    metrics : dict
        The flat metrics of :func:`evaluate_work` (or ``metrics.json``).

    Returns
    -------
    list of str
    """
    m = metrics.get
    out = []
    if m("trajectories.count") is not None:
        out.append(
            f"trajectories: {m('trajectories.count')} "
            f"(median length {_fmt(m('trajectories.length.median'), 0)} frames)"
        )
    if m("gt.error_m.median") is not None:
        none = m("gt.no_surface")
        out.append(
            f"3D error vs ground truth: median {_mm(m('gt.error_m.median'))} mm, "
            f"p90 {_mm(m('gt.error_m.p90'))} mm"
            + (f" ({none} point-frames with no surface near, left out)" if none else "")
            + (
                f"; on the figures and objects {_mm(m('gt.error_m.actors.median'))} / "
                f"{_mm(m('gt.error_m.actors.p90'))} mm"
                if m("gt.error_m.actors.support")
                else ""
            )
            + (
                f"; {_fmt(100 * m('gt.off_surface.share'), 1)} % of point-frames off the "
                f"surface (> {format_length(m('gt.off_surface_m'))})"
                if m("gt.off_surface.share") is not None
                else ""
            )
        )
    acc = [
        f"{name} {_fmt(100 * m(f'gt.accuracy.{key}'), 1)} %"
        for key, name in (
            ("graphcut", "graph cut"),
            *((f"{p}_argmax", f"argmax {HEADLINE_NAMES[p]}") for p in HEADLINE_NAMES),
        )
        if m(f"gt.accuracy.{key}") is not None
    ]
    if m("semantics.label_pooling") is not None:
        out.append(f"labels from: {m('semantics.label_pooling')} pooling")
    if acc:
        out.append("label accuracy: " + ", ".join(acc))
    for p, name in HEADLINE_NAMES.items():
        nc = sorted(
            (
                (k.split(".", 2)[2], v)
                for k, v in metrics.items()
                if k.startswith(f"temporal_nc.{p}.") and not k.endswith(".support")
            ),
            key=lambda item: float(item[0].rstrip("s")),  # metrics.json sorts 11s before 1s
        )
        if nc:
            out.append(
                f"temporal consistency, {name}: "
                + ", ".join(f"{_fmt(v, 2)} at {lag}" for lag, v in nc)
            )
    counts = sorted(
        {
            int(k.rsplit(".", 1)[1][:-4])
            for k in metrics
            if k.startswith("validity.") and k.endswith("cams")
        }
    )
    if counts:
        top = counts[-1]
        support = ""
        if m("validity.support.point_frames") is not None:
            support = (
                f" (on {m('validity.support.point_frames')} point-frames, "
                f"{_fmt(100 * m('validity.support.share'), 0)} % of the sampled trajectories)"
            )
        out.append(
            f"predictive validity with {top} cameras: "
            + ", ".join(
                f"{name} {_fmt(m(f'validity.{p}.{top}cams'), 2)}"
                for p, name in HEADLINE_NAMES.items()
                if f"validity.{p}.{top}cams" in metrics
            )
            + support
        )
    return out
