"""The health block (issue #17): warnings that fire on a bad run and stay silent on a good one."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from helpers.pipelines import TINY
from helpers.rigs import ring_rig

from pointtraj.cli import main
from pointtraj.evaluate.health import (
    HealthThresholds,
    check_health,
    floor_from_feet,
    health_lines,
    health_warnings,
    known_floor,
    observed_views,
    pair_counts,
)
from pointtraj.labelfile import TrajectoryLabels
from pointtraj.reconstruct.config import ReconstructConfig
from pointtraj.rigio import load_rig, save_rig
from pointtraj.trajectories import Trajectories, view_counts

#: Figures of a healthy run (close to the demo's): no check is past its threshold.
GOOD = {
    "health.points_per_frame": 900.0,
    "health.two_view_share": 0.3,
    "health.pairs.kept": 16,
    "health.pairs.near": 16,
    "health.cameras_unused": [],
    "health.below_floor_share": 0.001,
    "health.labelled_share": 0.4,
    "health.labelled_per_frame": 300.0,
    "validity.support.share": 0.6,
}


def test_healthy_figures_raise_no_warning():
    assert health_warnings(GOOD) == []
    assert health_lines({**GOOD, "health.warnings": []}) == ["health: no warnings"]
    assert health_lines({}) == []  # a report of an older version has no health block


@pytest.mark.parametrize(
    ("key", "value", "words"),
    [
        ("health.points_per_frame", 12.0, "only 12 points per frame"),
        ("health.two_view_share", 0.999, "99.9 % of the point-frames are seen by at most 2"),
        ("health.pairs.kept", 1, "kept 1 of the 16 camera pairs"),
        ("health.cameras_unused", ["cam03"], "cameras cam03 observe under 1 %"),
        ("health.below_floor_share", 0.14, "14.0 % of the point-frames lie more than 5 cm below"),
        ("health.labelled_share", 0.001, "few points on the labelled classes: 0.1 %"),
        ("health.labelled_per_frame", 2.0, "few points on the labelled classes"),
        ("validity.support.share", 0.05, "predictive validity compares only 5.0 %"),
    ],
)
def test_each_check_fires_past_its_threshold(key, value, words):
    warnings = health_warnings({**GOOD, key: value})
    assert len(warnings) == 1 and words in warnings[0]
    lines = health_lines({"health.warnings": warnings})
    assert lines[0] == "health: 1 warning" and lines[1] == f"  warning: {warnings[0]}"


def test_thresholds_are_the_config():
    strict = HealthThresholds(two_view_share=0.2)
    assert health_warnings(GOOD) == [] and len(health_warnings(GOOD, strict)) == 1


def test_pair_counts_of_a_ring():
    rig = ring_rig(8, target=(0, 0, 1))  # 45 degrees between neighbours
    assert pair_counts(rig, 90.0) == {"all": 28, "near": 16, "kept": 16}
    # A cut-off that keeps only the nearest neighbours drops half of the pairs.
    assert pair_counts(rig, 50.0)["kept"] == 8


def test_known_floor_only_for_synthetic_captures(tmp_path):
    assert known_floor(tmp_path) is None
    (tmp_path / "gt").mkdir()
    (tmp_path / "gt" / "synth.toml").write_text("scene = 'dribble'\n", encoding="utf-8")
    up, height = known_floor(tmp_path)
    assert up.tolist() == [0, 0, 1] and height == 0


def _store(views: int, num: int = 400, T: int = 5, below: float = 0.0) -> Trajectories:
    """``num`` still points at 1 m height, each seen by the first ``views`` of 4 cameras; the
    first ``below`` share of them 10 cm under the floor."""
    rng = np.random.default_rng(0)
    xyz = np.repeat(rng.uniform([-0.3, -0.3, 0.8], [0.3, 0.3, 1.2], (num, 1, 3)), T, axis=1)
    xyz[: int(below * num), :, 2] = -0.1
    vis = np.zeros((num, T, 4))
    vis[:, :, :views] = 1.0
    return Trajectories.from_dense(xyz, vis, camera_names=[f"cam{i:02d}" for i in range(4)])


def test_check_health_of_stores(tmp_path):
    rig = ring_rig(4, names="cam{i:02d}")
    good = _store(views=4)
    m = check_health(good, rig, None, ReconstructConfig())
    assert m["health.two_view_share"] == 0 and m["health.points_per_frame"] == 400
    assert m["health.pairs.near"] == m["health.pairs.kept"] == 4
    assert "health.below_floor_share" not in m  # no capture: no known floor
    assert health_warnings(m) == []
    bad = _store(views=2)
    m = check_health(bad, rig, None)
    assert m["health.two_view_share"] == 1 and "health.pairs.kept" not in m
    assert m["health.cameras_unused"] == ["cam02", "cam03"]
    assert len(health_warnings(m)) == 2
    # Points under a known floor, and labels that leave almost everything out.
    floor = tmp_path  # a synthetic capture's floor: z = 0
    (floor / "gt").mkdir()
    (floor / "gt" / "synth.toml").write_text("scene = 'dribble'\n", encoding="utf-8")
    under = _store(views=4, below=0.2)
    M = under.num_trajectories
    labels = TrajectoryLabels(
        np.r_[np.zeros(2), -np.ones(M - 2)].astype(np.int64),
        np.zeros(M, np.float32),
        np.zeros(M, np.int64),
        ("head",),
    )
    m = check_health(under, rig, floor, labels=labels)
    assert m["health.below_floor_share"] == pytest.approx(0.2)
    assert m["health.labelled_share"] == pytest.approx(2 / M)
    text = " | ".join(health_warnings(m))
    assert "below the floor" in text and "few points on the labelled classes" in text


def _feet_store(seed: int = 0):
    """A real rig's store (no known floor, z up): 300 foot trajectories between the floor
    (z = 0) and 10 cm; 20 wrong ones labelled foot, spread thin 0.5-6 m below the floor; 400
    body points at 0.8-1.2 m, and 100 more 1-2 m below the floor (a ghost floor). Labels:
    class 0 ``left_foot``, class 1 ``torso``."""
    rng = np.random.default_rng(seed)
    feet = rng.uniform([-0.3, -0.3, 0.0], [0.3, 0.3, 0.1], (300, 3))
    wrong = rng.uniform([-0.3, -0.3, -6.0], [0.3, 0.3, -0.5], (20, 3))
    body = rng.uniform([-0.3, -0.3, 0.8], [0.3, 0.3, 1.2], (400, 3))
    ghost = rng.uniform([-0.3, -0.3, -2.0], [0.3, 0.3, -1.0], (100, 3))
    xyz = np.repeat(np.concatenate([feet, wrong, body, ghost])[:, None], 3, axis=1)
    vis = np.ones((len(xyz), 3, 4))
    store = Trajectories.from_dense(xyz, vis, camera_names=[f"cam{i:02d}" for i in range(4)])
    cls = np.r_[np.zeros(320), np.ones(500)].astype(np.int64)
    labels = TrajectoryLabels(
        cls, np.zeros(len(cls), np.float32), np.zeros(len(cls), np.int64), ("left_foot", "torso")
    )
    return store, labels, len(ghost) + len(wrong)


def test_floor_from_feet_ignores_thin_wrong_feet():
    store, labels, _ = _feet_store()
    up = np.array([0.0, 0.0, 1.0])
    floor = floor_from_feet(store, labels, up, 0.025)
    assert 0.0 <= floor <= 0.025  # the 2nd percentile would be metres below
    assert np.percentile(store.xyz[: 320 * 3, 2], 2) < -1.0
    # No foot class, or too few foot points: no estimate.
    for names in (("a", "b"), ("football", "torso"), ("footwear", "torso")):
        other = TrajectoryLabels(labels.labels, labels.confidence, labels.argmax, names)
        assert floor_from_feet(store, other, up, 0.025) is None, names
    for names in (("foot", "torso"), ("Left Foot", "torso"), ("feet", "x")):
        feet = TrajectoryLabels(labels.labels, labels.confidence, labels.argmax, names)
        assert floor_from_feet(store, feet, up, 0.025) == floor, names
    few = store.subset(np.r_[np.arange(10), np.arange(320, 820)])
    few_labels = TrajectoryLabels(
        labels.labels[np.r_[np.arange(10), np.arange(320, 820)]],
        np.zeros(510, np.float32),
        np.zeros(510, np.int64),
        labels.class_names,
    )
    assert floor_from_feet(few, few_labels, up, 0.025) is None


def test_a_real_rig_gets_its_floor_from_the_feet():
    """No known floor (no capture): the floor under the labelled feet flags the ghost floor."""
    store, labels, under = _feet_store()
    rig = ring_rig(4, names="cam{i:02d}")  # z up, cameras in a level ring
    m = check_health(store, rig, None, labels=labels)
    assert m["health.floor"] == "feet" and 0.0 <= m["health.floor_height_m"] <= 0.025
    assert m["health.below_floor_share"] == pytest.approx(under / store.num_trajectories)
    text = " | ".join(health_warnings(m))
    assert "below the floor (the floor under the labelled feet" in text
    # Without labels there is nothing to stand on.
    assert "health.below_floor_share" not in check_health(store, rig, None)


def test_the_captures_up_direction_is_used_for_the_feet_floor():
    """A world whose up is -y (a camera's frame, as caliscope writes it) while the cameras'
    ring would say +z: with capture.toml's ``up`` the floor under the feet is found."""
    store, labels, under = _feet_store()
    R = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # +z -> -y
    turned = Trajectories.from_dense(
        (store.xyz.reshape(-1, 3, 3).astype(np.float64) @ R.T),
        np.ones((store.num_trajectories, 3, 4)),
        camera_names=store.camera_names,
    )
    rig = ring_rig(4, names="cam{i:02d}")
    m = check_health(turned, rig, None, labels=labels, up=np.array([0.0, -2.0, 0.0]))
    assert m["health.floor"] == "feet" and 0.0 <= m["health.floor_height_m"] <= 0.025
    assert m["health.below_floor_share"] == pytest.approx(under / store.num_trajectories)
    detected = check_health(turned, rig, None, labels=labels)  # the rig's +z: wrong here
    assert detected.get("health.below_floor_share") != m["health.below_floor_share"]


def test_observed_views_is_the_store_count():
    rng = np.random.default_rng(1)
    vis = rng.integers(0, 256, (1000, 6)).astype(np.uint8)
    per_point, per_camera = observed_views(vis)
    assert np.array_equal(per_point, view_counts(vis))
    assert per_camera.sum() == per_point.sum() and per_camera.shape == (6,)


@pytest.fixture(scope="module")
def two_camera_capture(tiny_reference, tmp_path_factory):
    """The tiny synthetic capture seen by 2 of its 4 cameras (one camera pair)."""
    tmp = tmp_path_factory.mktemp("health")
    full, cap = tiny_reference / "cap", tmp / "cap2"
    cap.mkdir()
    for name in ("capture.toml", "labels.toml", "gt"):
        os.symlink(full / name, cap / name)
    (cap / "frames").mkdir()
    for cam in ("cam00", "cam01"):
        os.symlink(full / "frames" / cam, cap / "frames" / cam)
    save_rig(load_rig(full / "rig.toml").subset(["cam00", "cam01"]), cap / "rig.toml")
    return tmp, cap


def test_a_one_pair_run_warns_at_the_end(two_camera_capture):
    """The deliberately bad run of issue #17: every point two-view, the warnings say so in the
    report, metrics.json and the last lines of ``pointtraj run``."""
    tmp, cap = two_camera_capture
    text = TINY.replace('capture = "cap"', f'capture = "{cap}"')
    text = text[: text.index("[synth]")] + text[text.index("[semantics]") :]
    text = text.replace(
        'work = "work"',
        f'work = "{tmp / "work"}"\nstages = '
        + ('["trajectories", "semantics", "affinity", "label", "evaluate"]'),
    )
    pipe = tmp / "two.toml"
    pipe.write_text(text, encoding="utf-8")
    res = CliRunner().invoke(main, ["run", str(pipe)])
    assert res.exit_code == 0, res.output
    out = res.stdout.rstrip().splitlines()
    at = next(i for i, line in enumerate(out) if line.startswith("health: "))
    assert out[at].endswith("warnings") and at + 1 + int(out[at].split()[1]) == len(out)
    assert any("seen by at most 2 cameras" in line for line in out[at + 1 :])
    metrics = json.loads((tmp / "work" / "report" / "metrics.json").read_text("utf-8"))
    assert metrics["health.two_view_share"] > 0.99
    assert metrics["health.pairs.all"] == metrics["health.pairs.kept"] == 1
    assert any("at most 2 cameras" in w for w in metrics["health.warnings"])
    assert metrics["trajectories.views.2.share"] > 0.99
    # every point-frame on two views, or on one where one-view survival carries it
    pf = metrics["trajectories.point_frames"]
    two, one = (metrics[f"reprojection_px.views.{v}.support"] for v in ("2", "1"))
    assert two + one == pf and two > 0.99 * pf
    index = (tmp / "work" / "report" / "index.md").read_text("utf-8")
    assert index.index("## Health") < index.index("## Trajectories")
    assert "- **warning**: " in index and "(unverifiable: near 0 by construction)" in index
    # Predictive validity says what it rests on.
    assert (
        0
        < metrics["validity.support.point_frames"]
        <= metrics["validity.support.sampled_point_frames"]
    )
    assert "point-frames compared" in index
    # On the console each warning comes once, at the end, not also in the log above it.
    proc = subprocess.run(
        [sys.executable, "-m", "pointtraj", "evaluate", str(tmp / "work")],
        capture_output=True,
        text=True,
        env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2])},
    )
    assert proc.returncode == 0, proc.stderr
    console = proc.stdout + proc.stderr
    assert "health: " in proc.stdout
    for w in metrics["health.warnings"]:
        assert console.count(w) == 1, console


