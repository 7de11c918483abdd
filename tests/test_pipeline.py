"""``pointtraj run``: typed pipeline files, stage skipping, resuming, and the demo config."""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from helpers.pipelines import TINY

from pointtraj.cli import main
from pointtraj.errors import FileFormatError, ValidationError
from pointtraj.labelfile import load_labels
from pointtraj.pipeline import (
    PipelineConfig,
    demo_pipeline,
    load_pipeline,
    run_pipeline,
)
from pointtraj.stages import SynthConfig
from pointtraj.trajectories import Trajectories

ROOT = Path(__file__).resolve().parents[1]


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "pipe.toml"
    path.write_text(text, encoding="utf-8")
    return path


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    """A tiny synthetic pipeline run once for the module: (config file, config, result)."""
    tmp = tmp_path_factory.mktemp("pipe")
    path = _write(tmp, TINY)
    config = load_pipeline(path, base=tmp)
    return path, config, run_pipeline(config)


def test_run_makes_every_output(tiny_run):
    _, config, result = tiny_run
    assert result.ran == [
        "capture",
        "trajectories",
        "semantics",
        "affinity",
        "label",
        "segments",
        "evaluate",
        "render",
    ]
    traj = Trajectories.load(config.work / "trajectories.npz")
    labels = load_labels(config.work / "labels.npz")
    assert len(labels) == traj.num_trajectories > 50
    assert labels.class_names[0] == "head"
    assert (config.work / "segments.npz").is_file()
    csv = (config.work / "labels.csv").read_text(encoding="utf-8").splitlines()
    assert len(csv) == traj.num_trajectories + 1
    timings = json.loads((config.work / "timings.json").read_text(encoding="utf-8"))
    assert set(timings) == {
        "synth",
        "reconstruct",
        "semantics",
        "affinity",
        "label",
        "segments",
        "evaluate",
        "render",
    }
    # The report: the paper's studies and the ground-truth metrics of this synthetic capture.
    metrics = json.loads((config.work / "report" / "metrics.json").read_text(encoding="utf-8"))
    assert metrics["trajectories.count"] == traj.num_trajectories
    assert 0 <= metrics["gt.error_m.median"] <= metrics["gt.error_m.p90"]
    assert metrics["gt.error_m.median"] < 0.05  # 320x256 images: a pixel is 12 mm there
    for key in ("gt.accuracy.graphcut", "gt.accuracy.view_argmax", "gt.accuracy.average_argmax"):
        assert 0.2 < metrics[key] <= 1.0, key
    assert {"validity.view.1cams", "validity.average.3cams", "timing.reconstruct_s"} <= set(metrics)
    index = (config.work / "report" / "index.md").read_text(encoding="utf-8")
    for title in ("Ground truth", "Affinity effectiveness", "Predictive validity", "Timing"):
        assert f"## {title}" in index
    from importlib.metadata import version

    assert f"| numpy | {version('numpy')} |" in index  # the report names its libraries
    assert f"| scipy | {version('scipy')} |" in index
    assert (config.work / "report" / "validity.png").is_file()
    assert all(v >= 0 for v in timings.values())
    renders = config.work / "renders"
    assert (renders / "legend.png").is_file() and (renders / "views" / "orbit.mp4").is_file()
    assert len(list((renders / "views" / "orbit").glob("*.png"))) == 3
    # Per-frame clouds carry the labels of their trajectories.
    import open3d as o3d

    pcd = o3d.t.io.read_point_cloud(str(config.work / "clouds" / "000001.ply"))
    track = pcd.point.track_id.numpy().ravel()
    np.testing.assert_array_equal(pcd.point.label.numpy().ravel(), labels.labels[track])


def test_rerun_skips_and_parameter_change_reruns_dependants(tiny_run, tmp_path):
    path, config, _ = tiny_run
    again = run_pipeline(config)
    assert again.ran == [] and len(again.skipped) == 8
    labels_before = (config.work / "labels.npz").stat().st_mtime_ns
    changed = dataclasses.replace(config, affinity=dataclasses.replace(config.affinity, tau=0.05))
    res = run_pipeline(changed)
    assert res.ran == ["affinity", "label", "segments", "evaluate", "render"]
    assert res.skipped == ["capture", "trajectories", "semantics"]
    assert (config.work / "labels.npz").stat().st_mtime_ns != labels_before
    forced = run_pipeline(changed, force=["semantics"])
    # affinity does not read the semantic map
    assert forced.ran == ["semantics", "label", "segments", "evaluate", "render"]


