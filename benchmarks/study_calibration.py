"""Study: how well ``pointtraj calibrate`` recovers a rig, on synthetic and real footage.

``synthetic``
    Renders ``static_room`` with a rig preset (default ``ring12``: 12 cameras, 800x640, two
    heights), calibrates it with pycolmap (:func:`pointtraj.calibrate.calibrate_images`),
    similarity-aligns the result to the ground-truth rig and reports per-camera errors in
    rotation (degrees), camera centre (mm), focal length (%) and distortion (RMS pixel
    displacement difference over the image). Goal: < 0.1 deg, < 5 mm, < 0.5 %.
``real``
    The caliscope 4-webcam capture (``/work/shared/data/caliscope_board_4cam``, 1280x720, a
    person moving a ChArUco board): SfM on frames spread over the videos, then, when SfM does
    not register every camera, the ChArUco-only calibration
    (:func:`pointtraj.calibrate.calibrate_charuco`). Compared with caliscope's own calibration
    (``camera_array.toml``) after a similarity alignment.

Writes ``docs/images/calibration_*.png`` and prints a JSON line per case.

Usage::

    .venv/bin/python benchmarks/study_calibration.py synthetic [--preset ring12] [--frames 1]
    .venv/bin/python benchmarks/study_calibration.py real [--every 6]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"
CALISCOPE = SHARED / "data" / "caliscope_board_4cam"
IMAGES = ROOT / "docs" / "images"


def plot_errors(cmp, title: str, path: Path) -> None:
    """Bar charts of the per-camera differences."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axs = plt.subplots(1, 3, figsize=(13, 3.6))
    x = np.arange(len(cmp.names))
    for ax, vals, label in (
        (axs[0], cmp.rotation_deg, "rotation error (deg)"),
        (axs[1], 1e3 * cmp.centre_m, "camera centre error (mm)"),
        (axs[2], 100 * cmp.focal_rel, "focal length error (%)"),
    ):
        ax.bar(x, vals, color="tab:blue")
        ax.set_xticks(x, cmp.names, rotation=60, fontsize=7)
        ax.set_ylabel(label)
        ax.grid(axis="y", alpha=0.3)
    fig.suptitle(title)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def synthetic(preset: str, frames: int, model: str) -> dict:
    from pointtraj.calibrate import (
        CalibrationOptions,
        calibrate_images,
        compare_rigs,
        export_frames,
    )
    from pointtraj.session import Capture
    from pointtraj.synth.render import render_capture

    with tempfile.TemporaryDirectory(prefix="study-calib-") as tmp:
        t0 = time.perf_counter()
        cap_dir = Path(tmp) / "capture"
        render_capture(cap_dir, preset=preset, scene="static_room", frames=frames, seed=0)
        t_render = time.perf_counter() - t0
        cap = Capture.open(cap_dir)
        list(export_frames(cap, range(frames), Path(tmp) / "images"))
        t0 = time.perf_counter()
        cal = calibrate_images(
            Path(tmp) / "images", Path(tmp) / "colmap", CalibrationOptions(camera_model=model)
        )
        t_cal = time.perf_counter() - t0
        cmp = compare_rigs(cal.rig, cap.rig)
    s = cmp.summary()
    plot_errors(
        cmp,
        f"{preset}, static_room, {frames} frame(s), {model}: calibrated vs ground truth",
        IMAGES / f"calibration_synthetic_{preset}.png",
    )
    return {
        "case": f"synthetic {preset} x{frames} {model}",
        "registered": f"{len(cal.rig)}/{len(cal.camera_names)}",
        "points": cal.num_points,
        "reprojection_px_mean": float(np.mean(list(cal.errors.values()))),
        **{k: round(v, 4) for k, v in s.items()},
        "failed": cal.failed,
        "left_out_of_alignment": cmp.alignment_outliers,
        "rotation_deg": dict(zip(cmp.names, np.round(cmp.rotation_deg, 3).tolist(), strict=True)),
        "centre_mm": dict(zip(cmp.names, np.round(1e3 * cmp.centre_m, 1).tolist(), strict=True)),
        "focal_pct": dict(zip(cmp.names, np.round(100 * cmp.focal_rel, 3).tolist(), strict=True)),
        "distortion_k1_est_max": float(np.abs(cal.rig.dist[:, 0]).max()),
        "render_s": round(t_render, 1),
        "calibrate_s": round(t_cal, 1),
    }


