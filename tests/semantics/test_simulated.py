"""Tests of the simulated recogniser (pointtraj.semantics.recognizers.simulated)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from helpers import labelmaps

from pointtraj.errors import FileFormatError, ValidationError
from pointtraj.labelset import LabelSet
from pointtraj.semantics.recognizers import ImageContext, make_recognizer
from pointtraj.semantics.recognizers.simulated import (
    INDEPENDENT_PRESETS,
    NOISE_PRESETS,
    SimulatedNoise,
    SimulatedRecognizer,
    confusion_tables,
    simulate_confidences,
)

LABELS = LabelSet.default()
NONE = INDEPENDENT_PRESETS["none"]  # the independent model: 8-pixel cells, no noise


def figure_map(H=96, W=128):
    """A label map with a torso, both hands and forearms, and a ball (a disc)."""
    return labelmaps.figure_map(LABELS, H, W)


def test_noise_free_output_is_the_area_averaged_one_hot_map():
    rng = np.random.default_rng(0)
    lab = rng.integers(-1, 3, size=(20, 30)).astype(np.int16)
    L = simulate_confidences(lab, ["a", "b", "c"], noise=NONE)
    assert L.shape == (3, 4, 3) and L.dtype == np.float32  # ceil(20 / 8), ceil(30 / 8)
    rows = np.arange(20) * 3 // 20
    cols = np.arange(30) * 4 // 30
    for y in range(3):
        for x in range(4):
            cell = lab[np.ix_(rows == y, cols == x)]
            expected = [(cell == k).mean() for k in range(3)]
            np.testing.assert_allclose(L[y, x], expected, atol=1e-6)


def test_deterministic_per_camera_and_frame():
    lab = figure_map()
    kw = dict(class_names=LABELS.names, kinds=LABELS.kinds, noise=INDEPENDENT_PRESETS["high"])
    a = simulate_confidences(lab, camera="c01", frame=3, **kw)
    np.testing.assert_array_equal(a, simulate_confidences(lab, camera="c01", frame=3, **kw))
    assert not np.array_equal(a, simulate_confidences(lab, camera="c02", frame=3, **kw))
    assert not np.array_equal(a, simulate_confidences(lab, camera="c01", frame=4, **kw))
    assert not np.array_equal(a, simulate_confidences(lab, camera="c01", frame=3, seed=1, **kw))
    assert a.min() >= 0.0 and a.max() <= 1.0


def test_objects_become_boxes_at_one_confidence():
    lab = figure_map()
    noise = dataclasses.replace(NONE, peak_min=0.7, peak_max=0.9)
    L = simulate_confidences(lab, LABELS.names, LABELS.kinds, noise, camera="c", frame=0)
    ball = L[:, :, LABELS.index("ball")]
    # The disc spans pixels 100..119 x 70..89 -> cells 12..14 x 8..11 (8-pixel cells).
    box = ball[8:12, 12:15]
    assert np.all(box == box[0, 0]) and 0.7 <= box[0, 0] <= 0.9
    outside = ball.copy()
    outside[8:12, 12:15] = 0
    assert outside.max() == 0


def test_confusions():
    lab = figure_map()
    lh, rh, lf = (LABELS.index(n) for n in ("left_hand", "right_hand", "left_forearm"))
    cell = (70 // 8, 40 // 8)  # inside the left hand
    swap = simulate_confidences(
        lab, LABELS.names, LABELS.kinds, dataclasses.replace(NONE, p_swap=1.0)
    )
    assert swap[cell][rh] == 1.0 and swap[cell][lh] == 0.0
    flip = simulate_confidences(
        lab, LABELS.names, LABELS.kinds, dataclasses.replace(NONE, p_flip=1.0)
    )
    assert flip[cell][rh] == 1.0
    nbr = simulate_confidences(
        lab, LABELS.names, LABELS.kinds, dataclasses.replace(NONE, p_neighbour=1.0)
    )
    assert nbr[cell][lf] == 1.0 and nbr[cell][lh] == 0.0
    miss = simulate_confidences(
        lab, LABELS.names, LABELS.kinds, dataclasses.replace(NONE, p_miss=1.0)
    )
    assert miss.max() == 0.0


def test_confusion_rates_follow_the_parameters():
    """Over many views, the left hand is reported right/neighbour at about the set rates."""
    lab = figure_map()
    noise = dataclasses.replace(NONE, p_swap=0.2, p_neighbour=0.3, hold_frames=1)
    lh, rh, lf = (LABELS.index(n) for n in ("left_hand", "right_hand", "left_forearm"))
    cell = (70 // 8, 40 // 8)
    outcomes = np.array(
        [
            np.argmax(
                simulate_confidences(lab, LABELS.names, LABELS.kinds, noise, camera=f"c{i}")[cell]
            )
            for i in range(400)
        ]
    )
    assert abs(np.mean(outcomes == rh) - 0.2) < 0.06
    assert abs(np.mean(outcomes == lf) - 0.8 * 0.3) < 0.06
    assert abs(np.mean(outcomes == lh) - 0.8 * 0.7) < 0.07


def test_confusions_persist_within_a_frame_block():
    lab = figure_map()
    noise = dataclasses.replace(NONE, p_swap=0.5, p_neighbour=0.5, hold_frames=1000)
    maps = [
        simulate_confidences(lab, LABELS.names, LABELS.kinds, noise, camera="c7", frame=t)
        for t in range(5)
    ]
    for m in maps[1:]:
        np.testing.assert_array_equal(m, maps[0])


def test_false_positives_and_noise():
    lab = np.full((64, 64), -1, np.int16)
    fp = simulate_confidences(
        lab, LABELS.names, LABELS.kinds, dataclasses.replace(NONE, fp_rate=20.0), camera="x"
    )
    assert fp.max() >= 0.3  # boxes appear on an empty image
    noisy = simulate_confidences(
        lab, LABELS.names, LABELS.kinds, dataclasses.replace(NONE, noise_std=0.05)
    )
    assert 0.02 < noisy.mean() < 0.06


def test_confusion_tables():
    mirror, nbr = confusion_tables(LABELS.names)
    assert LABELS.names[mirror[LABELS.index("left_shin")]] == "right_shin"
    assert mirror[LABELS.index("ball")] == LABELS.index("ball")
    names = {LABELS.names[j] for j in nbr[LABELS.index("left_forearm")]}
    assert names == {"left_upper_arm", "left_hand"}
    names = {LABELS.names[j] for j in nbr[LABELS.index("torso")]}
    assert names == {"head", "left_upper_arm", "right_upper_arm", "left_thigh", "right_thigh"}


def test_errors():
    with pytest.raises(ValidationError, match=r"class indices must be in -1..1"):
        simulate_confidences(np.full((4, 4), 2, np.int16), ["a", "b"])
    with pytest.raises(ValidationError, match="unknown preset 'loud'"):
        simulate_confidences(np.zeros((4, 4), np.int16), ["a"], noise="loud")
    with pytest.raises(ValidationError, match="p_swap"):
        SimulatedNoise(p_swap=1.5)
    with pytest.raises(ValidationError, match="unknown option 'blurr'"):
        SimulatedRecognizer(LABELS.names, blurr=2)
    rec = make_recognizer("simulated", LABELS, noise="low", downsample=4)
    assert rec.noise.downsample == 4 and rec.noise.p_swap == NOISE_PRESETS["low"].p_swap
    assert rec.noise.model == "correlated"
    with pytest.raises(ValidationError, match="ImageContext"):
        rec.recognize(None)
    with pytest.raises(ValidationError, match="no capture folder"):
        rec.recognize(None, ImageContext("c", 0))
    with pytest.raises(ValidationError, match="unknown name 'magic'"):
        make_recognizer("magic", LABELS)


def test_recognizer_reads_the_ground_truth_label_map(tmp_path):
    groundtruth = pytest.importorskip("pointtraj.synth.groundtruth")
    lab = figure_map()
    groundtruth.save_label_map(tmp_path, "cam03", 7, lab)
    rec = make_recognizer("simulated", LABELS, noise="default", seed=5)
    out = rec.recognize(None, ImageContext("cam03", 7, capture=str(tmp_path)))
    expected = simulate_confidences(
        lab, LABELS.names, LABELS.kinds, "default", camera="cam03", frame=7, seed=5
    )
    np.testing.assert_array_equal(out, expected)
    with pytest.raises(ValidationError, match="cam03 frame 7 is"):
        rec.recognize(np.zeros((10, 10, 3), np.uint8), ImageContext("cam03", 7, str(tmp_path)))
    with pytest.raises(FileFormatError, match="no such file"):
        rec.recognize(None, ImageContext("cam03", 8, capture=str(tmp_path)))


def test_registry_entries_resolve_to_recognizers():
    import importlib

    from pointtraj.semantics.recognizers import RECOGNIZERS, Recognizer

    for name, target in RECOGNIZERS.items():
        module, attr = target.split(":")
        try:
            cls = getattr(importlib.import_module(module), attr)
        except ModuleNotFoundError as exc:  # a recogniser module not written yet
            pytest.skip(f"{name}: {exc}")
        assert issubclass(cls, Recognizer), name


def test_person_masks_from_the_ground_truth_instance_map(tmp_path):
    """Two figures side by side: two person ids on their body pixels (image-local numbering),
    none on the ball; a capture without instance maps gives None."""
    from pointtraj.synth import groundtruth

    lab = figure_map()
    inst = np.full(lab.shape, -1, np.int16)
    inst[:, :64][lab[:, :64] >= 0] = 7  # the left figure (its instance id in the scene)
    inst[:, 64:][lab[:, 64:] >= 0] = 3  # the right one, and the ball (instance 3 too)
    groundtruth.save_label_map(tmp_path, "cam01", 0, lab)
    rec = make_recognizer("simulated", LABELS, noise="none", model="independent", downsample=4)
    ctx = ImageContext("cam01", 0, capture=str(tmp_path))
    L2D, people = rec.recognize_people(None, ctx)
    assert people is None  # no gt/instances yet
    groundtruth.save_instance_map(tmp_path, "cam01", 0, inst)
    np.testing.assert_array_equal(groundtruth.load_instance_map(tmp_path, "cam01", 0), inst)
    L2D, people = rec.recognize_people(None, ctx)
    np.testing.assert_array_equal(L2D, rec.recognize(None, ctx))
    assert people.shape == L2D.shape[:2] and people.dtype == np.int16
    assert set(np.unique(people).tolist()) == {-1, 0, 1}
    assert (people[:, : 64 // 4] != 1).all() and (people[:, 64 // 4 :] != 0).all()
    body = np.isin(lab[2::4, 2::4], LABELS.classes_of_kind("body"))
    np.testing.assert_array_equal(people >= 0, body)  # the ball is not a person
    # every person missed: no person pixels
    _, missed = make_recognizer(
        "simulated", LABELS, noise="none", model="independent", p_miss=1.0
    ).recognize_people(None, ctx)
    assert (missed == -1).all()
