"""labels.npz / labels.csv (pointtraj.labelfile): the person ``instance`` and older files."""

from __future__ import annotations

import numpy as np
import pytest

from pointtraj.atomic import save_npz_atomic
from pointtraj.errors import FileFormatError, ValidationError
from pointtraj.labelfile import FORMAT_VERSION, TrajectoryLabels, load_labels, save_labels


def _labels(instance: np.ndarray | None) -> TrajectoryLabels:
    return TrajectoryLabels(
        labels=np.array([0, 1, -1, 0]),
        confidence=np.array([0.9, 0.5, 0.0, 0.7]),
        argmax=np.array([0, 1, -1, 1]),
        class_names=("head", "torso"),
        energy=np.array([3.0, 2.0]),
        params={"smoothness": 0.5},
        instance=instance,
    )


def test_instance_round_trips_through_npz_and_csv(tmp_path):
    path = tmp_path / "labels.npz"
    save_labels(_labels(np.array([1, 0, -1, 1])), path, np.array([0, 2, 0, 5]), [4, 3, 1, 2])
    back = load_labels(path)
    assert back.instance is not None and back.instance.dtype == np.int64
    np.testing.assert_array_equal(back.instance, [1, 0, -1, 1])
    np.testing.assert_array_equal(back.labels, [0, 1, -1, 0])
    lines = (tmp_path / "labels.csv").read_text().splitlines()
    assert lines[0] == "track_id,label,label_name,confidence,first_frame,length,instance"
    assert lines[1] == "0,0,head,0.9000,0,4,1"
    assert lines[3] == "2,-1,,0.0000,0,1,-1"


def test_without_instance_the_csv_column_is_minus_one(tmp_path):
    path = tmp_path / "labels.npz"
    save_labels(_labels(None), path)
    assert load_labels(path).instance is None
    rows = (tmp_path / "labels.csv").read_text().splitlines()[1:]
    assert [r.rsplit(",", 1)[1] for r in rows] == ["-1"] * 4


def test_older_labels_without_instance_still_load(tmp_path):
    """A labels.npz written before instances (no ``instance`` array) loads with instance None."""
    path = tmp_path / "labels.npz"
    save_npz_atomic(
        path,
        format_version=np.int64(FORMAT_VERSION),
        labels=np.array([0, 1], np.int64),
        confidence=np.array([1.0, 1.0], np.float32),
        argmax=np.array([0, 1], np.int64),
        class_names=np.array(["head", "torso"]),
    )
    back = load_labels(path)
    assert back.instance is None
    np.testing.assert_array_equal(back.labels, [0, 1])


def test_bad_instance_is_refused(tmp_path):
    with pytest.raises(ValidationError, match="instance: expected shape"):
        _labels(np.array([0, 1]))
    with pytest.raises(ValidationError, match="instance: ids"):
        _labels(np.array([0, -2, 0, 0]))
    path = tmp_path / "labels.npz"
    save_npz_atomic(
        path,
        format_version=np.int64(FORMAT_VERSION),
        labels=np.array([0, 1], np.int64),
        class_names=np.array(["head", "torso"]),
        instance=np.array([0, 0, 0], np.int64),
    )
    with pytest.raises(FileFormatError, match="instance"):
        load_labels(path)
