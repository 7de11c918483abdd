"""Study: do tracked points stay on their surface point, or slide along their part?

Two measurements on a synthetic capture, whose parts are rigid:

1. **Trajectories** (``WORK GT_WORK``): each reconstructed trajectory on a labelled part (its true
   label, as the report votes it) starts at its first position, which the true part's motion then
   carries frame by frame (a Kabsch fit of the ground-truth store's points of that part between
   consecutive frames). The distance from the carried position to the trajectory's own is its
   drift along the part, by age. On the ground-truth store itself it is 0; the 3D error, a
   distance to the surface, does not see a slide along it.
2. **Frame-to-frame flow** (``--flow CAPTURE``): the ground-truth points seen by a camera at frame
   0 are tracked by :func:`pointtraj.reconstruct.flow.track_flow` alone, for each ``--windows``
   size, and compared with their true projections: the distance (px) by frame, and the component
   along their motion as a share of it (negative: the track lags behind). A window wider than a
   limb holds part of the static background and lags (``docs/reconstruction.md``, "The
   Lucas-Kanade window and the subject's size").

Usage::

    .venv/bin/python benchmarks/study_drift.py WORK GT_WORK [WORK ...]
    .venv/bin/python benchmarks/study_drift.py --flow CAPTURE --frames 16 --windows 7 11 15 21
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

AGES = (1, 2, 3, 5, 8, 12, 16, 20, 30, 40)


def part_motion(gt, labels: np.ndarray, num_classes: int, num_frames: int):
    """Each part's rigid motion from frame t - 1 to t: R (K, T, 3, 3), centroids (K, T, 3) x 2."""
    from pointtraj.geometry import fit_rigid

    R = np.full((num_classes, num_frames, 3, 3), np.nan)
    mu0 = np.full((num_classes, num_frames, 3), np.nan)
    mu1 = np.full((num_classes, num_frames, 3), np.nan)
    for t in range(1, num_frames):
        rows = gt.frame_rows(t)
        rows = rows[gt.first_frame[gt.row_track[rows]] <= t - 1]
        lab = labels[gt.row_track[rows]]
        for c in range(num_classes):
            rr = rows[lab == c]
            if rr.size < 3:
                continue
            a, b = gt.xyz[rr - 1].astype(float), gt.xyz[rr].astype(float)
            mu0[c, t], mu1[c, t] = a.mean(axis=0), b.mean(axis=0)
            fit = fit_rigid((a - mu0[c, t])[None], (b - mu1[c, t])[None], np.ones((1, rr.size)))
            R[c, t] = fit.rotation[0]
    return R, mu0, mu1


def drift_by_age(traj, labels: np.ndarray, motion) -> dict[int, np.ndarray]:
    """Distance (m) of each labelled trajectory from its first position carried by its part."""
    R, mu0, mu1 = motion
    lengths, first, off = traj.lengths, traj.first_frame, traj.offsets
    idx = np.flatnonzero((labels >= 0) & (lengths >= 2))
    pred = traj.xyz[off[idx]].astype(float)
    alive = np.ones(idx.size, bool)
    out: dict[int, np.ndarray] = {}
    for age in range(1, int(lengths.max(initial=1))):
        live = np.flatnonzero(alive & (lengths[idx] > age))
        if live.size == 0:
            break
        m = idx[live]
        t, c = first[m] + age, labels[m]
        p = np.einsum("nij,nj->ni", R[c, t], pred[live] - mu0[c, t]) + mu1[c, t]
        known = np.isfinite(p[:, 0])  # the part has a fit at t
        pred[live] = p
        alive[live[~known]] = False
        obs = traj.xyz[off[m] + age].astype(float)
        out[age] = np.linalg.norm(obs - p, axis=1)[known]
    return out


