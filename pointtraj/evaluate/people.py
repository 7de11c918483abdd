"""The report's "People" section: the person instances of ``labels.npz`` (and their accuracy).

Written when ``labels.npz`` has person ids (``instance``, :mod:`pointtraj.instances`): how many
people, and per person the labelled trajectories and the body parts; on a synthetic capture
also the instance accuracy against the figures (:func:`pointtraj.instances.instance_accuracy`,
on the trajectories labelled with a body part that lie on a figure) and per true person.

It says so when the figures elsewhere in the report pool people: the label accuracy per class
counts "head" of every person together, which is right for the classes but says nothing about
who is who. A labelling without person ids, on a capture whose ground truth has several figures,
gets a warning instead of a silent single-person reading.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .report import Section

__all__ = ["people_section"]


def people_section(
    labels: Any,
    person_classes: np.ndarray,
    truth: np.ndarray | None,
    metrics: dict[str, Any],
) -> Section | None:
    """The "People" section, or None when there is nothing to say.

    Parameters
    ----------
    labels : TrajectoryLabels
        With or without ``instance``.
    person_classes : (P,) int ndarray
        The body-part classes (:func:`pointtraj.instances.person_classes`).
    truth : (M,) int ndarray or None
        True person per trajectory (-1: on no figure), from
        :func:`pointtraj.evaluate.groundtruth.true_instances`; None without ground truth.
    metrics : dict
        Gains ``people.count``, ``people.<id>.trajectories`` and, with ``truth``,
        ``people.instance_accuracy``, ``people.true_count``, ``people.per_true.<id>``.
    """
    from ..instances import instance_accuracy, match_instances

    true_people = 0 if truth is None else len(np.unique(truth[truth >= 0]))
    if labels.instance is None:
        if true_people > 1:
            metrics["people.warning"] = "no person ids"
            return Section(
                "People",
                f"**Warning**: the ground truth has {true_people} figures, but `labels.npz` has "
                "no person ids (written before instances; rerun `pointtraj label`): every "
                "figure above pools the people, and nothing here says who is who.",
            )
        return None
    inst = labels.instance
    body = np.isin(labels.labels, person_classes)
    n = int(inst.max(initial=-1)) + 1
    metrics["people.count"] = n
    lines = [
        f"{n} people (person ids of `labels.npz`, from the rigid groups of the affinity graph "
        "and the recogniser's person masks); "
        f"{int((body & (inst < 0)).sum())} trajectories labelled with a body part are on no "
        "person.",
        "",
        "| person | trajectories | body parts (largest first) |",
        "|---|---|---|",
    ]
    names = np.array(labels.class_names)
    for p in range(n):
        mine = inst == p
        metrics[f"people.{p}.trajectories"] = int(mine.sum())
        counts = np.bincount(labels.labels[mine & (labels.labels >= 0)], minlength=len(names))
        top = [f"{names[k]} {counts[k]}" for k in np.argsort(-counts)[:4] if counts[k]]
        lines.append(f"| {p} | {int(mine.sum())} | {', '.join(top)} |")
    if truth is not None:
        judged = body & (truth >= 0)
        if judged.any():
            acc = instance_accuracy(inst[judged], truth[judged])
            metrics["people.instance_accuracy"] = acc
            metrics["people.true_count"] = true_people
            match = match_instances(inst[judged], truth[judged])
            mapped = np.array([match.get(int(i), -2) if i >= 0 else -2 for i in inst[judged]])
            per = []
            for q in np.unique(truth[judged]):
                sel = truth[judged] == q
                share = float((mapped[sel] == q).mean())
                metrics[f"people.per_true.{int(q)}"] = share
                per.append(f"figure {int(q)}: {100 * share:.1f} % of {int(sel.sum())}")
            lines += [
                "",
                f"Instance accuracy: **{100 * acc:.1f} %** of the {int(judged.sum())} "
                "trajectories labelled with a body part that lie on a figure have the right "
                f"person (best one-to-one matching of person ids to the {true_people} figures; "
                "no person counts as wrong). Per figure: " + "; ".join(per) + ".",
            ]
    if n > 1:
        lines += [
            "",
            "The label accuracy and the other studies pool the people (a class is a body part "
            "of anyone); the person ids are this section's.",
        ]
    return Section("People", "\n".join(lines))
