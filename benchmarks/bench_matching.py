"""Benchmark: brute-force against epipolar-guided matching, all pairs against a few per camera.

Reconstructs one frame of a synthetic capture from scratch (matching, triangulation, view
expansion: one :meth:`pointtraj.reconstruct.track.Tracker.step`) with each matching setting
and reports the points, the time and the distance of the points to the ground-truth surface
(:func:`pointtraj.evaluate.groundtruth.frame_surface_errors` over every camera whose image a
point projects into).

Usage (the figures of ``docs/reconstruction.md``; each setting runs in its own process)::

    .venv/bin/pointtraj synth --preset paper69 --scene dribble --frames 30 --out /tmp/p69
    .venv/bin/python benchmarks/bench_matching.py /tmp/p69 --frame 0
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

SETTINGS = {
    "brute force, all pairs (default)": {},
    "brute force, 12 pairs per camera": {"max_pairs_per_camera": 12},
    "guided, all pairs": {"guided": True},
    "guided, 12 pairs per camera (pipelines/paper69.toml)": {
        "guided": True,
        "max_pairs_per_camera": 12,
    },
}


def run(capture: Path, frame: int, setting: dict) -> dict:
    """One setting: reconstruct ``frame`` from scratch and measure it."""
    from pointtraj.evaluate.groundtruth import frame_surface_errors
    from pointtraj.reconstruct.config import ReconstructConfig
    from pointtraj.reconstruct.matching import MatchingConfig
    from pointtraj.reconstruct.track import Tracker
    from pointtraj.session import Capture

    cap = Capture.open(capture)
    rig = cap.rig
    cfg = ReconstructConfig(
        max_pairs_per_camera=setting.get("max_pairs_per_camera", 0),
        matching=MatchingConfig(guided=setting.get("guided", False)),
    )
    images = [cap.read(n, frame) for n in rig.names]
    t0, c0 = time.perf_counter(), time.process_time()
    rec = Tracker(rig, cfg).step(frame, images)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    err = frame_surface_errors(capture, rig, frame, rec.xyz)
    err = err[np.isfinite(err)]
    return {
        "points": len(rec),
        "wall_s": round(wall, 1),
        "cpu_s": round(cpu, 1),
        "error_mm_p50_p75_p90": [round(1000 * v, 1) for v in np.percentile(err, [50, 75, 90])],
        "over_5cm": round(float(np.mean(err > 0.05)), 3),
        "views_mean": round(float(np.mean((rec.visibility > 12).sum(axis=1))), 2),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("capture", type=Path, help="synthetic capture (with gt/)")
    ap.add_argument("--frame", type=int, default=0)
    ap.add_argument("--child", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        print(json.dumps(run(args.capture, args.frame, SETTINGS[args.child])))
        return
    print("| setting | points | wall s | CPU s | error median / p75 / p90 mm | > 5 cm | views |")
    print("|---|---:|---:|---:|---|---:|---:|")
    for name in SETTINGS:
        cmd = [sys.executable, __file__, str(args.capture), "--frame", str(args.frame)]
        out = subprocess.run(cmd + ["--child", name], capture_output=True, text=True, check=True)
        r = json.loads(out.stdout.strip().splitlines()[-1])
        e = " / ".join(f"{v:g}" for v in r["error_mm_p50_p75_p90"])
        print(
            f"| {name} | {r['points']} | {r['wall_s']} | {r['cpu_s']} | {e} | "
            f"{r['over_5cm']:.3f} | {r['views_mean']} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
