"""``pointtraj evaluate``: the report of a work folder, on a tiny synthetic capture."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from pointtraj.cli import main
from pointtraj.errors import FileFormatError, ValidationError
from pointtraj.evaluate.groundtruth import true_labels, voted_labels
from pointtraj.evaluate.study import (
    EvaluateConfig,
    affinity_effectiveness,
    evaluate_work,
    headline,
)
from pointtraj.stages import (
    SemanticsStageConfig,
    SynthConfig,
    affinity_work,
    ground_truth_work,
    label_work,
    semantics_work,
    synthesize,
)
from pointtraj.trajectories import Trajectories


@pytest.fixture(scope="module")
def gt_work(tmp_path_factory):
    """Ground-truth trajectories of a tiny capture taken through semantics, affinity and label."""
    tmp = tmp_path_factory.mktemp("study")
    cap, work = tmp / "cap", tmp / "work"
    synthesize(cap, SynthConfig(preset="tiny4", frames=3, points_per_part=40))
    ground_truth_work(work, cap)
    semantics_work(work, SemanticsStageConfig(options={"noise": "low"}), cap)
    affinity_work(work)
    label_work(work)
    return cap, work


def test_evaluate_writes_the_report(gt_work):
    cap, work = gt_work
    metrics = evaluate_work(work)
    saved = json.loads((work / "report" / "metrics.json").read_text(encoding="utf-8"))
    assert saved["trajectories.count"] == metrics["trajectories.count"] > 100
    # Ground-truth trajectories lie on the surface: what is left is the depth maps' own
    # sampling (a pixel is 12 mm wide at this 320x256 rig's distance).
    assert metrics["gt.error_m.median"] < 0.003
    # Every ground-truth point lies on a surface: none is left out of the 3D error.
    assert metrics["gt.no_surface"] == 0
    assert metrics["gt.error_m.support"] == metrics["trajectories.point_frames"]
    # ... and none is off it, in any view bucket; the buckets cover every point-frame.
    assert metrics["gt.off_surface.share"] == 0.0
    assert (
        sum(metrics[f"gt.error_m.views.{v}.support"] for v in ("1", "2", "3", "4+"))
        == metrics["trajectories.point_frames"]
    )
    assert saved["health.warnings"] == metrics["health.warnings"]
    assert (
        sum(metrics[f"reprojection_px.views.{v}.support"] for v in ("1", "2", "3", "4+"))
        == metrics["trajectories.point_frames"]
    )
    # 15 classes, and 40x32-cell recognition maps at this size: far above chance (1/15).
    assert metrics["gt.accuracy.graphcut"] > 0.45
    assert metrics["gt.accuracy.view_argmax"] > 0.45
    assert set(metrics) >= {"validity.view.1cams", "validity.average.3cams"}
    # The view audit of the ground truth itself: it keeps the views the ground truth sees.
    assert metrics["gt.views.recall"] > 0.95 and metrics["gt.views.recall.support"] > 100
    assert metrics["gt.views.two_view_share.support"] == metrics["trajectories.point_frames"]
    assert all(0 <= metrics[f"validity.view.{n}cams"] <= 1 for n in (1, 2, 3))
    index = (work / "report" / "index.md").read_text(encoding="utf-8")
    assert "## Ground truth" in index and "paper's Table 1" in index
    assert "## Views" in index and "| view recall" in index
    assert "| observed views | point-frames | median (mm) | p90 (mm) | off the surface |" in index
    assert "off the surface** (above" not in index
    for png in ("confusion.png", "affinity.png", "validity.png"):
        assert (work / "report" / png).stat().st_size > 1000
    lines = headline(saved)
    assert lines[0].startswith(f"trajectories: {metrics['trajectories.count']}")
    assert any(line.startswith("label accuracy: graph cut") for line in lines)
    # Both averages: the paper's over all cameras in whose image the point falls, and ours
    # over the visible cameras, in the validity study and the headline; the labels' pooling.
    assert {"validity.average_visible.3cams", "gt.accuracy.average_visible_argmax"} <= set(metrics)
    assert metrics["semantics.label_pooling"] == saved["semantics.label_pooling"] == "view"
    assert "## Pooling" in index and "| **view** (labels) |" in index
    assert "| **view** (labels) pooling |" in index  # predictive validity's row
    assert "ground-truth trajectories" in index  # the report says what it measured
    validity = next(line for line in lines if line.startswith("predictive validity"))
    assert "average pooling over all cameras (the paper's)" in validity
    assert "average pooling over visible cameras" in validity
    assert any(line == "labels from: view pooling" for line in lines)


def test_the_semantic_map_records_its_recogniser_options(gt_work):
    from pointtraj.semantics.semantic_map import SemanticMap

    _, work = gt_work
    assert SemanticMap.load(work / "semantic_map.npz").recognizer_options == {"noise": "low"}


def test_true_labels_of_ground_truth_and_of_other_stores(gt_work):
    cap, work = gt_work
    traj = Trajectories.load(work / "trajectories.npz")
    truth, source = true_labels(cap, traj)
    assert source == "ground truth" and truth.shape == (traj.num_trajectories,)
    # Voting with the label maps agrees with the points' own labels almost everywhere.
    voted = voted_labels(cap, traj)
    seen = voted >= 0
    assert seen.mean() > 0.8
    assert np.mean(voted[seen] == truth[seen]) > 0.95
    # Moved points are no longer the ground truth: their labels are voted.
    moved = Trajectories(
        traj.first_frame,
        traj.offsets,
        traj.xyz + np.float32(1e-3),
        traj.visibility,
        traj.reprojection_error,
        traj.color,
        traj.camera_names,
        traj.fps,
        traj.num_frames,
    )
    assert true_labels(cap, moved)[1] == "voted"


def _two_bodies(T=6, n=800, seed=0):
    """Two 25 cm boxes of points 35 cm apart, one still, one turning: labels 0 and 1."""
    rng = np.random.default_rng(seed)
    a = rng.uniform(-0.125, 0.125, (n, 3))
    b = rng.uniform(-0.125, 0.125, (n, 3))
    xyz = np.zeros((2 * n, T, 3))
    for t in range(T):
        ang = 0.15 * t
        R = np.array([[np.cos(ang), -np.sin(ang), 0], [np.sin(ang), np.cos(ang), 0], [0, 0, 1]])
        xyz[:n, t] = a
        xyz[n:, t] = b @ R.T + [0.35, 0, 0.02 * t]
    vis = np.ones((2 * n, T, 2))
    labels = np.repeat([0, 1], n)
    return Trajectories.from_dense(xyz, vis, camera_names=["a", "b"]), labels


def test_affinity_effectiveness_separates_rigid_bodies():
    traj, labels = _two_bodies()
    res = affinity_effectiveness(traj, labels, radius=0.6, draws=16, bin_width=0.1)
    assert res["bins"].tolist() == pytest.approx([0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6])
    # Pairs 30-40 cm apart mostly join the two bodies; the SE(3) neighbours keep to one body
    # at every distance, and keep most of a body's own pairs.
    assert res["eps_s"][3] > 0.3
    assert np.nanmax(res["se3"]) < 0.05
    assert np.nanmin(res["se3_recall"][:2]) > 0.5


def test_bad_input(tmp_path, gt_work):
    with pytest.raises(FileFormatError, match="trajectories.npz: no such file"):
        evaluate_work(tmp_path)
    with pytest.raises(ValidationError, match="evaluate.affinity_bin"):
        EvaluateConfig(affinity_bin=2.0)
    res = CliRunner().invoke(main, ["evaluate", str(tmp_path)])
    assert res.exit_code == 1 and "trajectories.npz: no such file" in res.output
    bad = tmp_path / "bad.toml"
    bad.write_text("x\n", encoding="utf-8")
    res = CliRunner().invoke(main, ["evaluate", str(gt_work[1]), "--config", str(bad)])
    assert res.exit_code == 2 and "bad.toml: invalid TOML" in res.output
    assert res.exception is None or isinstance(res.exception, SystemExit)


def test_evaluate_command(gt_work):
    cap, work = gt_work
    res = CliRunner().invoke(main, ["evaluate", str(work), "--validity-frames", "2"])
    assert res.exit_code == 0, res.output
    assert "label accuracy: graph cut" in res.output and "report:" in res.output


def _fifteen_second_map(fps=2.0, tracks=6, seconds=15):
    """A semantic map of trajectories living 15 s, with known pooled samples per pooling.

    ``view`` keeps its first frame's class with a little jitter (NC near 1), ``average``
    drifts to another class (NC -0.5), ``view_soft`` and ``average_visible`` in between.
    """
    from pointtraj.semantics.semantic_map import SemanticMap

    T, K = int(seconds * fps) + 1, 3
    rng = np.random.default_rng(0)
    first = np.tile([[0.9, 0.05, 0.05]], (T, 1))
    samples = {}
    for p, mix in (("view", 0.1), ("view_soft", 0.2), ("average_visible", 0.3), ("average", 1)):
        rows = []
        for _ in range(tracks):
            later = (1 - mix) * first + mix * np.array([0.05, 0.9, 0.05])
            later[0] = first[0]
            rows.append(later + rng.uniform(0, 0.01, (T, K)))
        samples[p] = np.concatenate(rows).astype(np.float32)
    M = tracks
    return SemanticMap(
        class_names=("a", "b", "c"),
        L3D={p: np.zeros((M, K), np.float32) for p in samples},
        count={p: np.full(M, T, np.int32) for p in samples},
        sample_tracks=np.arange(M, dtype=np.int64),
        sample_offsets=np.arange(M + 1, dtype=np.int64) * T,
        sample_first_frame=np.zeros(M, np.int64),
        samples=samples,
        fps=fps,
    )


def test_temporal_section_has_the_paper_lags_and_columns(tmp_path):
    from pointtraj.evaluate import paper
    from pointtraj.evaluate.study import PAPER_SECONDS, _temporal_section

    smap = _fifteen_second_map()
    metrics = {}
    section = _temporal_section(smap, tmp_path, metrics, None, chosen="view")
    body = section.body
    # Every lag of the paper's Table 1, 1 to 15 s, for every pooling, with its support.
    assert "| pooling | " + " | ".join(f"{s}s" for s in PAPER_SECONDS) + " |" in body
    for p in smap.poolings:
        for s in PAPER_SECONDS:
            assert metrics[f"temporal_nc.{p}.{s}s.support"] == 6
            assert -1 <= metrics[f"temporal_nc.{p}.{s}s"] <= 1
    assert metrics["temporal_nc.view.15s"] > 0.99 and metrics["temporal_nc.average.15s"] < 0
    # The chosen pooling is marked; the paper's rows stand beside ours, at the same lags.
    assert "| **view** (labels) |" in body
    for name, d in paper.TEMPORAL_NC.items():
        row = next(line for line in body.splitlines() if line.startswith(f"| paper, {name} |"))
        assert row.count("|") == len(PAPER_SECONDS) + 2
        assert f"{d[1][0]:.2f} ± {d[1][1]:.2f}" in row and f"{d[15][0]:.2f}" in row
    for p in smap.poolings:
        assert f"| ours, {p} |" in body
    # The verdicts: view above the paper's average baseline at every lag, and the order.
    assert "at every lag: **yes**" in body
    assert metrics["temporal_nc.view_minus_average.min"] > 1.0
    assert "at every lag: view > view_soft > average_visible" in body
    assert (tmp_path / "temporal.png").stat().st_size > 1000


def test_temporal_verdict_names_the_lags_where_view_falls_below():
    from pointtraj.evaluate.study import _temporal_verdicts

    means = {"view": {"1s": 0.9, "3s": 0.95}, "average": {"1s": 0.94, "3s": 0.9}}
    metrics = {}
    lines = _temporal_verdicts(means, ["1s", "3s"], metrics)
    assert "**no**: not at 1s;" in lines[0] and lines[1] == ""  # a paragraph each
    assert metrics["temporal_nc.view_minus_average.min"] == pytest.approx(-0.04)
    means["view"]["3s"] = 0.8
    assert "**no**, below it at every lag" in _temporal_verdicts(means, ["1s", "3s"], {})[0]
    # The headline lists the lags in time order (metrics.json sorts "11s" before "1s").
    nc = {f"temporal_nc.view.{s}s": s / 100 for s in (11, 1, 3)}
    assert "view pooling: 0.01 at 1s, 0.03 at 3s, 0.11 at 11s" in "\n".join(headline(nc))


def test_error_by_views_shows_wrong_two_view_points():
    """Two-view points a metre off (a wrong match) and points with no surface near count as off
    the surface, in their own view bucket; the other buckets stay clean."""
    from pointtraj.evaluate.study import _error_by_views

    err = np.array([0.001, 0.002, 1.0, np.nan, 0.003, 0.004, 0.002, 0.001])
    views = np.array([2, 2, 2, 2, 3, 3, 5, 1])
    metrics: dict = {}
    rows, share = _error_by_views(err, views, 0.05, metrics)
    assert share == pytest.approx(2 / 8) == metrics["gt.off_surface.share"]
    assert metrics["gt.off_surface.views.2.share"] == pytest.approx(0.5)
    assert metrics["gt.error_m.views.2.support"] == 4
    assert metrics["gt.error_m.views.2.median"] == pytest.approx(0.002)  # NaN left out
    assert metrics["gt.off_surface.views.3.share"] == 0.0
    assert metrics["gt.off_surface.views.4+.share"] == 0.0
    assert metrics["gt.error_m.views.1.support"] == 1
    assert len(rows) == 4 and "unverifiable" in rows[1] and "50.0 %" in rows[1]


def test_off_surface_share_follows_each_point_frame_views(gt_work, tmp_path):
    """The 3D error is measured frame by frame and the views are stored trajectory by
    trajectory: each point-frame's error must meet its own view count. Odd trajectories are
    moved 10 m off the surface (far from every surface) and given two views, even ones keep every view."""
    import dataclasses
    import shutil

    cap, work = gt_work
    moved = tmp_path / "work"
    shutil.copytree(work, moved, ignore=shutil.ignore_patterns("report"))
    traj = Trajectories.load(moved / "trajectories.npz")
    odd = (traj.row_track % 2 == 1)[:, None]  # (P, 1)
    xyz = traj.xyz + np.where(odd, np.float32([0, 0, 10.0]), np.float32(0))
    two = np.zeros_like(traj.visibility)
    two[:, :2] = 255
    vis = np.where(odd, two, np.full_like(traj.visibility, 255))
    dataclasses.replace(traj, xyz=xyz, visibility=vis).save(moved / "trajectories.npz")
    metrics = evaluate_work(moved, EvaluateConfig(validity_tracks=50, validity_frames=1))
    assert metrics["gt.error_m.views.2.support"] == int(odd.sum())
    assert metrics["gt.off_surface.views.2.share"] == 1.0
    assert metrics["gt.off_surface.views.4+.share"] == 0.0
    assert metrics["gt.off_surface.share"] == pytest.approx(odd.mean())
    assert "off the surface** (above 10 %)" in (moved / "report" / "index.md").read_text()


def test_actor_error_leaves_the_background_out(gt_work):
    """The figure on the figures and objects measures their point-frames alone: points of
    the background's trajectories 4 cm off raise the error of all point-frames, not theirs,
    and the supports split the point-frames by their trajectories' true labels."""
    from pointtraj.evaluate.study import _actor_error, _q

    rng = np.random.default_rng(0)
    truth = np.repeat([0, 3, -1, -2, 5], 40)  # (200,) per point-frame
    err = np.where(truth >= 0, rng.uniform(0, 0.002, 200), 0.04)
    err[0] = np.nan  # no surface near: left out of the percentiles, as for all point-frames
    metrics: dict = {}
    line = _actor_error(err, truth, metrics)
    assert metrics["gt.error_m.actors.support"] == 119
    assert metrics["gt.error_m.background.support"] == 40
    assert metrics["gt.error_m.actors.p90"] < 0.002 < _q(err[np.isfinite(err)], 90)
    assert "120 of 200, 40 on the background" in line and "mm**." in line
    # On a ground-truth store every trajectory is a part: the two figures are the same.
    cap, work = gt_work
    saved = evaluate_work(work)
    assert saved["gt.error_m.actors.support"] == saved["gt.error_m.support"]
    assert saved["gt.error_m.actors.p90"] == saved["gt.error_m.p90"]
    assert saved["gt.error_m.background.support"] == 0
    assert "On the figures and objects alone" in (work / "report" / "index.md").read_text()
    mm = f"{1e3 * saved['gt.error_m.actors.median']:.1f} / {1e3 * saved['gt.error_m.actors.p90']:.1f} mm"
    assert f"on the figures and objects {mm}" in "\n".join(headline(saved))


def test_actor_error_without_actors():
    from pointtraj.evaluate.study import _actor_error

    metrics: dict = {}
    line = _actor_error(np.array([0.01, np.nan]), np.array([-1, -2]), metrics)
    assert "No point-frame" in line and metrics["gt.error_m.actors.support"] == 0
    assert metrics["gt.error_m.background.support"] == 1
