"""Are the body-part labels on the right body parts? A 3D check against a triangulated skeleton.

Usage (after ``pointtraj run pipelines/pose2sim_demo.toml``)::

    .venv/bin/python benchmarks/study_bodyparts.py work/pose2sim [--capture DIR] \\
        [--every 5] [--report parts.json]

A real capture has no ground-truth labels, so we build an independent 3D reference: MediaPipe's
33 body landmarks are detected in every camera (:func:`pointtraj.examples.detect_landmarks`,
the same model the ``body-parts`` recogniser uses, but its landmarks, not its maps) and
triangulated by DLT over the cameras that see them, every ``--every``-th frame. Each body part
becomes a set of 3D segments (a bone; or every edge and diagonal of the landmark polygon of the
head, torso, hands and feet). For each labelled point-frame (a body-part label, on a frame
with a skeleton) we find the part whose segments lie nearest in 3D and report:

- **agreement**: the fraction whose label is that nearest part;
- **left/right swaps**: the fraction labelled with the mirror of the nearest part;
- **on the body**: the fraction within ``--radius`` (25 cm) of any part's segments (the
  segments are the skeleton's axes and the surface lies 5-15 cm from them, plus the landmark
  noise; farther points are background or mismatched points that got a body label);
- the same per trajectory (majority of its frames), and a confusion by part;
- **views**: the share of the labelled point-frames on the body seen by 3 or more cameras, and
  the median length of the labelled trajectories;
- **motion**: the median speed of the trajectories (5 frames or longer) of the labelled
  point-frames on and off the body. Points of the room are static; wrong points that move
  with the person are mismatches on the person.

Several people: the reference is one skeleton per frame (each camera's most prominent person,
triangulated), so it describes one person at best, and only if every camera picked the same
one. When ``labels.npz`` has person ids (``instance``, ``pointtraj label``) the figures are also
given per person (``per_person``), and a warning (printed, and in ``warnings``) says that the
whole-run figures mix people the skeleton does not describe: on a two-person capture the run
figures alone said "9.7 % on the body" without saying why. A run of labels without person ids
whose labelled points lie mostly off the skeleton gets a warning too.

The landmarks themselves are noisy (a median reprojection error of about 18 px on the Pose2Sim
demo, ``docs/real_captures.md``, i.e. 2-4 cm at 3 m), so neighbouring parts (upper arm and
forearm near the elbow) disagree for points near a joint; swaps and off-body points are the
errors that matter.
"""

from __future__ import annotations

import argparse
import json
import logging
from pathlib import Path

import numpy as np

MIRROR = {"left": "right", "right": "left"}


def part_segments(parts: dict[str, tuple[int, ...]]) -> tuple[list[str], np.ndarray, np.ndarray]:
    """Segments of each body part: (names, part index per segment (S,), landmark pairs (S, 2))."""
    names, owner, pairs = list(parts), [], []
    for k, idx in enumerate(parts.values()):
        if len(idx) == 2:
            combos = [tuple(idx)]
        else:
            combos = [(a, b) for i, a in enumerate(idx) for b in idx[i + 1 :]]
        owner += [k] * len(combos)
        pairs += combos
    return names, np.array(owner), np.array(pairs)


