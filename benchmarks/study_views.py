"""Ground-truth audit of the views of reconstructed points (issue #20).

Usage (from the repository root)::

    .venv/bin/python -m pointtraj demo --out /tmp/demo
    .venv/bin/python benchmarks/study_views.py /tmp/demo/capture /tmp/demo/work \\
        [--frames 0:30] [--radius 0.03] [--depth-tol 0.01] [--json audit.json]

Reads ``WORK/trajectories.npz`` and the capture's ground truth, and prints the audit of
:func:`pointtraj.evaluate.views.view_audit` as JSON (the ``gt.views.*`` metrics and the
false-occlusion figures), then a short table. The definitions are those of
:mod:`pointtraj.evaluate.views`: a point-frame is on an actor when its nearest ground-truth
sample lies within ``--radius``; a view is truly visible when the camera's depth map sees that
sample (within ``--depth-tol``); it is observed when the store's visibility exceeds the tracker's
``visibility_threshold``.

The false-occlusion rate applies the tracker's occlusion test at its default settings
(``occlusion_test`` with ``occlusion_tolerance`` and ``occlusion_cell_px`` of
``ReconstructConfig()``: a fixed 5 cm unless ``occlusion_sigmas`` is set, 8 px cells) to each
frame's stored points, and reports the share
of the views it marks occluded that the ground truth sees (support: marked views of actor
points), and the share of truly occluded in-image views it marks (support: those views). The
tracker applies it to the frame's candidate points before it drops those seen by fewer than
``min_views`` cameras; the stored points are the survivors, so this is an approximation.

Baseline on the demo (``pointtraj demo``, 60 frames, ring8; defaults; 6 s): view recall 0.496
(69141 true views), precision 0.742 (46166 observed views), 3.01 true / 2.01 observed cameras per
actor point-frame (22976), >= 3 views observed on 0.8 % of the 18347 actor point-frames truly
seen by >= 3, 99.3 % of 28325 point-frames observed in exactly 2 cameras, median actor
trajectory 7 frames (1608) against a ground-truth visible run of 7 (10264 runs; 13 with the
stored flags), 3D error median / p90 8.2 / 24.3 mm with 2 views (22788), 3.4 / 7.7 mm with 3
(165), 2.6 / 6.4 mm with 4+ (23); the occlusion test marks 65130 views of actor points of which
7.7 % are truly visible, and marks 52.4 % of the 114667 truly occluded in-image views.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import time
from pathlib import Path


def occlusion_audit(capture: Path, traj, frames: range, radius: float, depth_tol: float) -> dict:
    """False-occlusion figures of the tracker's default occlusion test over ``frames``."""
    import numpy as np

    from pointtraj.evaluate.views import OcclusionAudit, false_occlusion_rate, frame_truth
    from pointtraj.reconstruct.config import ReconstructConfig
    from pointtraj.reconstruct.occlusion import occlusion_test
    from pointtraj.reconstruct.track import occlusion_tolerance
    from pointtraj.session import Capture
    from pointtraj.trajectories import dequantize_visibility

    cfg = ReconstructConfig()
    rig = Capture.open(capture).rig.subset(traj.camera_names)
    total = OcclusionAudit()
    for t in frames:
        rows = traj.frame_rows(t)
        if not len(rows):
            continue
        xyz = traj.xyz[rows].astype(np.float64)
        observed = dequantize_visibility(traj.visibility[rows]).T > cfg.visibility_threshold
        tol = occlusion_tolerance(cfg, rig, xyz, observed)
        occ = occlusion_test(rig, xyz, tol, cell_px=cfg.occlusion_cell_px)
        truth = frame_truth(capture, rig, t, depth_tol)
        total = total + false_occlusion_rate(
            capture, rig, t, xyz, occ, radius, depth_tol, truth=truth
        )
    return {
        "occlusion.depth_m": cfg.occlusion_depth_m,
        "occlusion.sigmas": cfg.occlusion_sigmas,
        "occlusion.cell_px": cfg.occlusion_cell_px,
        "occlusion.false_rate": total.false_rate,
        "occlusion.false_rate.support": total.marked,
        "occlusion.recall": total.recall,
        "occlusion.recall.support": total.occluded,
    }


def _pct(x: float) -> str:
    return "n/a" if not math.isfinite(x) else f"{100 * x:.1f} %"


def _mm(x: float) -> str:
    return "n/a" if not math.isfinite(x) else f"{1000 * x:.1f}"


