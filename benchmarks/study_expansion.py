"""Study: what view expansion does to tracking, from the same starting state.

Takes the live trajectories of one reconstructed frame (``WORK/state/<frame>.npz`` of a
``pointtraj reconstruct`` run on a synthetic capture) and tracks them for ``--frames`` more
frames twice, without and with view expansion (``ReconstructConfig.expand_views``), with no
new matching in between, so that both runs follow exactly the same points. Reported per
frame: how many of the starting points are still alive and how many cameras observe a point;
at the last frame, the distance of the points alive in both runs to the ground-truth surface
(:func:`pointtraj.evaluate.groundtruth.frame_surface_errors` over every camera whose image a
point projects into).

Usage (the figures of ``docs/reconstruction.md``)::

    .venv/bin/pointtraj synth --preset paper69 --scene dribble --frames 30 --out /tmp/p69
    .venv/bin/pointtraj reconstruct /tmp/p69 --out /tmp/p69_work --frames 0:8
    .venv/bin/python benchmarks/study_expansion.py /tmp/p69 /tmp/p69_work --start 7 --frames 5
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import numpy as np


def track_from(capture, work: Path, start: int, frames: int, expand: bool) -> dict:
    """Track the live points of ``start`` for ``frames`` frames; figures and the last frame."""
    from pointtraj.reconstruct.config import ReconstructConfig
    from pointtraj.reconstruct.flow import to_grey
    from pointtraj.reconstruct.stage import _load_state
    from pointtraj.reconstruct.track import Tracker, TrackState

    rig = capture.rig
    _, st = _load_state(work / "state" / f"{start:06d}.npz", len(rig))
    cfg = dataclasses.replace(ReconstructConfig(), expand_views=expand, match_every=10**6)
    tracker = Tracker(rig, cfg, state=st, first_frame=start)
    images = [capture.read(n, start) for n in rig.names]
    tracker.set_previous_images(images)
    out = {"expand_views": expand, "frames": []}
    t0 = time.perf_counter()
    if expand:  # expand the starting frame too, as the tracker does after every frame
        grey = [to_grey(im) for im in images]
        xyz, vis, _, pix = tracker._expand(
            grey, st.xyz, st.visibility, np.zeros(len(st)), st.pixels.astype(np.float64)
        )
        pix = np.where((vis.T > cfg.visibility_threshold)[..., None], pix, np.nan)
        tracker.state = TrackState(start, st.ids, xyz, vis, pix.astype(np.float32), st.next_id)
    start_ids = st.ids
    for t in range(start + 1, start + 1 + frames):
        rec = tracker.step(t, [capture.read(n, t) for n in rig.names])
        views = np.isfinite(tracker.state.pixels[..., 0]).sum(axis=0)
        out["frames"].append(
            {
                "frame": t,
                "alive_of_start": int(np.isin(rec.ids, start_ids).sum()),
                "views_per_point": round(float(views.mean()), 2),
            }
        )
    out["seconds"] = round(time.perf_counter() - t0, 1)
    out["start_points"] = int(len(start_ids))
    out["last"] = rec
    return out


def main() -> None:
    from pointtraj.evaluate.groundtruth import frame_surface_errors
    from pointtraj.session import Capture

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("capture", type=Path, help="synthetic capture (with gt/)")
    ap.add_argument("work", type=Path, help="reconstruction work folder with state/")
    ap.add_argument("--start", type=int, required=True, help="frame whose state to start from")
    ap.add_argument("--frames", type=int, default=5)
    ap.add_argument("--report", type=Path, help="write the figures as JSON")
    args = ap.parse_args()
    capture = Capture.open(args.capture)
    runs = [track_from(capture, args.work, args.start, args.frames, e) for e in (False, True)]
    last = [r.pop("last") for r in runs]
    common, ia, ib = np.intersect1d(last[0].ids, last[1].ids, return_indices=True)
    t_last = last[0].frame
    for run, rec, idx in zip(runs, last, (ia, ib)):
        # every camera whose image a point projects into: the runs' visibilities differ
        e = frame_surface_errors(args.capture, capture.rig, t_last, rec.xyz[idx])
        e = e[np.isfinite(e)]
        run["surface_error_mm_p50_p75_p90"] = [
            round(1000 * v, 2) for v in np.percentile(e, [50, 75, 90])
        ]
        run["common_points"] = int(common.size)
    for run in runs:
        print(json.dumps(run))
    if args.report:
        args.report.write_text(json.dumps(runs, indent=1))


if __name__ == "__main__":
    main()