#: A healthy run that is cheap: the ground-truth trajectories of 2 frames of the demo's rig
#: (8 cameras), through every later stage.
HEALTHY = """
name = "healthy"
capture = "cap"
work = "work"
trajectories = "ground_truth"
stages = ["capture", "trajectories", "semantics", "affinity", "label", "evaluate"]

[synth]
preset = "ring8"
frames = 2
points_per_part = 40

[semantics]
recognizer = "simulated"
options = { noise = "low" }

[evaluate]
validity_frames = 2

[executor]
workers = 1
"""


def test_a_healthy_run_is_silent(tmp_path):
    """The other half of issue #17's check: no warning where nothing went wrong (the demo's
    rig; the demo itself, too slow for a test, ends with ``health: no warnings`` as well)."""
    (tmp_path / "healthy.toml").write_text(HEALTHY, encoding="utf-8")
    res = CliRunner().invoke(
        main,
        ["run", str(tmp_path / "healthy.toml"), "--capture", str(tmp_path / "cap")]
        + ["--work", str(tmp_path / "work")],
    )
    assert res.exit_code == 0, res.output
    assert res.stdout.rstrip().splitlines()[-1] == "health: no warnings"
    metrics = json.loads((tmp_path / "work" / "report" / "metrics.json").read_text("utf-8"))
    assert metrics["health.warnings"] == []
    assert metrics["health.below_floor_share"] == 0  # ground-truth points lie on the surfaces
    assert metrics["health.two_view_share"] < 0.5 and metrics["validity.support.share"] > 0.2
