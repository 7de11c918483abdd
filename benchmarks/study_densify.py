"""Study: patch densification (``[reconstruct.densify]``) against the ground-truth surface.

Two measurements on a synthetic capture, on all its cameras or on ``--cameras`` (a subset such
as four cameras 62 degrees apart, like the Pose2Sim demo's rig):

1. **From ground-truth seeds.** A random ``--seed-fraction`` of the frame's ground-truth
   surface points that two or more of the cameras see are the seeds, observed at their true
   projections. :func:`pointtraj.reconstruct.densify.densify` grows new points from them; they
   are RANSAC-triangulated as the tracker does, and their distance to the ground-truth surface
   is measured (:func:`pointtraj.evaluate.groundtruth.frame_surface_errors`). This isolates the
   densifier from the matcher, for each setting of ``SETTINGS``.
2. **In the tracker** (``--track-frames N``): ``N`` frames reconstructed with densification
   off and on (everything else from ``--config``); points at the last frame, their surface
   error, and the CPU time.

Usage (the figures of ``docs/reconstruction.md``)::

    .venv/bin/pointtraj synth --preset paper69 --scene dribble --frames 30 --out /tmp/p69
    .venv/bin/python benchmarks/study_densify.py /tmp/p69 --frame 5 \\
        --cameras cam00,cam06,cam12,cam18
    .venv/bin/pointtraj synth --preset ring8 --scene dribble --frames 10 --out /tmp/ring8
    .venv/bin/python benchmarks/study_densify.py /tmp/ring8 --frame 5 --track-frames 6
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import numpy as np

SETTINGS = {
    "default": {},
    "no centre test (inner_ncc = -1)": {"inner_ncc": -1.0},
    "no veto (veto_ncc = -1)": {"veto_ncc": -1.0},
    "min_ncc 0.8, no centre test": {"min_ncc": 0.8, "inner_ncc": -1.0},
    "min_ncc 0.85": {"min_ncc": 0.85},
    "4 rounds": {"rounds": 4},
    "grid step 4 px": {"step_px": 4.0},
    "every partner (max_partners = 0)": {"max_partners": 0},
}


def _errors(capture: Path, rig, frame: int, xyz: np.ndarray) -> dict:
    from pointtraj.evaluate.groundtruth import frame_surface_errors

    err = frame_surface_errors(capture, rig, frame, xyz)
    err = err[np.isfinite(err)]
    if err.size == 0:
        return {"measured": 0}
    return {
        "measured": int(err.size),
        "error_mm_p50_p75_p90": [round(1000 * v, 1) for v in np.percentile(err, [50, 75, 90])],
        "over_2cm": round(float(np.mean(err > 0.02)), 3),
        "over_5cm": round(float(np.mean(err > 0.05)), 3),
    }


def ground_truth_seeds(capture: Path, rig, frame: int, fraction: float):
    """A seeded random ``fraction`` of the frame's ground-truth points that 2+ cameras see.

    Returns
    -------
    X : (N, 3) float64 ndarray
    pixels : (C, N, 2) float ndarray
        Their true projections, NaN in the cameras that do not see them.
    grey : list of C (H, W) uint8 ndarrays
        The frame's grey images.
    """
    from pointtraj.reconstruct.flow import to_grey
    from pointtraj.session import Capture
    from pointtraj.synth.groundtruth import load_ground_truth

    cap = Capture.open(capture)
    gt = load_ground_truth(capture)
    cols = [list(gt.camera_names).index(n) for n in rig.names]
    visible = gt.visible[:, frame][:, cols]  # (M, C)
    rng = np.random.default_rng(0)
    pick = (visible.sum(axis=1) >= 2) & (rng.random(len(visible)) < fraction)
    X = gt.xyz[pick, frame].astype(np.float64)
    pix = rig.project(X).pixels
    pix[~visible[pick].T] = np.nan
    return X, pix, [to_grey(cap.read(n, frame)) for n in rig.names]


def from_seeds(capture: Path, rig, frame: int, fraction: float, setting: dict) -> dict:
    """Part 1: grow from ground-truth seeds with one setting."""
    from pointtraj.reconstruct.densify import DensifyConfig, densify, prepare_images
    from pointtraj.reconstruct.triangulate import TriangulationConfig, triangulate_ransac

    X, pix, grey_u8 = ground_truth_seeds(capture, rig, frame, fraction)
    grey = prepare_images(rig, grey_u8)
    cfg = DensifyConfig(enabled=True, **setting)
    c0 = time.process_time()
    obs = densify(rig, grey, X, pix, pix, cfg)
    cpu = time.process_time() - c0
    tri = triangulate_ransac(rig, obs, TriangulationConfig(threshold_px=2.0))
    ok = tri.valid & (tri.mean_error <= 2.0)
    views = np.all(np.isfinite(obs[:, ok]), axis=2).sum(axis=0)
    return {
        "seeds": int(len(X)),
        "new_points": int(ok.sum()),
        "views_mean": round(float(views.mean()), 2) if views.size else 0.0,
        "cpu_s": round(cpu, 1),
        **_errors(capture, rig, frame, tri.points[ok]),
    }


def in_tracker(capture: Path, rig, config_path, last: int, frames: int, on: bool) -> dict:
    """Part 2: ``frames`` frames ending at ``last``, densification off or on."""
    from pointtraj.reconstruct.stage import with_texture_choices
    from pointtraj.reconstruct.track import Tracker
    from pointtraj.session import Capture
    from pointtraj.stages import load_reconstruct_config

    cap = Capture.open(capture)
    cfg = load_reconstruct_config(config_path)
    cfg = dataclasses.replace(cfg, densify=dataclasses.replace(cfg.densify, enabled=on))
    # the patch spacings the reconstruction would choose from the images (2 px when rendered)
    tracker = Tracker(rig, with_texture_choices(cfg, cap, last - frames + 1))
    c0 = time.process_time()
    for t in range(last - frames + 1, last + 1):
        rec = tracker.step(t, [cap.read(n, t) for n in rig.names])
    cpu = time.process_time() - c0
    return {
        "densify": on,
        "points": len(rec),
        "cpu_s": round(cpu, 1),
        "views_mean": round(float(np.mean((rec.visibility > 12).sum(axis=1))), 2),
        **_errors(capture, rig, last, rec.xyz.astype(np.float64)),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("capture", type=Path, help="synthetic capture (with gt/)")
    ap.add_argument("--frame", type=int, default=5)
    ap.add_argument("--cameras", help="comma-separated camera names (default: all)")
    ap.add_argument("--seed-fraction", type=float, default=0.1)
    ap.add_argument("--track-frames", type=int, default=0)
    ap.add_argument("--config", help="reconstruct TOML for part 2 (default: defaults)")
    args = ap.parse_args()
    from pointtraj.session import Capture

    rig = Capture.open(args.capture).rig
    if args.cameras:
        rig = rig.subset(args.cameras.split(","))
    print(f"rig: {', '.join(rig.names)}; frame {args.frame}")
    print(
        "\n| setting | seeds | new points | views | CPU s | error p50 / p75 / p90 mm | > 2 cm | > 5 cm |"
    )
    print("|---|---:|---:|---:|---:|---|---:|---:|")
    for name, setting in SETTINGS.items():
        r = from_seeds(args.capture, rig, args.frame, args.seed_fraction, setting)
        e = " / ".join(f"{v:g}" for v in r.get("error_mm_p50_p75_p90", []))
        print(
            f"| {name} | {r['seeds']} | {r['new_points']} | {r['views_mean']} | {r['cpu_s']} | "
            f"{e} | {r.get('over_2cm', '')} | {r.get('over_5cm', '')} |",
            flush=True,
        )
    if args.track_frames:
        print("\n| densify | points | views | CPU s | error p50 / p75 / p90 mm | > 2 cm | > 5 cm |")
        print("|---|---:|---:|---:|---|---:|---:|")
        for on in (False, True):
            r = in_tracker(args.capture, rig, args.config, args.frame, args.track_frames, on)
            e = " / ".join(f"{v:g}" for v in r.get("error_mm_p50_p75_p90", []))
            print(
                f"| {'on' if on else 'off'} | {r['points']} | {r['views_mean']} | {r['cpu_s']} | "
                f"{e} | {r.get('over_2cm', '')} | {r.get('over_5cm', '')} |",
                flush=True,
            )
            print(json.dumps(r), flush=True)


if __name__ == "__main__":
    main()
