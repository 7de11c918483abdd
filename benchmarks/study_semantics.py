"""Semantic-map studies on synthetic captures (the paper's Section 6, semantic map robustness).

1. **Accuracy**: the fraction of ground-truth trajectories whose argmax-L3D class is their true
   class, for view and average pooling, at simulated-recogniser noise ``low``/``default``/``high``
   and with 5, 10, 20 and 69 cameras (evenly spread subsets of the 69-camera rig). The capture is
   the ``dribble`` scene on the ``paper69`` geometry rendered at quarter resolution (320x256,
   f = 150 px, the same field of view) for a few frames; the simulated recogniser then
   downsamples by 2, so its maps are 160x128 cells, as ``paper69``'s 1280x1024 images at the
   default 1/8.
2. **Temporal consistency** (the paper's Table 1): ``NC(L_pool(t0), L_pool(t0 + lag))``, the
   Pearson correlation across the K classes of a trajectory's pooled confidences at its first
   frame and ``lag`` later, averaged over the trajectories alive that long, for lags of 1, 3, 5,
   ..., 15 s. A 15 s sequence at 30 Hz with 69 cameras at full size is too expensive to render
   here, so this part renders the ``paper69`` geometry at 160x128 (``--temporal-rig paper69``,
   the default; the recogniser keeps the full resolution, 160x128 maps) or the ``ring12``
   geometry at 320x256 (``ring12``; it downsamples by 2), sampled at 10 Hz for 15 s (151
   frames; scene time is frame / fps, so the motion is the same as at 30 Hz). The recogniser
   holds its per-view confusions for 5 frames (0.5 s, as ``hold_frames=15`` at 30 Hz).

Ground-truth trajectories (``GroundTruth.to_trajectories``, visibility 1 where a camera sees
the point) stand in for reconstructed ones. Everything is seeded.

Usage::

    .venv/bin/python benchmarks/study_semantics.py --work /tmp/pointtraj_study [--quick]
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import numpy as np

from pointtraj.camera import CameraRig
from pointtraj.labelset import LabelSet
from pointtraj.semantics.recognizers.simulated import SimulatedRecognizer
from pointtraj.semantics.semantic_map import SemanticsConfig, build_semantic_map
from pointtraj.session import Capture
from pointtraj.synth.groundtruth import load_ground_truth
from pointtraj.synth.presets import PRESETS, RigPreset, ring_cameras
from pointtraj.synth.render import render_capture

#: The paper's two poolings, ours (``view_soft``) and the average over the visible cameras.
POOLS = ("view", "view_soft", "average", "average_visible")


def _ring12_small() -> CameraRig:
    return CameraRig(ring_cameras(12, 2.5, [1.1, 2.0], (0.0, 0.0, 0.9), (320, 256), 168.0))


#: The study's rigs: the library's ``paper69q`` (320x256) and ``paper69t`` (160x128, 10 Hz,
#: also the rig of ``pipelines/paper_table1.toml``), and a study-only ring12 at 10 Hz.
STUDY_PRESETS = {
    "study-paper69-quarter": PRESETS["paper69q"],
    "study-paper69-10hz": PRESETS["paper69t"],
    "study-ring12-10hz": RigPreset(
        "ring12 geometry at 320x256, f=168 px (same FOV), sampled at 10 Hz", _ring12_small, 10.0
    ),
}


def render(
    out: Path, preset: str, frames: int, points_per_part: int, scene: str = "dribble"
) -> Path:
    PRESETS.update(STUDY_PRESETS)  # study-only rigs, registered for this process
    t0 = time.perf_counter()
    summary = render_capture(
        out, preset=preset, scene=scene, frames=frames, seed=0, points_per_part=points_per_part
    )
    print(f"rendered {out} ({preset}, {frames} frames) in {time.perf_counter() - t0:.0f} s")
    del summary
    return out


def ground_truth_trajectories(capture: Path, cameras: list[int] | None = None):
    """GT trajectories seen by >= 2 of the chosen cameras, and each one's true class."""
    gt = load_ground_truth(capture)
    if cameras is not None:
        gt = dataclasses.replace(
            gt,
            visible=gt.visible[:, :, cameras],
            camera_names=[gt.camera_names[c] for c in cameras],
        )
    point, _, _ = gt.segments(2)
    return gt.to_trajectories(2), gt.label[point]


