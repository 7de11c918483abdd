"""Study: segment poses and joint centres against the synthetic figure's exact ones.

Reads a work folder's ``segments.npz`` (``pointtraj segments WORK``) and compares it with the
generator's part poses and joint centres (:func:`pointtraj.synth.groundtruth.segment_ground_truth`)
of its synthetic capture:

- joint-centre error: the distance from the estimated world centre to the true one (the
  child part's local origin), per joint and frame where the estimate exists;
- segment rotation error: the angle between the estimated pose rotation ``R_t`` (reference
  frame to t) and the true ``G_t G_ref^T``, per part and frame where a pose exists.

Without person instances every segment is matched to figure 0; with them, a segment's person
is matched to the figure whose joints it lies nearest to.

Usage (the figures of ``docs/segments.md``)::

    pointtraj demo --out /tmp/segments/demo
    pointtraj segments /tmp/segments/demo/work
    python benchmarks/study_segments.py /tmp/segments/demo/work
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def evaluate(work: Path, capture: Path | None = None) -> dict:
    """Per-joint and per-part errors of ``work/segments.npz`` against the generator."""
    from pointtraj.geometry import rotation_angle_deg
    from pointtraj.segments import JOINT_STATUS, load_segments
    from pointtraj.synth.groundtruth import segment_ground_truth
    from pointtraj.workdir import WorkFolder

    wf = WorkFolder(work)
    seg = load_segments(wf.segments)
    capture = capture or wf.capture_path()
    truth = segment_ground_truth(capture)
    T = min(seg.num_frames, truth.joints.shape[1])
    est = seg.joint_positions()[:, :T]
    persons = sorted(set(seg.segment_instance.tolist()))
    figures = sorted(set(truth.joint_instance.tolist()))
    # match each person to the figure whose joints it is nearest to (identity with one each)
    match = {}
    for p in persons:
        best, dist = figures[0], np.inf
        for f in figures:
            d = []
            for j, (n, i) in enumerate(zip(seg.joint_names, seg.joint_instance)):
                if i != p:
                    continue
                k = [
                    q
                    for q, (m, g) in enumerate(zip(truth.joint_names, truth.joint_instance))
                    if m == n and g == f
                ]
                if k:
                    d.append(np.nanmedian(np.linalg.norm(est[j] - truth.joints[k[0], :T], axis=1)))
            d = np.nanmedian(d) if np.isfinite(d).any() else np.inf
            if d < dist:
                best, dist = f, d
        match[p] = best
    joints, all_err = [], []
    labels = seg.joint_labels()
    for j, (n, p) in enumerate(zip(seg.joint_names, seg.joint_instance)):
        k = [
            q
            for q, (m, g) in enumerate(zip(truth.joint_names, truth.joint_instance))
            if m == n and g == match[p]
        ]
        err = np.linalg.norm(est[j] - truth.joints[k[0], :T], axis=1) if k else np.full(T, np.nan)
        ok = np.isfinite(err)
        all_err.append(err[ok])
        joints.append(
            {
                "joint": labels[j],
                "status": JOINT_STATUS[seg.joint_status[j]],
                "frames": int(ok.sum()),
                "rotation_deg": [round(float(v), 1) for v in seg.joint_rotation_deg[j]],
                "median_mm": round(1000 * float(np.median(err[ok])), 1) if ok.any() else None,
                "p90_mm": round(1000 * float(np.percentile(err[ok], 90)), 1) if ok.any() else None,
            }
        )
    parts, all_rot = [], []
    names = seg.segment_names()
    for s in range(seg.num_segments):
        k = np.flatnonzero(
            (truth.part_label == seg.segment_label[s])
            & (truth.part_instance == match[int(seg.segment_instance[s])])
        )
        if not k.size:
            continue
        G = truth.part_poses[k[0], :T, :3, :3]
        r = int(seg.reference_frame[s])
        if r >= T:
            continue
        err = rotation_angle_deg(seg.rotation[s, :T], G @ G[r].T)
        ok = np.isfinite(err)
        ok[r] = False  # the identity at the reference frame is exact by definition
        all_rot.append(err[ok])
        parts.append(
            {
                "part": names[s],
                "frames": int(ok.sum()),
                "median_points": int(np.median(seg.points[s, :T])),
                "median_inliers": int(np.median(seg.inliers[s, :T])),
                "median_deg": round(float(np.median(err[ok])), 2) if ok.any() else None,
                "p90_deg": round(float(np.percentile(err[ok], 90)), 2) if ok.any() else None,
            }
        )
    je = np.concatenate(all_err) if all_err else np.zeros(0)
    re = np.concatenate(all_rot) if all_rot else np.zeros(0)
    return {
        "work": str(work),
        "frames": T,
        "joint_median_mm": round(1000 * float(np.median(je)), 1) if je.size else None,
        "joint_frames": int(je.size),
        "rotation_median_deg": round(float(np.median(re)), 2) if re.size else None,
        "rotation_frames": int(re.size),
        "joints": joints,
        "parts": parts,
    }


def to_markdown(res: dict) -> str:
    """The result as two markdown tables."""
    lines = [
        f"joint-centre error median {res['joint_median_mm']} mm over {res['joint_frames']} "
        f"joint-frames; segment rotation error median {res['rotation_median_deg']} deg over "
        f"{res['rotation_frames']} part-frames ({res['frames']} frames)",
        "",
        "| joint | status | frames | RMS rotation (deg, 3 axes) | median (mm) | p90 (mm) |",
        "|---|---|---|---|---|---|",
    ]
    for j in res["joints"]:
        rot = " / ".join(f"{v:.1f}" for v in j["rotation_deg"])
        lines.append(
            f"| {j['joint']} | {j['status']} | {j['frames']} | {rot} | {j['median_mm']} | "
            f"{j['p90_mm']} |"
        )
    lines += [
        "",
        "| part | frames | points (median) | inliers (median) | median (deg) | p90 (deg) |",
        "|---|---|---|---|---|---|",
    ]
    for p in res["parts"]:
        lines.append(
            f"| {p['part']} | {p['frames']} | {p['median_points']} | {p['median_inliers']} | "
            f"{p['median_deg']} | {p['p90_deg']} |"
        )
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("work", type=Path, help="work folder with segments.npz")
    ap.add_argument("--capture", type=Path, help="its synthetic capture (default: work.toml's)")
    ap.add_argument("--json", type=Path, help="also write the result as JSON here")
    args = ap.parse_args()
    res = evaluate(args.work, args.capture)
    print(to_markdown(res))
    if args.json:
        args.json.write_text(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
