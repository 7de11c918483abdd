"""Tests of pointtraj.labelset: the labels.toml contract."""

from __future__ import annotations

import numpy as np
import pytest

from pointtraj.errors import FileFormatError, ValidationError
from pointtraj.labelset import BODY_PARTS, LabelSet


def test_default_has_body_parts_then_objects():
    labels = LabelSet.default()
    assert labels.names[: len(BODY_PARTS)] == BODY_PARTS
    assert labels.index("ball") == len(BODY_PARTS)
    assert labels.colors.shape == (len(labels), 3) and labels.colors.dtype == np.uint8
    assert len({tuple(c) for c in labels.colors}) == len(labels)  # distinct colours
    assert labels.kinds[labels.index("ball")] == "object"
    assert labels.classes_of_kind("object").tolist() == [14, 15]


def test_save_load_round_trip(tmp_path):
    base = LabelSet.default()
    labels = LabelSet(
        base.names,
        base.colors,
        base.kinds,
        recognizers={"object-detector": {"sports ball": "ball", "person": "torso"}},
        recognizer_options={"onnx-segmentation": {"model": "seg.onnx", "size": [512, 512]}},
    )
    path = tmp_path / "labels.toml"
    labels.save(path)
    back = LabelSet.load(path)
    assert back == labels
    assert back.mapping("object-detector") == {"sports ball": "ball", "person": "torso"}
    assert back.mapping_indices("object-detector") == {"sports ball": 14, "person": 1}
    assert back.mapping("body-parts") == {}
    assert back.options("onnx-segmentation") == {"model": "seg.onnx", "size": [512, 512]}


def test_load_hand_written_file(tmp_path):
    path = tmp_path / "labels.toml"
    path.write_text(
        '[[classes]]\nname = "head"\ncolor = [255, 0, 0]\n\n'
        '[[classes]]\nname = "ball"\ncolor = [0, 0, 255]\nkind = "object"\n\n'
        '[recognizers.object-detector.map]\n"sports ball" = "ball"\n'
    )
    labels = LabelSet.load(path)
    assert labels.names == ("head", "ball")
    assert labels.kinds == ("body", "object")
    assert labels.colors.tolist() == [[255, 0, 0], [0, 0, 255]]
    assert labels.mapping("object-detector") == {"sports ball": "ball"}


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("", "at least one"),
        (
            '[[classes]]\nname = "a"\ncolor = [1, 2, 3]\n[[classes]]\nname = "a"\ncolor = [1, 2, 3]',
            "duplicate class name 'a'",
        ),
        ('[[classes]]\nname = "a"\ncolor = [1, 2, 300]', r"classes\[0\].color"),
        ('[[classes]]\nname = "a"\ncolor = [1, 2]', r"classes\[0\].color"),
        ('[[classes]]\nname = "a"\ncolor = [1, 2, 3]\nkind = "animal"', r"classes\[0\].kind"),
        ('[[classes]]\nname = "a"\ncolour = [1, 2, 3]', "unknown key 'colour'"),
        (
            '[[classes]]\nname = "a"\ncolor = [1, 2, 3]\n[recognizers.x]\nmap = { p = "b" }',
            "unknown class 'b'",
        ),
        (
            '[[classes]]\nname = "a"\ncolor = [1, 2, 3]\n[[classes]]\ncolor = [1, 2, 3]',
            r"classes\[1\].name",
        ),
        ("[[classes]\n", "invalid TOML"),
    ],
)
def test_load_errors_name_the_file_and_field(tmp_path, text, match):
    path = tmp_path / "labels.toml"
    path.write_text(text)
    with pytest.raises(FileFormatError, match=match) as info:
        LabelSet.load(path)
    assert str(path) in str(info.value)


def test_missing_file(tmp_path):
    with pytest.raises(FileFormatError, match="no such file"):
        LabelSet.load(tmp_path / "labels.toml")


def test_constructor_validation():
    with pytest.raises(ValidationError, match="duplicate"):
        LabelSet(["a", "a"], [[0, 0, 0], [1, 1, 1]])
    with pytest.raises(ValidationError, match=r"colors: expected shape \(2, 3\)"):
        LabelSet(["a", "b"], [[0, 0, 0]])
    with pytest.raises(ValidationError, match="0..255"):
        LabelSet(["a"], [[0, 0, 256]])
    with pytest.raises(ValidationError, match="unknown class"):
        LabelSet(["a"], [[0, 0, 0]], recognizers={"r": {"x": "b"}})
    with pytest.raises(KeyError, match="unknown class 'z'"):
        LabelSet.default().index("z")


def test_joints_round_trip_and_errors(tmp_path):
    """``[[joints]]``: the default set has BODY_JOINTS, they survive save/load, and a joint
    naming an unknown class, the same class twice or without two parts is refused."""
    from pointtraj.labelset import BODY_JOINTS, body_joints

    labels = LabelSet.default()
    assert labels.joints == BODY_JOINTS and len(BODY_JOINTS) == 13
    path = tmp_path / "labels.toml"
    labels.save(path)
    assert "[[joints]]" in path.read_text(encoding="utf-8")
    assert LabelSet.load(path) == labels
    assert body_joints(["torso", "left_thigh", "left_shin"]) == (
        ("left_hip", "torso", "left_thigh"),
        ("left_knee", "left_thigh", "left_shin"),
    )
    head = (
        '[[classes]]\nname = "a"\ncolor = [1, 2, 3]\n[[classes]]\nname = "b"\ncolor = [1, 2, 3]\n'
    )
    for joint, match in [
        ('name = "j"\nparts = ["a", "c"]', "unknown class 'c'"),
        ('name = "j"\nparts = ["a", "a"]', "to itself"),
        ('name = "j"\nparts = ["a"]', r"joints\[0\].parts"),
        ('name = "j"\nparts = ["a", "b"]\nangle = 3', "unknown key 'angle'"),
    ]:
        path.write_text(head + "[[joints]]\n" + joint + "\n", encoding="utf-8")
        with pytest.raises(FileFormatError, match=match) as err:
            LabelSet.load(path)
        assert "labels.toml" in str(err.value)
    with pytest.raises(ValidationError, match="duplicate joint"):
        LabelSet(["a", "b"], [[1, 2, 3]] * 2, joints=[("j", "a", "b"), ("j", "b", "a")])
