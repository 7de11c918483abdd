"""Study: which reconstructed points lie off the true surface, by view count (issues 17, 20).

Runs the tracker over the first frames of a synthetic capture with a ``[reconstruct]`` config
(the rig-derived defaults without one), and measures every point-frame against the ground
truth (:func:`pointtraj.evaluate.groundtruth.frame_surface_errors`). A point-frame is off the
surface when it lies more than ``--off`` (5 cm at human size; divided by the scene's scale,
``gt/synth.toml``) from it, or has no surface near it at all. Prints one JSON line per run and
a summary: point-frames, the share off the surface overall and for those observed by 2 and by
3 or more cameras, and for those on the figures and objects (where every observing camera's
ground-truth label map has a part at the point's pixel) and on the background (the floor),
the point-frames on the surface, their median error, and the CPU time.

With ``--draw CAM:FRAME:PATH`` the points that camera observes at that frame are drawn on
its image: green on the surface, red off it; large dots are seen by 3 or more cameras.

Usage::

    pointtraj synth --preset lab4 --scene dribble --frames 6 --out /tmp/lab4
    .venv/bin/python benchmarks/study_off_surface.py /tmp/lab4 --frames 6
    .venv/bin/python benchmarks/study_off_surface.py /tmp/lab4 --frames 6 --config gms6.toml \\
        --draw 0:5:/tmp/lab4_cam0_f5.png

``docs/reconstruction.md`` ("Ghost surfaces on repeated texture") has the figures.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np


def _draw(capture, rig, t: int, cam: int, xyz, views, observed, off, path: str) -> None:
    """The points ``cam`` observes at frame ``t`` on its image (green on the surface, red
    off it; large where seen by 3 or more cameras), scaled to at most 720 px."""
    import cv2

    from pointtraj.session import Capture

    image = Capture.open(capture).read(rig.names[cam], t)[..., ::-1].copy()  # BGR
    pix = rig.project(xyz).pixels[cam]
    for (u, v), o, k in zip(pix[observed], off[observed], views[observed], strict=True):
        if np.isfinite(u) and np.isfinite(v):
            colour = (0, 0, 255) if o else (0, 255, 0)
            cv2.circle(image, (int(u), int(v)), 4 if k >= 3 else 2, colour, -1)
    s = min(1.0, 720 / max(image.shape[:2]))
    cv2.imwrite(path, cv2.resize(image, None, fx=s, fy=s, interpolation=cv2.INTER_AREA))


def _on_actor(capture, rig, t: int, xyz: np.ndarray, observed: np.ndarray) -> np.ndarray:
    """(N,) bool: every camera observing the point has a figure's or object's part at its
    pixel in the ground-truth label map (-1 is the background)."""
    from pointtraj.synth.groundtruth import load_label_map

    proj = rig.project(xyz)
    actor = observed.any(axis=1)
    for c, cam in enumerate(rig):
        sel = np.flatnonzero(observed[:, c] & proj.in_image[c])
        if sel.size:
            labels = load_label_map(capture, cam.name, t)
            H, W = labels.shape
            u = np.clip(np.rint(proj.pixels[c, sel, 0]).astype(np.int64), 0, W - 1)
            v = np.clip(np.rint(proj.pixels[c, sel, 1]).astype(np.int64), 0, H - 1)
            actor[sel] &= labels[v, u] >= 0
    return actor


def study(capture: str, frames: int, config: str | None, off_m: float, draw: str | None) -> dict:
    """Track ``frames`` frames of ``capture`` and measure them (see the module's docstring)."""
    from pointtraj.evaluate.groundtruth import frame_surface_errors
    from pointtraj.reconstruct.stage import with_texture_choices
    from pointtraj.reconstruct.track import Tracker
    from pointtraj.session import Capture
    from pointtraj.stages import load_reconstruct_config
    from pointtraj.synth.groundtruth import capture_scale
    from pointtraj.trajectories import OBSERVED_MIN

    cap = Capture.open(capture)
    rig = cap.rig
    scale = capture_scale(capture)
    # the patch spacings the reconstruction would choose from the images (2 px when rendered)
    tracker = Tracker(rig, with_texture_choices(load_reconstruct_config(config), cap, 0))
    want = tuple(int(x) for x in draw.split(":")[:2]) if draw else None
    counts = dict.fromkeys(("n", "off", "n2", "off2", "n3", "off3", "na", "offa", "nb", "offb"), 0)
    on_surface = []
    cpu = 0.0
    for t in range(frames):
        c0 = time.process_time()
        rec = tracker.step(t, [cap.read(name, t) for name in rig.names])
        cpu += time.process_time() - c0
        xyz = rec.xyz.astype(np.float64)
        err = frame_surface_errors(capture, rig, t, xyz) / scale  # (N,) at human size
        observed = rec.visibility >= OBSERVED_MIN  # (N, C)
        views = observed.sum(axis=1)
        with np.errstate(invalid="ignore"):
            off = ~(err <= off_m)  # NaN: no surface near
        counts["n"] += len(err)
        counts["off"] += int(off.sum())
        counts["n2"] += int((views == 2).sum())
        counts["off2"] += int((off & (views == 2)).sum())
        counts["n3"] += int((views >= 3).sum())
        counts["off3"] += int((off & (views >= 3)).sum())
        actor = _on_actor(capture, rig, t, xyz, observed)
        counts["na"] += int(actor.sum())
        counts["offa"] += int((off & actor).sum())
        counts["nb"] += int((~actor).sum())
        counts["offb"] += int((off & ~actor).sum())
        on_surface.append(err[~off])
        if want is not None and want[1] == t:
            cam = want[0]
            _draw(capture, rig, t, cam, xyz, views, observed[:, cam], off, draw.split(":", 2)[2])
    good = np.concatenate(on_surface) if on_surface else np.zeros(0)

    def share(k: str, n: str) -> float:
        return round(counts[k] / counts[n], 3) if counts[n] else float("nan")

    return {
        "capture": str(capture),
        "config": config,
        "frames": frames,
        "point_frames": counts["n"],
        "off_share": share("off", "n"),
        "two_view": counts["n2"],
        "two_view_off_share": share("off2", "n2"),
        "three_plus": counts["n3"],
        "three_plus_off_share": share("off3", "n3"),
        "on_actors": counts["na"],
        "on_actors_off_share": share("offa", "na"),
        "on_background": counts["nb"],
        "on_background_off_share": share("offb", "nb"),
        "on_surface": int(len(good)),
        "on_surface_median_mm": round(float(np.median(good)) * 1e3, 2) if len(good) else None,
        "cpu_s": round(cpu, 1),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("capture", help="a synthetic capture (with gt/)")
    ap.add_argument("--frames", type=int, default=6)
    ap.add_argument("--config", help="a TOML with [reconstruct] (default: the defaults)")
    ap.add_argument("--off", type=float, default=0.05, help="metres at human size")
    ap.add_argument("--draw", metavar="CAM:FRAME:PATH", help="draw one camera's points")
    args = ap.parse_args()
    out = study(args.capture, args.frames, args.config, args.off, args.draw)
    print(json.dumps(out))
    print(
        f"{out['point_frames']} point-frames, {100 * out['off_share']:.1f} % off the surface; "
        f"2 views: {out['two_view']} ({100 * out['two_view_off_share']:.1f} % off); "
        f"3+: {out['three_plus']} ({100 * out['three_plus_off_share']:.1f} % off); "
        f"at actors' pixels: {out['on_actors']} ({100 * out['on_actors_off_share']:.1f} % off); "
        f"at the background's: {out['on_background']} "
        f"({100 * out['on_background_off_share']:.1f} % off); "
        f"{out['on_surface']} on the surface, median {out['on_surface_median_mm']} mm; "
        f"{out['cpu_s']} CPU-s"
    )


if __name__ == "__main__":
    main()
