"""Scaled synthetic scenes (pointtraj synth --scale / --rig-scale) and a run on a small rig with
the defaults (issue 17)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pointtraj.synth import groundtruth as gtio
from pointtraj.synth.presets import PRESETS, make_rig
from pointtraj.synth.render import synthetic_world
from pointtraj.synth.scenes import STAGE_CENTRE, make_scene, scale_scene

F = 0.004


def test_scale_scene_scales_geometry_motion_texture_and_ground_truth():
    scene = make_scene("dribble", 0)
    target = (0.0, 0.0, 0.0)
    small = scale_scene(scene, F, target)
    assert small.scale == F and scene.scale == 1.0
    c = np.asarray(STAGE_CENTRE)
    for t in (0.0, 0.4):
        P, Q = scene.poses(t), small.poses(t)
        np.testing.assert_allclose(Q[:, :3, :3], P[:, :3, :3])
        np.testing.assert_allclose(Q[:, :3, 3], F * (P[:, :3, 3] - c), atol=1e-15)
    for g, h in zip(scene.geometries, small.geometries, strict=True):
        np.testing.assert_allclose(h.mesh.vertices, F * g.mesh.vertices)
        assert h.label == g.label and h.instance == g.instance
    # The same ground-truth points, at F times the size: same geometry, classes and colours.
    a = gtio.sample_ground_truth_points(scene, 30, seed=1)
    b = gtio.sample_ground_truth_points(small, 30, seed=1)
    np.testing.assert_array_equal(a.geometry, b.geometry)
    np.testing.assert_array_equal(a.label, b.label)
    np.testing.assert_allclose(b.local, F * a.local, rtol=1e-9, atol=1e-15)
    assert np.abs(a.color.astype(int) - b.color.astype(int)).max() <= 1  # the same texture
    np.testing.assert_allclose(
        b.world(small.poses(0.2)), F * (a.world(scene.poses(0.2)) - c), atol=1e-12
    )
    assert scale_scene(scene, 1.0) is scene  # a human-sized scene is untouched


def test_narrow7_gets_a_scene_that_fills_its_view():
    rig, scene = synthetic_world("narrow7", "dribble", 0)
    assert scene.scale == PRESETS["narrow7"].scene_scale == F
    pts = gtio.sample_ground_truth_points(scene, 20, seed=0)
    xyz = pts.world(scene.poses(0.0))
    body = pts.label >= 0
    size = np.ptp(xyz[body], axis=0)
    assert 0.005 < size.max() < 0.01  # a figure a few mm tall
    seen = rig.project(xyz[body]).in_image.mean(axis=1)
    assert seen.min() > 0.6  # every camera sees most of the figure
    # the human presets are as before
    rig8, scene8 = synthetic_world("ring8", "dribble", 0)
    assert scene8.scale == 1.0
    np.testing.assert_array_equal(rig8.C, make_rig("ring8").C)


@pytest.mark.slow
def test_a_scaled_capture_reconstructs_like_its_human_sized_original(tmp_path: Path):
    """tiny4 and tiny4 at 0.004 of its size (scene and rig): the defaults follow the scale,
    so both give about as many points, with the same error relative to the scene's size."""
    from pointtraj.evaluate.health import known_floor
    from pointtraj.scale import work_scene_scale
    from pointtraj.stages import SynthConfig, affinity_work, reconstruct_work, synthesize

    runs = {}
    for name, f in (("human", 1.0), ("small", F)):
        cap = tmp_path / f"cap_{name}"
        synthesize(
            cap, SynthConfig(preset="tiny4", frames=2, points_per_part=20, scale=f, rig_scale=f)
        )
        assert gtio.capture_scale(cap) == f
        depth = gtio.load_depth_map(cap, "cam00", 0)
        assert np.nanmax(depth) < 10 * f  # metres, at the scene's scale
        # the floor moves with the scene: z = 0.9 - 0.9 f about the stage centre at 0.9 m
        assert known_floor(cap)[1] == pytest.approx(0.9 - 0.9 * f)
        traj = reconstruct_work(tmp_path / f"work_{name}", cap)
        # the later stages take the work folder's scale: the affinity's lengths follow it
        factor = work_scene_scale(tmp_path / f"work_{name}").factor
        assert (factor == 1.0) if f == 1.0 else (0.003 < factor < 0.006)
        graph = affinity_work(tmp_path / f"work_{name}")
        assert graph.params["epsilon"] == pytest.approx(0.05 * factor)
        assert graph.params["tau"] == pytest.approx(0.005 * factor)
        xyz = [traj.frame(t).xyz for t in range(2)]
        runs[name] = (traj.num_trajectories, xyz, cap)
    n_h, n_s = runs["human"][0], runs["small"][0]
    assert n_s > 50
    assert 0.7 < n_s / n_h < 1.3
    # the points lie on the scaled surface: relative errors of the same size
    from pointtraj.evaluate.groundtruth import frame_surface_errors
    from pointtraj.session import Capture

    rel = {}
    for name, f in (("human", 1.0), ("small", F)):
        _, xyz, cap = runs[name]
        rig = Capture.open(cap).rig
        e = np.concatenate([frame_surface_errors(cap, rig, t, x) for t, x in enumerate(xyz)])
        rel[name] = float(np.nanmedian(e)) / f
    # tiny4's 320x256 images: about 3 cm (median, floor included) at human size, both ways
    assert rel["small"] < 1.5 * rel["human"] + 0.005
