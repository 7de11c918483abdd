"""Study: people as instances on a synthetic capture with several figures (``docs/labeling.md``).

Runs the pipeline's own stages on CAPTURE into WORK, each only when its output is missing:
the trajectories (``--source gt``: the ground-truth trajectories, ``pointtraj gt-trajectories``;
``--source reconstruct``: ``pointtraj reconstruct`` with the defaults, optionally on
``--frames A:B``), the semantic map (the simulated recogniser, default noise, which gives person
masks from ``gt/instances``), the affinity graph and the labelling (which assigns the
instances, :mod:`pointtraj.instances`). Then it measures, on the labelled body-part
trajectories (predicted class of kind ``body``) that lie on a figure:

- **instance accuracy**: the share whose person id is right, after the best one-to-one
  matching of predicted to true ids (:func:`pointtraj.instances.instance_accuracy`; -1 is
  wrong); per person too;
- the same without the person masks (rigid groups alone), as an ablation, and with other
  ``min_weight`` (``--min-weight``, the sweep);
- how many people were found, and how many labelled body-part trajectories got no person.

The truth is the ground-truth point's figure for ground-truth trajectories, and otherwise the
majority of the instance maps at the trajectory's visible projections
(:func:`pointtraj.evaluate.groundtruth.true_instances`).

Usage::

    pointtraj synth --preset ring8 --scene two_people --frames 40 --out CAPTURE --workers 1
    .venv/bin/python benchmarks/study_instances.py CAPTURE WORK [--source reconstruct] \\
        [--frames 0:20] [--report instances.json]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import time
from pathlib import Path

import numpy as np


def run_stages(capture: Path, work: Path, source: str, frames: str | None) -> dict[str, float]:
    """Run the missing stages; returns the seconds each took."""
    from pointtraj import stages

    took = {}
    t0 = time.perf_counter()
    if not (work / "trajectories.npz").is_file():
        if source == "gt":
            stages.ground_truth_work(work, capture)
        else:
            stages.reconstruct_work(work, capture, frames=frames)
        took["trajectories"] = time.perf_counter() - t0
    steps = (
        ("semantic_map.npz", lambda: stages.semantics_work(work, capture=capture)),
        ("affinity.npz", lambda: stages.affinity_work(work)),
        ("labels.npz", lambda: stages.label_work(work)),
    )
    for name, call in steps:
        if not (work / name).is_file():
            t0 = time.perf_counter()
            call()
            took[name] = time.perf_counter() - t0
    return took


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("capture", type=Path)
    ap.add_argument("work", type=Path)
    ap.add_argument("--source", choices=["gt", "reconstruct"], default="gt")
    ap.add_argument("--frames", default=None, help="A:B, with --source reconstruct")
    ap.add_argument("--report", type=Path, default=None)
    ap.add_argument("--min-weight", type=float, nargs="*", default=[0.05, 0.2, 0.3, 0.5, 0.7, 0.9])
    ap.add_argument("-v", "--verbose", action="store_true")
    args = ap.parse_args()
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING)

    from pointtraj.affinity import load_affinity
    from pointtraj.evaluate.groundtruth import true_instances
    from pointtraj.instances import (
        InstanceConfig,
        assign_instances,
        instance_accuracy,
        match_instances,
        person_classes,
    )
    from pointtraj.labelfile import load_labels
    from pointtraj.labelset import LabelSet
    from pointtraj.semantics.semantic_map import SemanticMap
    from pointtraj.stages import LabelStageConfig
    from pointtraj.trajectories import Trajectories

    took = run_stages(args.capture, args.work, args.source, args.frames)
    traj = Trajectories.load(args.work / "trajectories.npz")
    labels = load_labels(args.work / "labels.npz")
    smap = SemanticMap.load(args.work / "semantic_map.npz")
    graph = load_affinity(args.work / "affinity.npz")
    if labels.instance is None:
        raise SystemExit(f"{args.work / 'labels.npz'} has no instance: rerun `pointtraj label`")
    true, source = true_instances(args.capture, traj)
    kinds = LabelSet.load(args.capture / "labels.toml").kinds
    people = person_classes(labels.class_names, kinds)
    body = np.isin(labels.labels, people)  # labelled as a body part
    judged = body & (true >= 0)  # ... and on a figure

    cfg = LabelStageConfig().instances

    def accuracy(pred: np.ndarray) -> float:
        return instance_accuracy(pred[judged], true[judged])

    no_masks = assign_instances(
        labels.labels, people, graph.row, graph.col, graph.weight, None, cfg
    )
    pred = labels.instance
    match = match_instances(pred[judged], true[judged])  # predicted id -> true id
    mapped = np.array([match.get(int(i), -2) if i >= 0 else -2 for i in pred])  # (M,)
    per_person = {}
    for p in np.unique(true[judged]):
        sel = judged & (true == p)
        per_person[int(p)] = {
            "trajectories": int(sel.sum()),
            "accuracy": float((mapped[sel] == p).mean()),
        }
    res = {
        "capture": str(args.capture),
        "source": args.source,
        "truth": source,
        "trajectories": int(traj.num_trajectories),
        "labelled_body_part_trajectories": int(body.sum()),
        "judged_trajectories": int(judged.sum()),
        "labelled_body_part_off_figures": int((body & (true < 0)).sum()),
        "people_found": int(pred.max(initial=-1)) + 1,
        "people_true": len(per_person),
        "no_person_share": float((pred[judged] < 0).mean()) if judged.any() else float("nan"),
        "instance_accuracy": accuracy(pred),
        "per_person": per_person,
        "without_masks": accuracy(no_masks),
        "people_without_masks": int(no_masks.max(initial=-1)) + 1,
        "min_weight_sweep": {
            str(w): accuracy(
                assign_instances(
                    labels.labels,
                    people,
                    graph.row,
                    graph.col,
                    graph.weight,
                    smap.person_votes,
                    dataclasses.replace(cfg, min_weight=w),
                )
            )
            for w in args.min_weight
        },
        "person_votes": int(len(smap.person_votes)),
        "affinity_edges": int(graph.num_edges),
        "config": dataclasses.asdict(InstanceConfig()),
        "seconds": took,
    }
    print(json.dumps(res, indent=2))
    if args.report is not None:
        args.report.write_text(json.dumps(res, indent=2) + "\n")


if __name__ == "__main__":
    main()
