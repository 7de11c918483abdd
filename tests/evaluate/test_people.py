"""The report's "People" section (pointtraj.evaluate.people)."""

from __future__ import annotations

import numpy as np

from pointtraj.evaluate.people import people_section
from pointtraj.labelfile import TrajectoryLabels


def _labels(instance):
    labels = np.array([0, 1, 0, 1, 2, -1, 0])  # classes head, torso (people), ball
    return TrajectoryLabels(
        labels=labels,
        confidence=np.ones(7),
        argmax=labels,
        class_names=("head", "torso", "ball"),
        instance=instance,
    )


def test_people_and_instance_accuracy_per_figure():
    metrics = {}
    truth = np.array([4, 4, 9, 9, -1, -1, 9])  # figures 4 and 9; the ball is on no figure
    section = people_section(
        _labels(np.array([1, 1, 0, 0, -1, -1, 1])), np.array([0, 1]), truth, metrics
    )
    assert section.title == "People"
    assert metrics["people.count"] == 2 and metrics["people.true_count"] == 2
    assert metrics["people.0.trajectories"] == 2 and metrics["people.1.trajectories"] == 3
    assert metrics["people.instance_accuracy"] == 0.8  # trajectory 6 is on the wrong person
    assert metrics["people.per_true.4"] == 1.0 and metrics["people.per_true.9"] == 2 / 3
    assert "80.0 %" in section.body and "pool the people" in section.body


def test_no_person_ids_on_several_figures_is_a_warning_not_silence():
    metrics = {}
    truth = np.array([4, 4, 9, 9, -1, -1, 9])
    section = people_section(_labels(None), np.array([0, 1]), truth, metrics)
    assert "Warning" in section.body and metrics["people.warning"] == "no person ids"
    assert people_section(_labels(None), np.array([0, 1]), np.zeros(7, np.int64), {}) is None
    assert people_section(_labels(None), np.array([0, 1]), None, {}) is None
    # without ground truth: the people, no accuracy
    metrics = {}
    section = people_section(_labels(np.array([0, 0, 0, -1, -1, -1, 0])), [0, 1], None, metrics)
    assert metrics == {"people.count": 1, "people.0.trajectories": 4}
    assert "Instance accuracy" not in section.body
