"""Tests of ``pointtraj semantics`` and ``pointtraj gt-trajectories`` on a rendered capture."""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from pointtraj.cli import main
from pointtraj.semantics.semantic_map import SemanticMap


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    render = pytest.importorskip("pointtraj.synth.render")
    out = tmp_path_factory.mktemp("semantics_cli") / "capture"
    render.render_capture(out, preset="tiny4", scene="dribble", frames=2, points_per_part=20)
    return out


def test_gt_trajectories_then_semantics(capture, tmp_path):
    from pointtraj.synth.groundtruth import load_ground_truth

    work = tmp_path / "work"
    runner = CliRunner()
    result = runner.invoke(main, ["gt-trajectories", str(capture), "--out", str(work)])
    assert result.exit_code == 0, result.output
    assert (work / "trajectories.npz").is_file()
    assert str(capture.resolve()) in (work / "work.toml").read_text()

    args = ["semantics", str(work), "--recognizer", "simulated", "-o", "noise=none"]
    result = runner.invoke(main, [*args, "-o", "downsample=2"])
    assert result.exit_code == 0, result.output
    assert "semantic_map.npz" in result.output
    smap = SemanticMap.load(work / "semantic_map.npz")
    gt = load_ground_truth(capture)
    truth = gt.label[gt.segments(2)[0]]
    seen = smap.count["view"] > 0
    assert seen.mean() > 0.99
    assert smap.class_names == tuple(gt.class_names) and smap.recognizer == "simulated"
    assert np.mean(smap.argmax_labels("view")[seen] == truth[seen]) > 0.85


def test_from_ground_truth_and_errors(capture, tmp_path):
    runner = CliRunner()
    work = tmp_path / "w2"
    base = ["semantics", str(work), "--capture", str(capture)]
    result = runner.invoke(main, [*base, "--recognizer", "simulated"])
    assert result.exit_code != 0 and "--from-ground-truth" in result.output
    result = runner.invoke(
        main, [*base, "--recognizer", "simulated", "--from-ground-truth", "--pooling", "view"]
    )
    assert result.exit_code == 0, result.output
    assert SemanticMap.load(work / "semantic_map.npz").poolings == ("view",)
    result = runner.invoke(main, [*base, "--recognizer", "simulated", "--background-vote", "2"])
    assert result.exit_code != 0 and "background_vote: must be in [0, 1], got 2.0" in result.output
    result = runner.invoke(main, [*base, "--recognizer", "magic"])
    assert result.exit_code != 0 and "unknown name 'magic'" in result.output
    result = runner.invoke(main, [*base, "--recognizer", "simulated", "-o", "blurr=2"])
    assert result.exit_code != 0 and "unknown option 'blurr'" in result.output
    maps = tmp_path / "maps"
    maps.mkdir()
    result = runner.invoke(main, [*base, "--recognizer", "precomputed", "-o", f"directory={maps}"])
    assert result.exit_code != 0 and "missing confidence map of camera" in result.output
    result = runner.invoke(main, ["semantics", str(tmp_path / "none"), "--recognizer", "simulated"])
    assert result.exit_code != 0 and "--capture" in result.output


def test_semantics_reads_a_pipeline_file(capture, tmp_path):
    """``--config``: the pipeline file's [semantics] table, with the options given here over it
    and -o options added to its recogniser options."""
    runner = CliRunner()
    work = tmp_path / "w3"
    assert runner.invoke(main, ["gt-trajectories", str(capture), "--out", str(work)]).exit_code == 0
    pipeline = tmp_path / "p.toml"
    pipeline.write_text(
        f'capture = "{capture}"\nwork = "{work}"\n[semantics]\nrecognizer = "simulated"\n'
        'options = { noise = "none" }\npoolings = ["view", "max"]\neps_e = 0.2\n',
        encoding="utf-8",
    )
    args = ["semantics", str(work), "--config", str(pipeline), "-o", "downsample=2"]
    result = runner.invoke(main, [*args, "--eps-e", "0.3"])
    assert result.exit_code == 0, result.output
    smap = SemanticMap.load(work / "semantic_map.npz")
    assert smap.recognizer == "simulated" and smap.poolings == ("view", "max")
    assert smap.recognizer_options == {"noise": "none", "downsample": 2}
    assert smap.eps_e == 0.3  # the command line over the file
    # a file without the recogniser, and no -r: said, not the simulated one by default
    pipeline.write_text(f'capture = "{capture}"\nwork = "{work}"\n', encoding="utf-8")
    result = runner.invoke(main, ["semantics", str(work), "--config", str(pipeline)])
    assert result.exit_code != 0 and "--recognizer" in result.output
    assert "has no [semantics] recognizer" in result.output
    result = runner.invoke(main, ["semantics", str(work)])
    assert result.exit_code != 0 and "--recognizer" in result.output
    pipeline.write_text("semantics = 3\n", encoding="utf-8")  # not a table: one line
    result = runner.invoke(main, ["semantics", str(work), "-r", "simulated", "--config", pipeline])
    assert result.exit_code != 0 and "[semantics] must be a table" in result.output
    assert "Traceback" not in result.output
