"""Study: contrast-sensitive smoothing in the labelling, on stored work folders (not kept).

The labelling's pairwise term is the paper's: ``λ A_ij [l_i != l_j]``. A contrast-sensitive
Potts term (GrabCut's) also weakens an edge where the two trajectories' recognition differs:
``A_ij exp(-c d_ij^2 / (2 <d^2>))``, ``d_ij`` the total-variation distance between their L3D rows
(with the background label's constant column, each row normalised to sum 1) and ``<d^2>`` its
mean over the edges it applies to. It applies between trajectories that both pool at least
``support_frames`` frames (shorter ones keep the whole affinity, so that their neighbours still
correct them).

For each work folder of a synthetic capture it prints the report's label accuracy over the
judged trajectories, of argmax view pooling and of the cut at each λ and contrast ``c`` (0: the
library's labelling), on the work folder's own affinity graph and semantic map. (A real
capture's check, ``study_bodyparts.py``, reads a work folder's labels.npz, which this study
does not write.) The figures of ``docs/labeling.md``, "Contrast-sensitive smoothing".

Usage::

    .venv/bin/python benchmarks/study_label_contrast.py WORK [WORK ...] --contrast 0 0.5 1
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np


def contrast_weights(
    l3d: np.ndarray,
    row: np.ndarray,
    col: np.ndarray,
    weight: np.ndarray,
    gated: np.ndarray,
    contrast: float,
) -> np.ndarray:
    """(E,) affinities times ``exp(-contrast d^2 / (2 <d^2>))`` between gated trajectories.

    ``l3d`` (M, K) with NaN as 0 (a row of zeros counts as uniform), ``row``/``col``/``weight``
    (E,) the graph, ``gated`` (M,) bool: the trajectories whose edges take part.
    """
    on = gated[row] & gated[col]
    out = np.asarray(weight, np.float64).copy()
    if contrast == 0 or not on.any():
        return out
    p = np.nan_to_num(np.asarray(l3d, np.float64), nan=0.0)
    total = p.sum(axis=1, keepdims=True)
    p = np.where(total > 0, p / np.where(total > 0, total, 1.0), 1.0 / p.shape[1])
    d = 0.5 * np.abs(p[row[on]] - p[col[on]]).sum(axis=1)
    mean_sq = float(np.mean(d**2))
    if mean_sq > 0:
        out[on] *= np.exp(-contrast * d**2 / (2.0 * mean_sq))
    return out


def study(work: Path, lambdas: list[float], contrasts: list[float]) -> None:
    from pointtraj.affinity import load_affinity
    from pointtraj.evaluate.groundtruth import true_labels
    from pointtraj.evaluate.metrics import label_accuracy
    from pointtraj.labeling import LabelingConfig, argmax_labels, label_trajectories
    from pointtraj.semantics.semantic_map import SemanticMap
    from pointtraj.trajectories import Trajectories
    from pointtraj.workdir import WorkFolder

    wf = WorkFolder(work)
    traj = Trajectories.load(wf.trajectories)
    smap = SemanticMap.load(wf.semantic_map)
    truth, source = true_labels(wf.capture_path(), traj)
    g = load_affinity(wf.affinity)
    l3d = np.asarray(smap.L3D["view"], np.float64)
    count = np.asarray(smap.count["view"], np.float64)
    K = l3d.shape[1]
    fg = truth >= 0

    def acc(labels: np.ndarray) -> str:
        return f"{100 * label_accuracy(labels[fg], truth[fg], K).overall:.2f}"

    base = LabelingConfig()
    with_bg = np.column_stack([np.nan_to_num(l3d, nan=0.0), np.full(len(l3d), base.background)])
    gated = count >= base.support_frames
    print(
        f"{work} ({source} labels): {int(fg.sum())} judged, argmax view pooling "
        f"{acc(argmax_labels(l3d, base.background))} %"
    )
    print("| λ | " + " | ".join(f"c = {c:g}" for c in contrasts) + " |")
    print("|---|" + "---|" * len(contrasts))
    for lam in lambdas:
        cells = []
        for c in contrasts:
            w = contrast_weights(with_bg, g.row, g.col, g.weight, gated, c)
            cfg = LabelingConfig(smoothness=lam)
            cells.append(acc(label_trajectories(l3d, g.row, g.col, w, cfg, support=count).labels))
        print(f"| {lam:g} | " + " | ".join(cells) + " |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("work", type=Path, nargs="+", help="work folders of synthetic captures")
    ap.add_argument("--lambda", dest="lambdas", type=float, nargs="+", default=[0.5, 1.0])
    ap.add_argument("--contrast", type=float, nargs="+", default=[0.0, 0.5, 1.0])
    args = ap.parse_args()
    for work in args.work:
        study(work, args.lambdas, args.contrast)


if __name__ == "__main__":
    main()