def table(m: dict) -> str:
    """A short plain-text table of the audit's figures with their supports."""
    rows = [
        ("view recall", _pct(m["gt.views.recall"]), m["gt.views.recall.support"], "true views"),
        (
            "view precision",
            _pct(m["gt.views.precision"]),
            m["gt.views.precision.support"],
            "observed views",
        ),
        (
            "views per actor point-frame: true / observed",
            f"{m['gt.views.true_per_point']:.2f} / {m['gt.views.observed_per_point']:.2f}",
            m["gt.views.per_point.support"],
            "actor point-frames",
        ),
        (
            "actor share of live point-frames",
            _pct(m["gt.views.actor_share"]),
            m["gt.views.actor_share.support"],
            "live point-frames",
        ),
        (
            ">=3 views observed | >=3 true",
            _pct(m["gt.views.three_view_share"]),
            m["gt.views.three_view_share.support"],
            "actor point-frames",
        ),
        (
            ">=3 views true, of actor point-frames",
            _pct(m["gt.views.three_view_truth"]),
            m["gt.views.three_view_truth.support"],
            "actor point-frames",
        ),
        (
            "GT surface: >=3 cameras | >=2 (the rig allows)",
            _pct(m["gt.views.surface_three_view"]),
            m["gt.views.surface_three_view.support"],
            "sample-frames",
        ),
        (
            "exactly 2 views observed",
            _pct(m["gt.views.two_view_share"]),
            m["gt.views.two_view_share.support"],
            "live point-frames",
        ),
        (
            "median actor trajectory (frames)",
            f"{m['gt.views.trajectory_length.median']:.0f}",
            m["gt.views.trajectory_length.support"],
            "trajectories",
        ),
        (
            "median GT visible run, true (frames)",
            f"{m['gt.views.visible_run.median']:.0f}",
            m["gt.views.visible_run.support"],
            "runs",
        ),
        (
            "median GT visible run, stored flags",
            f"{m['gt.views.flag_run.median']:.0f}",
            m["gt.views.flag_run.support"],
            "runs",
        ),
        (
            "stored flags agree with true visibility",
            _pct(m["gt.views.flags_agreement"]),
            m["gt.views.flags_agreement.support"],
            "in-image sample views",
        ),
    ]
    for k in ("2", "3", "4+"):
        if f"gt.views.error_m.{k}.median" in m:
            rows.append(
                (
                    f"3D error, {k} views: median / p90 (mm)",
                    f"{_mm(m[f'gt.views.error_m.{k}.median'])} / "
                    f"{_mm(m[f'gt.views.error_m.{k}.p90'])}",
                    m[f"gt.views.error_m.{k}.support"],
                    "actor point-frames",
                )
            )
    if "occlusion.false_rate" in m:
        rows += [
            (
                "occlusion test: marked views truly visible",
                _pct(m["occlusion.false_rate"]),
                m["occlusion.false_rate.support"],
                "marked views",
            ),
            (
                "occlusion test: truly occluded views marked",
                _pct(m["occlusion.recall"]),
                m["occlusion.recall.support"],
                "occluded in-image views",
            ),
        ]
    w = max(len(r[0]) for r in rows)
    lines = [f"{'figure':<{w}}  {'value':>16}  support"]
    lines += [f"{a:<{w}}  {b:>16}  {c} {d}" for a, b, c, d in rows]
    return "\n".join(lines)


def main() -> None:
    """Parse the command line, run the audit, print JSON and the table."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("capture", type=Path)
    ap.add_argument("work", type=Path)
    ap.add_argument("--frames", default=None, help="A:B (B exclusive); default all")
    ap.add_argument("--radius", type=float, default=0.03)
    ap.add_argument("--depth-tol", type=float, default=0.01)
    ap.add_argument("--no-occlusion", action="store_true", help="skip the occlusion audit")
    ap.add_argument("--json", type=Path, default=None, help="also write the figures here")
    args = ap.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")

    from pointtraj.evaluate.views import view_audit
    from pointtraj.reconstruct.config import ReconstructConfig
    from pointtraj.trajectories import Trajectories
    from pointtraj.workdir import parse_frames

    traj = Trajectories.load(args.work / "trajectories.npz")
    frames = parse_frames(args.frames, traj.num_frames, "--frames")
    t0 = time.perf_counter()
    audit = view_audit(
        args.capture,
        traj,
        frames,
        radius=args.radius,
        depth_tol=args.depth_tol,
        visibility_threshold=ReconstructConfig().visibility_threshold,
    )
    metrics = audit.to_metrics()
    if not args.no_occlusion:
        metrics.update(occlusion_audit(args.capture, traj, frames, args.radius, args.depth_tol))
    metrics["seconds"] = time.perf_counter() - t0
    text = json.dumps(metrics, indent=1)
    print(text)
    if args.json is not None:
        args.json.write_text(text + "\n", encoding="utf-8")
    print()
    print(table(metrics))


if __name__ == "__main__":
    main()
