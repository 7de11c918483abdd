"""Study: why the graph cut helps or hurts on a work folder: the purity of its affinity graph.

On a synthetic work folder (reconstructed or ground-truth trajectories, with a semantic map) it
measures, against the ground-truth label of each trajectory (``true_labels``: the point's own
label on a ground-truth store, else the majority of the label maps at its projections):

1. **The graph** of the defaults (and of ``--affinity KEY=VALUE`` variants): edges, the share of
   the edge weight between two ground-truth classes, the mean weighted degree, the share of
   trajectories whose affinity goes mostly to other classes, and the mean affinity A of
   same-class and cross-class edges by shared lifetime.
2. **What the trajectories allow a rigidity test to see**, on the candidate pairs closer than
   10 cm: the spread of their distance over the shared lifetime (no transform involved), for
   same-class and cross-class pairs; and how much of the frame-to-frame change of that distance
   between same-class neighbours happens at steps where a trajectory's set of observing cameras
   changes (``affinity.view_breaks``: the point is re-triangulated from other cameras).
3. **What the cut could do with a purer graph**: the cut's accuracy on the default graph, on it
   without a random 25/50/75 % of its cross-class edges, and without all of them (an oracle),
   with the paper's data cost (``support_frames = 0``).
4. **Labelling variants**: λ and ``support_frames`` (the data cost weighed by pooled frames).
5. With ``--part-motion GT_WORK`` (a ground-truth store of the same capture, ``pointtraj
   gt-trajectories``): the graph and the cut when every trajectory's local rotations are the
   exact motion of its ground-truth part (fitted on that part's ground-truth points), which
   separates what the estimated transforms cost from what the trajectories themselves allow.

Usage (the figures of ``docs/labeling.md``)::

    .venv/bin/python benchmarks/study_affinity_purity.py WORK [--affinity view_breaks=true] \
        [--part-motion GT_WORK]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import numpy as np


def load(work: Path):
    """(trajectories, truth (M,), L3D (M, K), pooled frames (M,), scaled AffinityConfig)."""
    from pointtraj.affinity import AffinityConfig
    from pointtraj.evaluate.groundtruth import true_labels
    from pointtraj.scale import scale_lengths, work_scene_scale
    from pointtraj.semantics.semantic_map import SemanticMap
    from pointtraj.trajectories import Trajectories
    from pointtraj.workdir import WorkFolder

    wf = WorkFolder(work)
    traj = Trajectories.load(wf.trajectories)
    smap = SemanticMap.load(wf.semantic_map)
    truth, source = true_labels(wf.capture_path(), traj)
    cfg = scale_lengths(AffinityConfig(), work_scene_scale(wf), log=False)
    print(
        f"# {work}: {traj.num_trajectories} trajectories ({source} labels), "
        f"{int((truth >= 0).sum())} on labelled parts, median length "
        f"{np.median(traj.lengths):.0f} of {traj.num_frames} frames"
    )
    return traj, truth, smap.L3D["view"].astype(np.float64), smap.count["view"], cfg


def shared_frames(traj, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    return (
        np.minimum(traj.last_frame[i], traj.last_frame[j])
        - np.maximum(traj.first_frame[i], traj.first_frame[j])
        + 1
    )


def graph_purity(traj, truth: np.ndarray, g, name: str) -> None:
    i, j, w = g.row, g.col, g.weight
    both = (truth[i] >= 0) & (truth[j] >= 0)
    cross = both & (truth[i] != truth[j])
    M = traj.num_trajectories
    fg = truth >= 0
    deg = np.bincount(i, w, M) + np.bincount(j, w, M)
    same_w = np.bincount(i[both & ~cross], w[both & ~cross], M)
    same_w += np.bincount(j[both & ~cross], w[both & ~cross], M)
    diff_w = np.bincount(i[cross], w[cross], M) + np.bincount(j[cross], w[cross], M)
    print(f"\n## graph: {name}\n")
    print(
        f"edges {g.num_edges}; cross-class share of the weight {w[cross].sum() / w[both].sum():.3f}; "
        f"mean weighted degree {deg[fg].mean():.2f}; trajectories with most affinity to other "
        f"classes {(diff_w[fg] > same_w[fg]).mean():.3f}"
    )
    n = shared_frames(traj, i, j)
    print("| shared frames | edges | cross-class share of weight | mean A same | mean A cross |")
    print("|---|---|---|---|---|")
    for lo, hi in ((2, 5), (5, 10), (10, 20), (20, 40), (40, 10**6)):
        m = both & (n >= lo) & (n < hi)
        if not m.any():
            continue
        a_s = g.affinity[m & ~cross].mean() if (m & ~cross).any() else np.nan
        a_c = g.affinity[m & cross].mean() if (m & cross).any() else np.nan
        print(
            f"| {lo}-{hi - 1 if hi < 10**6 else 'all'} | {m.sum()} | "
            f"{w[m & cross].sum() / w[m].sum():.3f} | {a_s:.2f} | {a_c:.2f} |"
        )


def rigidity_evidence(traj, truth: np.ndarray, cfg) -> None:
    from pointtraj.affinity import _shared_chunks, candidate_pairs, view_breaks
    from pointtraj.trajectories import OBSERVED_MIN

    rng = np.random.default_rng([cfg.seed, 0])
    i, j, d = candidate_pairs(traj, cfg.epsilon_a, cfg.near_neighbors, cfg.max_neighbors, rng)
    both = (truth[i] >= 0) & (truth[j] >= 0)
    near = both & (d < 0.1)
    cross = truth[i] != truth[j]
    brk = view_breaks(traj)
    spread = np.zeros(i.size)
    steps, at_break = [], []
    for pid, ri, rj in _shared_chunks(traj, i, j):
        dist = np.linalg.norm(traj.xyz[ri].astype(np.float64) - traj.xyz[rj], axis=1)
        st = np.flatnonzero(np.r_[True, pid[1:] != pid[:-1]])
        spread[pid[st]] = np.maximum.reduceat(dist, st) - np.minimum.reduceat(dist, st)
        k = np.flatnonzero(np.r_[False, pid[1:] == pid[:-1]] & (near & ~cross)[pid])
        steps.append(np.abs(dist[k] - dist[k - 1]))
        at_break.append(brk[ri[k]] | brk[rj[k]])
    print("\n## rigidity evidence, candidate pairs closer than 10 cm\n")
    print(
        "| pairs | count | distance spread over the shared lifetime (mm): p25 | median | p75 | p90 |"
    )
    print("|---|---|---|---|---|---|")
    for name, m in (("same class", near & ~cross), ("cross class", near & cross)):
        q = np.percentile(spread[m], [25, 50, 75, 90]) * 1000 if m.any() else [np.nan] * 4
        print(f"| {name} | {int(m.sum())} | " + " | ".join(f"{v:.1f}" for v in q) + " |")
    steps, at_break = np.concatenate(steps), np.concatenate(at_break)
    if steps.size:
        print(
            f"\nsame-class steps at a change of observing cameras: {at_break.mean():.3f} of "
            f"{steps.size}; they hold {steps[at_break].sum() / steps.sum():.3f} of the total "
            f"|change of distance|; share above 2 mm: {(steps[at_break] > 0.002).mean():.3f} "
            f"at a change, {(steps[~at_break] > 0.002).mean():.3f} elsewhere "
            f"(observed: visibility >= {OBSERVED_MIN}/255)"
        )


def cut_study(truth, l3d, count, g, lambdas, supports, seed: int) -> None:
    from pointtraj.labeling import LabelingConfig, argmax_labels, label_trajectories

    fg = truth >= 0

    def acc(labels: np.ndarray) -> float:
        return 100 * float((labels[fg] == truth[fg]).mean())

    def cut(keep: np.ndarray, **over) -> float:
        res = label_trajectories(
            l3d, g.row[keep], g.col[keep], g.weight[keep], LabelingConfig(**over), support=count
        )
        return acc(res.labels)

    allk = np.ones(g.num_edges, bool)
    both = (truth[g.row] >= 0) & (truth[g.col] >= 0)
    cross = both & (truth[g.row] != truth[g.col])
    print(f"\n## the cut ({int(fg.sum())} trajectories judged)\n")
    print(f"argmax view-pooled L3D: {acc(argmax_labels(l3d)):.1f} %")
    print(f"graph cut, LabelingConfig defaults: {cut(allk):.1f} %")
    print(
        f"graph cut, the paper's data cost (support_frames = 0): {cut(allk, support_frames=0):.1f} %"
    )
    rng = np.random.default_rng(seed)
    for f in (0.25, 0.5, 0.75, 1.0):
        keep = ~(cross & (rng.random(g.num_edges) < f))
        share = g.weight[keep & cross].sum() / g.weight[keep & both].sum()
        print(
            f"without {100 * f:.0f} % of the cross-class edges (cross share {share:.3f}): "
            f"{cut(keep, support_frames=0):.1f} %"
        )
    print("\n| support_frames | " + " | ".join(f"λ = {lam:g}" for lam in lambdas) + " |")
    print("|---|" + "---|" * len(lambdas))
    for sf in supports:
        cells = [f"{cut(allk, smoothness=lam, support_frames=sf):.1f}" for lam in lambdas]
        print(f"| {sf:g} | " + " | ".join(cells) + " |")


def part_motion_study(traj, truth, l3d, count, cfg, gt_work: Path) -> None:
    """Graph and cut with each trajectory's rotations taken from its true part's motion."""
    from study_drift import part_motion  # (this script's folder is on sys.path)

    import pointtraj.affinity as affinity
    from pointtraj.evaluate.groundtruth import true_labels
    from pointtraj.labeling import LabelingConfig, label_trajectories
    from pointtraj.trajectories import Trajectories
    from pointtraj.workdir import WorkFolder

    wf = WorkFolder(gt_work)
    gt = Trajectories.load(wf.trajectories)
    gl, source = true_labels(wf.capture_path(), gt)
    if source != "ground truth":
        raise SystemExit(f"{gt_work}: not the capture's ground-truth trajectories")
    K, T = int(max(gl.max(), truth.max())) + 1, traj.num_frames
    part_rot = part_motion(gt, gl, K, T)[0]
    P = traj.num_point_frames
    rot = np.full((P, 3, 3), np.nan, np.float32)
    tr, tf = traj.row_track, traj.row_frame
    ok = (truth[tr] >= 0) & (tf >= 1) & (np.arange(P) != traj.offsets[tr])
    rot[ok] = part_rot[truth[tr[ok]], tf[ok]]
    exact = affinity.LocalTransforms(rot, np.zeros(P, np.int16))
    g = affinity.compute_affinity(traj, cfg, transforms=exact)
    graph_purity(traj, truth, g, "every trajectory moved by its true part's exact rotations")
    fg = truth >= 0
    res = label_trajectories(l3d, g.row, g.col, g.weight, LabelingConfig(support_frames=0))
    print(
        "\ngraph cut on it, the paper's data cost: "
        f"{100 * (res.labels[fg] == truth[fg]).mean():.1f} %"
    )


def main() -> None:
    from pointtraj.affinity import compute_affinity

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("work", type=Path, help="work folder of a synthetic capture")
    ap.add_argument(
        "--affinity",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="AffinityConfig override of a variant graph (repeatable)",
    )
    ap.add_argument("--lambda", dest="lambdas", type=float, nargs="+", default=[0.25, 0.5, 1.0])
    ap.add_argument(
        "--support-frames", dest="supports", type=float, nargs="+", default=[0.0, 5.0, 10.0, 20.0]
    )
    ap.add_argument(
        "--part-motion",
        type=Path,
        metavar="GT_WORK",
        help="ground-truth work folder of the same capture (study 5)",
    )
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    traj, truth, l3d, count, cfg = load(args.work)
    t0 = time.perf_counter()
    g = compute_affinity(traj, cfg)
    print(f"(affinity {time.perf_counter() - t0:.1f} s)")
    graph_purity(traj, truth, g, "defaults")
    if args.affinity:
        over = {k: json.loads(v) for k, v in (a.split("=", 1) for a in args.affinity)}
        graph_purity(
            traj,
            truth,
            compute_affinity(traj, dataclasses.replace(cfg, **over)),
            ", ".join(args.affinity),
        )
    rigidity_evidence(traj, truth, cfg)
    cut_study(truth, l3d, count, g, args.lambdas, args.supports, args.seed)
    if args.part_motion is not None:
        part_motion_study(traj, truth, l3d, count, cfg, args.part_motion)


if __name__ == "__main__":
    main()