def accuracy_study(work: Path, frames: int, points_per_part: int) -> None:
    capture = render(work / "capture69", "study-paper69-quarter", frames, points_per_part)
    cap = Capture.open(capture)
    labels = LabelSet.load(cap.labels_path)
    rows = []
    for n_cams in (5, 10, 20, 69):
        cams = np.unique(np.round(np.linspace(0, 68, n_cams)).astype(int)).tolist()
        traj, truth = ground_truth_trajectories(capture, cams)
        for noise in ("low", "default", "high"):
            rec = SimulatedRecognizer(
                labels.names, labels.kinds, noise=noise, capture=capture, downsample=2
            )
            t0 = time.perf_counter()
            config = SemanticsConfig(sample_budget_mb=0, poolings=POOLS)
            smap = build_semantic_map(cap, traj, rec, config=config)
            secs = time.perf_counter() - t0
            acc = []
            for p in POOLS:
                seen = smap.count[p] > 0
                acc.append(float(np.mean(smap.argmax_labels(p)[seen] == truth[seen])))
            rows.append((n_cams, noise, len(traj), acc, secs))
    print(f"\n### Accuracy of argmax L3D against ground truth (dribble, {frames} frames)\n")
    print("| cameras | noise | trajectories | " + " | ".join(POOLS) + " | seconds |")
    print("|---:|---|---:|" + "---:|" * len(POOLS) + "---:|")
    for n, noise, m, acc, s in rows:
        print(f"| {n} | {noise} | {m} | " + " | ".join(f"{a:.3f}" for a in acc) + f" | {s:.1f} |")


def temporal_study(
    work: Path,
    rig: str,
    seconds: int,
    points_per_part: int,
    scene: str = "dribble",
    noises: tuple[str, ...] = ("default", "high"),
) -> None:
    preset = f"study-{rig}-10hz"
    fps = STUDY_PRESETS[preset].fps
    frames = int(seconds * fps) + 1
    suffix = "" if scene == "dribble" else f"-{scene}"
    capture = render(work / f"capture-{rig}-10hz{suffix}", preset, frames, points_per_part, scene)
    # Maps of 160x128 cells, as paper69's 1280x1024 images at the default 1/8.
    downsample = 1 if rig == "paper69" else 2
    cap = Capture.open(capture)
    labels = LabelSet.load(cap.labels_path)
    traj, truth = ground_truth_trajectories(capture)
    lags = [s for s in range(1, seconds + 1, 2)]
    for noise in noises:
        rec = SimulatedRecognizer(
            labels.names,
            labels.kinds,
            noise=noise,
            capture=capture,
            downsample=downsample,
            hold_frames=5,
        )
        t0 = time.perf_counter()
        smap = build_semantic_map(cap, traj, rec, config=SemanticsConfig(poolings=POOLS))
        secs = time.perf_counter() - t0
        smap.save(work / f"semantic_map-{rig}-{scene}-{noise}.npz")  # for later analyses
        print(
            f"\n### Temporal consistency NC(L_pool^0, L_pool^t), {scene}, {rig}, noise {noise} "
            f"({len(traj)} trajectories, {frames} frames at {fps:g} Hz, {secs:.0f} s)\n"
        )
        print("| pooling | " + " | ".join(f"{s} s" for s in lags) + " |")
        print("|---|" + "---:|" * len(lags))
        for p in smap.poolings:
            cells = []
            for s in lags:
                mean, std, n = smap.temporal_consistency(int(round(s * fps)), p)
                cells.append(f"{mean:.2f} ± {std:.2f} (n={n})" if n else "-")
            print(f"| {p} | " + " | ".join(cells) + " |")
        for p in smap.poolings:
            seen = smap.count[p] > 0
            acc = float(np.mean(smap.argmax_labels(p)[seen] == truth[seen]))
            print(f"accuracy ({p}): {acc:.3f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, default=Path("/tmp/pointtraj_study"))
    parser.add_argument("--frames", type=int, default=8, help="frames of the accuracy capture")
    parser.add_argument("--seconds", type=int, default=15, help="length of the temporal capture")
    parser.add_argument("--points-per-part", type=int, default=150)
    parser.add_argument(
        "--temporal-rig",
        choices=["paper69", "ring12"],
        default="paper69",
        help="rig of the temporal capture (paper69 geometry at 160x128, or ring12 at 320x256)",
    )
    parser.add_argument("--temporal-scene", default="dribble", help="scene of the temporal capture")
    parser.add_argument(
        "--temporal-noise", nargs="+", default=["default", "high"], help="noise presets"
    )
    parser.add_argument(
        "--quick", action="store_true", help="a smoke run: 2 accuracy frames, 3 s temporal capture"
    )
    parser.add_argument("--skip-accuracy", action="store_true")
    parser.add_argument("--skip-temporal", action="store_true")
    args = parser.parse_args()
    if args.quick:
        args.frames, args.seconds = 2, 3
    args.work.mkdir(parents=True, exist_ok=True)
    if not args.skip_accuracy:
        accuracy_study(args.work, args.frames, args.points_per_part)
    if not args.skip_temporal:
        temporal_study(
            args.work,
            args.temporal_rig,
            args.seconds,
            args.points_per_part,
            args.temporal_scene,
            tuple(args.temporal_noise),
        )


if __name__ == "__main__":
    main()
