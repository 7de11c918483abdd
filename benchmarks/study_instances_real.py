"""Study: people as instances on a real capture, where nobody says who is who.

Pose2Sim's ``Demo_MultiPerson`` (``pipelines/pose2sim_multi.toml``) has two people who stay
apart: a man on a treadmill and a woman beside it. Without ground truth, the check is
geometric and independent of how the instances were made (rigid groups of the affinity graph and
the recogniser's person masks, :mod:`pointtraj.instances`):

1. The labelled body-part trajectories' positions over all frames, on the floor plane (the two
   coordinates across the up axis), are split into as many spatial clusters as the labelling
   found people (k-means, :func:`scipy.cluster.vq.kmeans2`, seeded; the people must stand apart
   for this to be a truth, so the distance between the cluster centres and the share of
   positions within ``--margin`` of the boundary between them are printed).
2. Each trajectory's spatial person is the cluster holding most of its positions; trajectories
   that straddle (under ``--purity`` of their positions in one cluster) are left out and
   counted.
3. **Instance agreement**: the share of the labelled body-part trajectories whose instance id
   matches their spatial person after the best one-to-one matching
   (:func:`pointtraj.instances.instance_accuracy`; no instance counts as wrong), overall and per
   person, with the number of trajectories and point-frames of each person.

Usage::

    cd /tmp/p2sm && pointtraj run /path/to/pipelines/pose2sim_multi.toml
    .venv/bin/python benchmarks/study_instances_real.py work/pose2sim-multi [--report r.json]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def floor_coordinates(xyz: np.ndarray, up: np.ndarray) -> np.ndarray:
    """(N, 2) coordinates of points on the plane across ``up`` (3,)."""
    up = up / np.linalg.norm(up)
    a = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 1.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(up, a)
    return np.stack([xyz @ a, xyz @ b], axis=1)


def main() -> None:
    from scipy.cluster.vq import kmeans2

    import pointtraj
    from pointtraj.config import load_toml
    from pointtraj.geometry import resolve_up
    from pointtraj.instances import instance_accuracy
    from pointtraj.labelset import LabelSet
    from pointtraj.session import Capture

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("work", type=Path)
    ap.add_argument("--margin", type=float, default=0.3, help="metres around the boundary")
    ap.add_argument("--purity", type=float, default=0.9, help="share in one cluster")
    ap.add_argument("--report", type=Path)
    args = ap.parse_args()

    res = pointtraj.load(args.work)
    traj, labels = res.trajectories, res.labels
    cap = Capture.open(load_toml(args.work / "work.toml")["capture"])
    labelset = LabelSet.load(cap.labels_path)
    body_names = {labelset.names[i] for i in labelset.classes_of_kind("body")}
    body = np.array([c in body_names for c in labels.class_names])
    lab = labels.labels
    on_body = (lab >= 0) & body[np.maximum(lab, 0)]
    inst = labels.instance
    people = sorted({int(i) for i in inst[on_body] if i >= 0})
    k = len(people)
    print(f"labelled body-part trajectories: {int(on_body.sum())}, people found: {k}")
    if k < 2:
        print("fewer than two people: nothing to check")
        return
    up, how = resolve_up("auto", cap.rig)
    rows = np.flatnonzero(on_body[traj.row_track])
    track = traj.row_track[rows]
    xy = floor_coordinates(traj.xyz[rows].astype(np.float64), up)
    rng = np.random.default_rng(0)
    sample = rng.choice(len(xy), min(len(xy), 200_000), replace=False)
    centres, _ = kmeans2(xy[sample], k, seed=1, minit="++")
    d = np.linalg.norm(xy[:, None, :] - centres[None], axis=2)  # (R, k)
    near = np.argmin(d, axis=1)
    ds = np.sort(d, axis=1)
    boundary = float(np.mean(ds[:, 1] - ds[:, 0] < 2 * args.margin))
    gap = float(
        np.min([np.linalg.norm(a - b) for i, a in enumerate(centres) for b in centres[i + 1 :]])
    )
    counts = np.zeros((traj.num_trajectories, k), np.int64)
    np.add.at(counts, (track, near), 1)
    total = counts.sum(axis=1)
    spatial = np.where(total > 0, np.argmax(counts, axis=1), -1)
    pure = (total > 0) & (counts.max(axis=1) >= args.purity * np.maximum(total, 1))
    judged = on_body & pure
    true = np.where(judged, spatial, -1)
    acc = instance_accuracy(np.where(judged, inst, -1), true)
    per = {}
    for c in range(k):
        sel = judged & (spatial == c)
        per[c] = {
            "trajectories": int(sel.sum()),
            "point_frames": int(total[sel].sum()),
            "agreement": instance_accuracy(np.where(sel, inst, -1), np.where(sel, c, -1)),
            "centre_m": centres[c].round(3).tolist(),
        }
    report = {
        "work": str(args.work),
        "up": up.round(3).tolist(),
        "up_from": how,
        "people_found": k,
        "labelled_body_trajectories": int(on_body.sum()),
        "without_instance": int((on_body & (inst < 0)).sum()),
        "cluster_gap_m": gap,
        "near_boundary_share": boundary,
        "straddling_trajectories": int((on_body & ~pure).sum()),
        "judged_trajectories": int(judged.sum()),
        "instance_agreement": acc,
        "per_person": per,
    }
    print(json.dumps(report, indent=1))
    print(
        f"\ninstance agreement with the spatial split: {100 * acc:.1f} % of {int(judged.sum())} "
        f"trajectories (clusters {gap:.2f} m apart; {100 * boundary:.1f} % of positions within "
        f"{args.margin:g} m of the boundary; {report['straddling_trajectories']} straddling "
        "trajectories left out)"
    )
    if args.report:
        args.report.write_text(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