def read_videos(every: int) -> tuple[dict, list[str], list[tuple[int, int]], Path]:
    """Frames 0, every, 2 every, ... of the 4 videos, as RGB images keyed by (camera, frame)."""
    import cv2

    names = [f"cam_{i}" for i in range(4)]
    frames = {}
    sizes = []
    for c, name in enumerate(names):
        video = cv2.VideoCapture(str(CALISCOPE / "calibration" / "extrinsic" / f"{name}.mp4"))
        f = 0
        while True:
            ok, img = video.read()
            if not ok:
                break
            if f % every == 0:
                frames[(c, f)] = img[..., ::-1].copy()
            f += 1
        video.release()
        sizes.append((frames[(c, 0)].shape[1], frames[(c, 0)].shape[0]))
    return frames, names, sizes, CALISCOPE


def real(every: int, lens: str) -> list[dict]:
    import cv2

    from pointtraj.calibrate import (
        CalibrationError,
        CharucoBoard,
        align_rig_to_charuco,
        calibrate_charuco,
        calibrate_images,
        compare_rigs,
        detect_charuco,
    )
    from pointtraj.rigio import load_rig

    if not CALISCOPE.is_dir():
        raise SystemExit(f"shared data not found at {CALISCOPE}")
    reference = load_rig(CALISCOPE / "camera_array.toml")
    board = CharucoBoard.from_toml(CALISCOPE / "charuco.toml")
    frames, names, sizes, _ = read_videos(1)
    dets = {k: detect_charuco(img, board) for k, img in frames.items()}
    rows = []
    # 1. Feature-based SfM on spread frames.
    with tempfile.TemporaryDirectory(prefix="study-calib-real-") as tmp:
        for (c, f), img in frames.items():
            if f % every:
                continue
            d = Path(tmp) / "images" / names[c]
            d.mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(d / f"{f:06d}.jpg"), img[..., ::-1])
        t0 = time.perf_counter()
        try:
            cal = calibrate_images(Path(tmp) / "images", Path(tmp) / "colmap")
            row = {
                "case": f"real sfm (every {every}th frame)",
                "registered": f"{len(cal.rig)}/{len(cal.camera_names)}",
                "failed": cal.failed,
                "points": cal.num_points,
            }
            reg = {names.index(n): k for k, n in enumerate(cal.rig.names)}
            sub = {(reg[c], f): v for (c, f), v in dets.items() if c in reg}
            try:
                rig, stats = align_rig_to_charuco(cal.rig, sub, board)
                row["charuco"] = stats
            except CalibrationError as exc:
                rig, row["charuco"] = cal.rig, str(exc)
            row.update({k: round(v, 4) for k, v in compare_rigs(rig, reference).summary().items()})
        except CalibrationError as exc:
            row = {"case": f"real sfm (every {every}th frame)", "error": str(exc)}
        row["calibrate_s"] = round(time.perf_counter() - t0, 1)
        rows.append(row)
    # 2. ChArUco corners only (all frames).
    t0 = time.perf_counter()
    cal, stats = calibrate_charuco(dets, board, names, sizes, lens=lens)
    cmp = compare_rigs(cal.rig, reference)
    plot_errors(
        cmp,
        f"caliscope 4 webcams, ChArUco-only calibration ({lens} lens) vs caliscope",
        IMAGES / "calibration_real_charuco.png",
    )
    rows.append(
        {
            "case": f"real charuco ({lens} lens, all 57 frames)",
            "registered": f"{len(cal.rig)}/{len(names)}",
            **{k: round(v, 4) for k, v in cmp.summary().items()},
            "left_out_of_alignment": cmp.alignment_outliers,
            "rotation_deg": np.round(cmp.rotation_deg, 2).tolist(),
            "centre_mm": np.round(1e3 * cmp.centre_m, 1).tolist(),
            "focal_pct": np.round(100 * cmp.focal_rel, 2).tolist(),
            "reprojection_px": {k: round(v, 3) for k, v in cal.errors.items()},
            "caliscope_reported_px": [0.541, 0.401, 0.366, 0.329],
            **{k: round(v, 3) for k, v in stats.items()},
            "calibrate_s": round(time.perf_counter() - t0, 1),
        }
    )
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("what", choices=["synthetic", "real"])
    parser.add_argument("--preset", default="ring12")
    parser.add_argument("--frames", type=int, default=1)
    parser.add_argument("--model", default="RADIAL")
    parser.add_argument("--every", type=int, default=6, help="real: SfM on every Nth frame")
    parser.add_argument("--lens", default="simple", choices=["simple", "full"])
    args = parser.parse_args()
    if args.what == "synthetic":
        print(json.dumps(synthetic(args.preset, args.frames, args.model)))
    else:
        for row in real(args.every, args.lens):
            print(json.dumps(row, default=str))


if __name__ == "__main__":
    main()