def segment_distances(X: np.ndarray, A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """(N, S) distance of points X (N, 3) to segments A-B (S, 3); NaN for NaN segments."""
    d = B - A  # (S, 3)
    L2 = np.einsum("sk,sk->s", d, d)
    t = np.einsum("nsk,sk->ns", X[:, None] - A[None], d) / np.where(L2 > 0, L2, 1.0)
    t = np.clip(t, 0.0, 1.0)
    P = A[None] + t[..., None] * d[None]  # (N, S, 3)
    return np.linalg.norm(X[:, None] - P, axis=2)


def mirror(name: str) -> str:
    side, _, rest = name.partition("_")
    return f"{MIRROR[side]}_{rest}" if side in MIRROR else name


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("work", type=Path)
    ap.add_argument("--capture", type=Path, default=None, help="default: from WORK/work.toml")
    ap.add_argument("--every", type=int, default=5, help="use every n-th frame")
    ap.add_argument("--radius", type=float, default=0.25, help="on the body within (m)")
    ap.add_argument("--min-length", type=int, default=1, help="only trajectories this long")
    ap.add_argument("--report", type=Path, default=None)
    ap.add_argument("-v", "--verbose", action="store_true")
    args = ap.parse_args()
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING)

    from pointtraj.examples import detect_landmarks
    from pointtraj.labelfile import load_labels
    from pointtraj.reconstruct.triangulate import triangulate_points
    from pointtraj.semantics.recognizers.bodyparts import BODY_PARTS
    from pointtraj.session import Capture
    from pointtraj.trajectories import Trajectories, view_counts
    from pointtraj.workdir import WorkFolder

    wf = WorkFolder(args.work)
    cap = Capture.open(args.capture or wf.require_capture(None))
    traj = Trajectories.load(wf.trajectories)
    labels = load_labels(wf.labels)
    rig = cap.rig.subset(traj.camera_names)
    frames = list(traj.occupied_frames[:: args.every])
    cache = args.work / f"landmarks_every{args.every}.npy"
    if cache.is_file():
        lm = np.load(cache)
    else:
        lm = detect_landmarks(cap, frames, threads=2)  # (C, F, 33, 2)
        np.save(cache, lm)
    C, F = lm.shape[:2]
    skel = triangulate_points(rig, lm.reshape(C, -1, 2)).reshape(F, 33, 3)  # NaN: < 2 views

    names, owner, pairs = part_segments(BODY_PARTS)
    class_of = {n: labels.class_names.index(n) for n in names if n in labels.class_names}
    part_of_class = {c: names.index(n) for n, c in class_of.items()}
    instance = labels.instance  # (M,) person id or None (labels written before instances)
    rows_lab, rows_near, rows_dist, rows_track, rows_views = [], [], [], [], []
    for f, t in enumerate(frames):
        rows = traj.frame_rows(t)
        lab = labels.labels[traj.row_track[rows]]
        body = np.isin(lab, list(part_of_class))
        body &= traj.lengths[traj.row_track[rows]] >= args.min_length
        if not body.any() or not np.isfinite(skel[f]).any():
            continue
        X = traj.xyz[rows[body]].astype(np.float64)
        A, B = skel[f][pairs[:, 0]], skel[f][pairs[:, 1]]  # (S, 3)
        d = segment_distances(X, A, B)  # (N, S)
        per_part = np.full((len(X), len(names)), np.inf)
        for k in range(len(names)):
            dk = d[:, owner == k]
            ok = np.isfinite(dk).any(axis=1)
            per_part[ok, k] = np.nanmin(dk[ok], axis=1)
        rows_lab.append(np.array([part_of_class[c] for c in lab[body]]))
        rows_near.append(per_part.argmin(axis=1))
        rows_dist.append(per_part.min(axis=1))
        rows_track.append(traj.row_track[rows[body]])
        rows_views.append(view_counts(traj.visibility[rows[body]]))
    lab = np.concatenate(rows_lab)
    near = np.concatenate(rows_near)
    dist = np.concatenate(rows_dist)
    track = np.concatenate(rows_track)
    views = np.concatenate(rows_views)
    on = dist <= args.radius
    mirror_idx = np.array([names.index(mirror(n)) for n in names])
    swapped = (mirror_idx[near] == lab) & (mirror_idx[near] != near)
    # per trajectory: majority of its evaluated frames
    uniq, inv = np.unique(track, return_inverse=True)
    agree_tr = np.bincount(inv, weights=(lab == near) & on) / np.bincount(inv)
    res = {
        "frames": len(frames),
        "frames_with_skeleton": int(np.isfinite(skel).any(axis=(1, 2)).sum()),
        "labelled_point_frames": int(len(lab)),
        "on_body_fraction": float(on.mean()),
        "agreement_on_body": float((lab == near)[on].mean()),
        "left_right_swaps_on_body": float(swapped[on].mean()),
        "distance_to_labelled_part_median_m": float(np.median(dist[on])),
        "distance_to_body_percentiles_10_25_50_75_90_m": np.percentile(dist, [10, 25, 50, 75, 90])
        .round(3)
        .tolist(),
        "views_3_or_more_on_body": float((views[on] >= 3).mean()),
        "trajectories": int(len(uniq)),
        "labelled_trajectory_length_median": float(
            np.median(traj.lengths[np.flatnonzero(labels.labels >= 0)])
        ),
        "trajectories_majority_agree": float(np.mean(agree_tr > 0.5)),
        "by_part": {},
    }
    for key, mask in (("on_body", on), ("off_body", ~on)):
        ids = np.unique(track[mask])
        ids = ids[traj.lengths[ids] >= 5]
        speed = np.array(
            [
                np.median(
                    np.linalg.norm(np.diff(traj.xyz[traj.rows_of(np.array([i]))], axis=0), axis=1)
                )
                for i in ids
            ]
        ) * float(traj.fps)
        res[f"speed_{key}"] = {
            "trajectories": int(len(ids)),
            "median_speed_percentiles_10_50_90_m_per_s": np.percentile(speed, [10, 50, 90])
            .round(3)
            .tolist()
            if len(ids)
            else [],
            "static_below_2cm_per_s": float(np.mean(speed < 0.02)) if len(ids) else float("nan"),
        }
    for k, n in enumerate(names):
        sel = on & (lab == k)
        if sel.any():
            top = np.bincount(near[sel], minlength=len(names))
            res["by_part"][n] = {
                "n": int(sel.sum()),
                "off_body": int(np.sum(~on & (lab == k))),
                "agree": float(np.mean(near[sel] == k)),
                "most_often_nearest": names[int(top.argmax())],
            }
    res["warnings"] = []
    if instance is not None:
        person = instance[track]  # (N,) per evaluated point-frame
        res["per_person"] = {
            str(int(p)): {
                "labelled_point_frames": int(np.sum(person == p)),
                "on_body_fraction": float(on[person == p].mean()),
                "agreement_on_body": float((lab == near)[(person == p) & on].mean())
                if np.any((person == p) & on)
                else float("nan"),
            }
            for p in np.unique(person)
        }
        people = int(np.sum(np.unique(person) >= 0))
        res["people"] = people
        if people > 1:
            res["warnings"].append(
                f"{people} people are labelled, but the skeleton reference is one person per "
                "frame (each camera's most prominent, triangulated): the whole-run figures mix "
                "people it does not describe; read per_person, the one on the skeleton has the "
                "meaningful figures"
            )
    if res["on_body_fraction"] < 0.5:
        res["warnings"].append(
            f"only {100 * res['on_body_fraction']:.1f} % of the labelled point-frames lie on the "
            "skeleton: several people (the reference describes one), a skeleton that mixes "
            "people across cameras, or labels off the body"
        )
    for w in res["warnings"]:
        logging.getLogger("study_bodyparts").warning("%s", w)
    print(json.dumps(res, indent=1))
    if args.report:
        args.report.write_text(json.dumps(res, indent=2))


if __name__ == "__main__":
    main()
