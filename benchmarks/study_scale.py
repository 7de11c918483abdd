"""Study: a finished synthetic run's figures in units relative to the scene's scale (issue 17).

For each work folder of a pipeline run on a synthetic capture (``pointtraj run``: reconstruct,
semantics, label, evaluate), prints what ``docs/reconstruction.md`` ("Lengths that follow the
rig's scale") compares between a small rig, the same capture at human size and a human rig:
points per frame, trajectory lengths, views per point, the 3D error in metres, at human size
(divided by the scene's scale, ``gt/synth.toml``) and in pixels (divided by the median pixel
footprint at the preset's target), the share of point-frames more than 5 cm at human size off
the true surface (overall and for those seen by 3 cameras or more:
:func:`pointtraj.evaluate.groundtruth.frame_surface_errors`), and the label accuracies from the
report's ``metrics.json``.

Usage::

    pointtraj -v run n7.toml        # [synth] preset = "narrow7", frames = 12;
                                    # [semantics] recognizer = "simulated"
    .venv/bin/python benchmarks/study_scale.py WORK [WORK ...]
"""

from __future__ import annotations

import argparse
import json

import numpy as np


def study(work: str, frames: list[int] | None = None) -> list[str]:
    """The figures of one work folder (the surface distances over ``frames``, default all),
    as printable lines; without a report (``pointtraj reconstruct`` alone) only those."""
    from pointtraj.config import load_toml
    from pointtraj.evaluate.groundtruth import frame_surface_errors
    from pointtraj.session import Capture
    from pointtraj.synth.groundtruth import capture_scale
    from pointtraj.synth.presets import PRESETS, axes_meeting_point
    from pointtraj.trajectories import Trajectories
    from pointtraj.workdir import WorkFolder

    wf = WorkFolder(work)
    cap = wf.require_capture()
    rig = Capture.open(cap).rig
    s = capture_scale(cap)
    preset = str(load_toml(cap / "gt" / "synth.toml")["preset"])
    # a twin of a rig file (``pointtraj synth --rig``) looks where its cameras' axes meet
    target = np.asarray(PRESETS[preset].target if preset in PRESETS else axes_meeting_point(rig))
    foot = float(np.median(np.linalg.norm(rig.C - target, axis=1) / rig.K[:, 0, 0]))
    tr = Trajectories.load(wf.trajectories)
    per_frame = np.array([len(tr.frame_rows(t)) for t in range(tr.num_frames)])
    errors, views = [], []
    for t in range(tr.num_frames) if frames is None else frames:
        fs = tr.frame(t)
        if len(fs.xyz):
            errors.append(frame_surface_errors(cap, rig, t, fs.xyz) / s)  # at human size
            views.append((fs.visibility > 0.05).sum(axis=1))
    e, v = np.concatenate(errors), np.concatenate(views)
    ok = np.isfinite(e)
    many = ok & (v >= 3)
    two = ok & (v == 2)
    lines = [
        f"== {work}: scene scale {s:g}, pixel footprint {foot * 1e6:.3g} um",
        f"  trajectories {tr.num_trajectories}, median length {np.median(tr.lengths):.0f}; "
        f"points per frame mean {per_frame.mean():.0f} (first {per_frame[0]}, last "
        f"{per_frame[-1]})",
        f"  over {'all frames' if frames is None else f'frames {frames}'}: {len(e)} point-frames"
        f", > 5 cm (human size) off the surface {np.mean(e[ok] > 0.05):.3f}, median "
        f"{np.median(e[ok]) * 1e3:.2f} mm; two-view ones off {np.mean(e[two] > 0.05):.3f}; "
        f"seen by >= 3 cameras {np.mean(v >= 3):.3f}, of those off {np.mean(e[many] > 0.05):.3f}"
        f", median / p90 {np.median(e[many]) * 1e3:.2f} / "
        f"{np.percentile(e[many], 90) * 1e3:.1f} mm",
    ]
    if not (wf.report / "metrics.json").is_file():
        return lines
    m = json.loads((wf.report / "metrics.json").read_text(encoding="utf-8"))
    e50, e90 = m["gt.error_m.median"], m["gt.error_m.p90"]
    return lines + [
        f"  views per point observed {m['gt.views.observed_per_point']:.2f} (true "
        f"{m['gt.views.true_per_point']:.2f}), two-view share {m['gt.views.two_view_share']:.2f}"
        f", view recall {m['gt.views.recall']:.3f}, precision {m['gt.views.precision']:.3f}",
        f"  3D error median / p90 {e50 * 1e3:.4g} / {e90 * 1e3:.4g} mm; at human size "
        f"{e50 / s * 1e3:.3g} / {e90 / s * 1e3:.3g} mm; {e50 / foot:.2f} / {e90 / foot:.2f} px",
        f"  labels: graph cut {m['gt.accuracy.graphcut']:.3f}, view argmax "
        f"{m['gt.accuracy.view_argmax']:.3f}, average argmax {m['gt.accuracy.average_argmax']:.3f}",
    ]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("work", nargs="+", help="work folders of finished synthetic runs")
    ap.add_argument("--frames", type=int, nargs="+", help="frames of the surface distances")
    args = ap.parse_args()
    for work in args.work:
        print("\n".join(study(work, args.frames)))


if __name__ == "__main__":
    main()