def test_interrupted_reconstruction_resumes(tmp_path):
    from pointtraj.stages import reconstruct_work

    config = load_pipeline(_write(tmp_path, TINY), base=tmp_path)
    config = dataclasses.replace(config, stages=("capture", "trajectories"))
    run_pipeline(config)
    work = config.work
    reference = Trajectories.load(work / "trajectories.npz")
    shutil.rmtree(work)

    class Crash(Exception):
        pass

    def crash_after_frame_1(label: str, done: int, total: int) -> None:
        if label == "reconstruct" and done == 2:
            raise Crash

    with pytest.raises(Crash):  # a run killed after frame 1
        reconstruct_work(
            work, config.capture, config.reconstruct, config.frames, progress=crash_after_frame_1
        )
    assert not (work / "trajectories.npz").exists()
    first_cloud = (work / "clouds" / "000000.ply").stat().st_mtime_ns
    res = run_pipeline(config)
    assert "trajectories" in res.ran
    assert (work / "clouds" / "000000.ply").stat().st_mtime_ns == first_cloud  # not redone
    assert (work / "state" / "000002.npz").is_file()
    resumed = Trajectories.load(work / "trajectories.npz")
    assert resumed.num_frames == 3
    np.testing.assert_array_equal(resumed.offsets, reference.offsets)
    np.testing.assert_array_equal(resumed.xyz, reference.xyz)


def test_bad_pipeline_files_name_the_problem(tmp_path):
    with pytest.raises(FileFormatError, match=r"pipe.toml: .*unknown key 'sigmaa'"):
        load_pipeline(_write(tmp_path, TINY + "\n[reconstruct]\nsigmaa = 2\n"))
    with pytest.raises(FileFormatError, match=r"missing required key 'work'"):
        load_pipeline(_write(tmp_path, 'capture = "c"\n'))
    with pytest.raises(FileFormatError, match=r"synth.preset: unknown 'ring99'"):
        load_pipeline(_write(tmp_path, TINY.replace('"tiny4"', '"ring99"')))
    with pytest.raises(FileFormatError, match=r"label.pooling 'weighted' is not among"):
        load_pipeline(_write(tmp_path, TINY + '\n[label]\npooling = "weighted"\n'))
    with pytest.raises(FileFormatError, match="invalid TOML"):
        load_pipeline(_write(tmp_path, "capture = \n"))
    with pytest.raises(FileFormatError, match="capture folder does not exist"):
        run_pipeline(PipelineConfig(capture=tmp_path / "nowhere", work=tmp_path / "w"))
    with pytest.raises(ValidationError, match="unknown stage 'labels'"):
        run_pipeline(demo_pipeline(tmp_path), force=["labels"])


def test_every_shipped_pipeline_loads_and_the_demo_file_matches_the_demo():
    files = sorted((ROOT / "pipelines").glob("*.toml"))
    assert {"synthetic_demo.toml", "paper69.toml"} <= {f.name for f in files}
    for f in files:
        assert isinstance(load_pipeline(f, base=ROOT), PipelineConfig)
    from_file = load_pipeline(ROOT / "pipelines" / "synthetic_demo.toml", base=ROOT)
    assert from_file == demo_pipeline(ROOT / "pointtraj-demo")


def test_run_command(tmp_path):
    path = _write(tmp_path, TINY.replace("frames = 3", "frames = 2"))
    cwd = os.getcwd()
    os.chdir(tmp_path)
    try:
        runner = CliRunner()
        res = runner.invoke(main, ["run", str(path), "--work", "w2"])
        assert res.exit_code == 0, res.output
        assert "labels" in res.output and (tmp_path / "w2" / "labels.npz").is_file()
        res = runner.invoke(main, ["run", str(path), "--work", "w2"])
        assert (
            "up to date: capture, trajectories, semantics, affinity, label, segments, evaluate, "
            "render" in res.output
        )
        res = runner.invoke(main, ["run", "missing.toml"])
        assert res.exit_code == 1 and "missing.toml: no such file" in res.output
    finally:
        os.chdir(cwd)


def test_synth_config_validates():
    with pytest.raises(ValidationError, match="synth.scene: unknown 'juggle'"):
        SynthConfig(scene="juggle")


def test_load_api(tiny_run, tmp_path):
    import pointtraj
    from pointtraj.render import label_colors

    _, config, _ = tiny_run
    res = pointtraj.load(config.work)
    M = res.trajectories.num_trajectories
    assert res.labels is not None and res.semantic_map is not None
    assert res.class_names == res.labels.class_names and res.class_colors.shape == (15, 3)
    pcd = res.pointcloud(1)
    track = pcd.point.track_id.numpy().ravel()
    label = pcd.point.label.numpy().ravel()
    np.testing.assert_array_equal(label, res.label[track])
    colors = np.rint(pcd.point.colors.numpy() * 255).astype(int)
    np.testing.assert_array_equal(colors, label_colors(label, res.class_colors))  # -1: grey
    assert len(res.label) == M
    with pytest.raises(FileFormatError, match="trajectories.npz: no such file"):
        pointtraj.load(tmp_path)