def trajectories_study(work: Path, gt_work: Path) -> None:
    from pointtraj.evaluate.groundtruth import true_labels
    from pointtraj.trajectories import Trajectories
    from pointtraj.workdir import WorkFolder

    gw = WorkFolder(gt_work)
    gt = Trajectories.load(gw.trajectories)
    gl, source = true_labels(gw.capture_path(), gt)
    if source != "ground truth":
        raise SystemExit(f"{gt_work}: not the capture's ground-truth trajectories")
    wf = WorkFolder(work)
    traj = Trajectories.load(wf.trajectories)
    truth, _ = true_labels(wf.capture_path(), traj)
    K = int(max(gl.max(), truth.max())) + 1
    motion = part_motion(gt, gl, K, max(traj.num_frames, gt.num_frames))
    print(f"\n# {work}: drift along the true part (mm) by age (frames)")
    print("| age | trajectories | median | p75 | p90 |\n|---:|---:|---:|---:|---:|")
    drift = drift_by_age(traj, truth, motion)
    for age in AGES:
        d = drift.get(age)
        if d is not None and d.size:
            q = np.percentile(d, [50, 75, 90]) * 1000
            print(f"| {age} | {d.size:,} | {q[0]:.2f} | {q[1]:.2f} | {q[2]:.2f} |")


def flow_study(capture: Path, frames: int, windows: list[int], levels: int, every: int) -> None:
    from pointtraj.reconstruct.flow import to_grey, track_flow
    from pointtraj.session import Capture
    from pointtraj.synth.groundtruth import load_ground_truth

    cap = Capture.open(capture)
    rig, names = cap.rig, list(cap.rig.names)
    gt = load_ground_truth(capture)
    frames = min(frames, gt.num_frames)
    true = [rig.project(gt.xyz[:, t].astype(float)).pixels for t in range(frames)]  # (C, N, 2)
    print(f"\n# {capture}: frame-to-frame flow of the ground-truth points, every {every} camera")
    print(
        "| window | frame | views | distance to the truth, median / p90 (px) | along the motion |"
    )
    print("|---:|---:|---:|---|---:|")
    for window in windows:
        dist: dict[int, list] = {}
        along: dict[int, list] = {}
        for c in range(0, len(rig), every):
            grey = [to_grey(cap.read(names[c], t)) for t in range(frames)]
            sel = np.flatnonzero(gt.visible[:, 0, c] & (gt.label >= 0))
            p = true[0][c, sel].astype(np.float32)
            alive = np.ones(sel.size, bool)
            for t in range(1, frames):
                p = track_flow(
                    grey[t - 1],
                    grey[t],
                    np.where(alive[:, None], p, np.nan),
                    window=window,
                    levels=levels,
                )
                alive &= np.isfinite(p[:, 0]) & gt.visible[sel, t, c]
                err = (p - true[t][c, sel])[alive]
                moved = (true[t][c, sel] - true[0][c, sel])[alive]
                dist.setdefault(t, []).append(np.linalg.norm(err, axis=1))
                norm = np.linalg.norm(moved, axis=1)
                far = norm > 2.0
                along.setdefault(t, []).append((err[far] * moved[far]).sum(1) / norm[far] ** 2)
        for t in sorted(dist):
            if t in AGES or t == frames - 1:
                d, a = np.concatenate(dist[t]), np.concatenate(along[t])
                q = np.percentile(d, [50, 90]) if d.size else (np.nan, np.nan)
                share = f"{100 * np.median(a):+.1f} %" if a.size else "-"
                print(f"| {window} | {t} | {d.size:,} | {q[0]:.2f} / {q[1]:.2f} | {share} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("works", nargs="*", type=Path, help="WORK GT_WORK, or WORK... GT_WORK")
    ap.add_argument("--flow", type=Path, help="a synthetic capture: the flow study")
    ap.add_argument("--frames", type=int, default=16)
    ap.add_argument("--windows", type=int, nargs="+", default=[7, 11, 15, 21])
    ap.add_argument("--levels", type=int, default=3)
    ap.add_argument("--every", type=int, default=2, help="every k-th camera (flow study)")
    args = ap.parse_args()
    if len(args.works) == 1:
        ap.error("give a ground-truth work folder after the work folders")
    for work in args.works[:-1]:
        trajectories_study(work, args.works[-1])
    if args.flow is not None:
        flow_study(args.flow, args.frames, args.windows, args.levels, args.every)


if __name__ == "__main__":
    main()
