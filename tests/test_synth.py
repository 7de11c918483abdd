"""Tests of the synthetic capture generator (pointtraj.synth)."""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from pointtraj.errors import FileFormatError, ValidationError
from pointtraj.synth import (
    PRESETS,
    Renderer,
    load_depth_map,
    load_ground_truth,
    load_label_map,
    make_rig,
    make_scene,
    render_capture,
)
from pointtraj.synth.figure import BODY_PARTS
from pointtraj.synth.groundtruth import GroundTruth, save_depth_map, save_label_map
from pointtraj.synth.objects import GRAVITY, BallPath, make_capsule, make_ellipsoid


# -- fixtures --------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    """A rendered tiny4 dribble capture of 3 frames."""
    out = tmp_path_factory.mktemp("synth") / "cap"
    summary = render_capture(out, preset="tiny4", scene="dribble", frames=3, points_per_part=200)
    return out, summary


@pytest.fixture(scope="module")
def dribble():
    return make_scene("dribble", seed=0)


@pytest.fixture(scope="module")
def close_views(dribble):
    """Camera 0 of ring8 (640x512) rendered at frames 10 and 11, with the renderer."""
    rig = make_rig("ring8").subset([0])
    renderer = Renderer(dribble, rig, seed=0)
    views = [next(renderer.render_frame(t)) for t in (10, 11)]
    return rig, renderer, views


# -- presets ---------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "name, count, size",
    [("paper69", 69, (1280, 1024)), ("ring12", 12, (800, 640)), ("ring8", 8, (640, 512)),
     ("tiny4", 4, (320, 256))],
)  # fmt: skip
def test_presets_have_the_right_cameras(name, count, size):
    rig = make_rig(name)
    assert len(rig) == count
    assert all(tuple(c.size) == size for c in rig)
    assert len(set(rig.names)) == count
    assert not np.any(rig.dist)
    # Every camera sees the whole figure volume around the stage centre.
    box = np.array([[x, y, z] for x in (-0.3, 0.3) for y in (-0.3, 0.3) for z in (0.05, 1.75)])
    assert rig.project(box).in_image.all()
    assert name in PRESETS and PRESETS[name].description


def test_paper69_geometry_matches_the_paper():
    rig = make_rig("paper69")
    radius = np.linalg.norm(rig.C[:, :2], axis=1)
    assert np.all((radius >= 1.5) & (radius <= 1.7))  # on or just outside the 3 m cylinder
    heights = np.round(rig.C[:, 2], 2)
    assert sorted(set(heights.tolist())) == [1.0, 2.2]
    assert np.sum(heights == 1.0) == 35 and np.sum(heights == 2.2) == 34
    assert np.all(rig.C[:, 2] <= 2.5)


def test_unknown_preset_and_scene_are_clear_errors():
    with pytest.raises(ValidationError, match="unknown rig preset 'nope'.*paper69"):
        make_rig("nope")
    with pytest.raises(ValidationError, match="unknown scene 'nope'.*dribble"):
        make_scene("nope")


# -- meshes, motion --------------------------------------------------------------------------
def test_meshes_are_closed_with_the_right_area():
    import open3d as o3d

    for mesh in (make_capsule(0.3, 0.05), make_ellipsoid((0, 0, 0), (0.1, 0.2, 0.3))):
        legacy = o3d.geometry.TriangleMesh(
            o3d.utility.Vector3dVector(mesh.vertices), o3d.utility.Vector3iVector(mesh.triangles)
        )
        assert legacy.is_watertight()
    cap = make_capsule(0.3, 0.05)
    exact = 2 * np.pi * 0.05 * 0.3 + 4 * np.pi * 0.05**2
    assert cap.triangle_areas.sum() == pytest.approx(exact, rel=0.03)
    pts, tri = cap.sample_surface(500, np.random.default_rng(0))
    r = np.hypot(pts[:, 0], pts[:, 1])
    assert np.all(r <= 0.05 + 1e-9) and np.all(pts[:, 2] <= 0.05 + 1e-9)


def test_ball_path_is_a_projectile_between_floor_and_hand():
    ball = BallPath()
    t = np.linspace(0, 3 * ball.period, 20001)
    z = ball.height(t)
    assert z.min() == pytest.approx(ball.radius, abs=1e-3)
    assert np.max(np.abs(np.diff(z))) < 0.01  # continuous
    dt = t[1] - t[0]
    acc = np.diff(z, 2) / dt**2
    _, local, contact = ball.split(t[1:-1])
    flight = ~contact & (np.abs(local - ball.contact - ball.fall_time) > 0.01)
    flight &= (np.abs(local - ball.contact) > 0.01) & (local < ball.period - 0.01)
    assert np.allclose(acc[flight], -GRAVITY, atol=0.05)


def test_dribble_scene_is_plausible(dribble):
    names = [g.name for g in dribble.geometries]
    idx = {n: i for i, n in enumerate(names)}
    for t in np.linspace(0, 3, 31):
        poses = dribble.poses(t)
        feet_z = [
            dribble.geometries[idx[f"person0/{s}_foot"]].mesh.transformed(poses[idx[f"person0/{s}_foot"]])[:, 2].min()
            for s in ("left", "right")
        ]  # fmt: skip
        assert min(feet_z) == pytest.approx(0.0, abs=1e-6)  # on the floor
        assert max(feet_z) < 0.2
        ball_z = poses[idx["ball"], 2, 3]
        assert ball_z >= 0.12 - 1e-6
    # The hand touches the ball during contact, and never enters it.
    ball = dribble.extras["ball"]
    for t in np.linspace(0, 3, 301):
        poses = dribble.poses(t)
        hand = dribble.geometries[idx["person0/right_hand"]].mesh.transformed(
            poses[idx["person0/right_hand"]]
        )
        centre = poses[idx["ball"], :3, 3]
        gap = np.linalg.norm(hand - centre, axis=1).min() - ball.radius
        assert gap > -0.005
        if ball.split(np.array(t))[2]:  # in contact
            assert gap < 0.005


def test_scenes_are_deterministic_for_a_seed():
    for name in ("dribble", "two_people", "static_room"):
        a, b = make_scene(name, seed=3), make_scene(name, seed=3)
        assert np.array_equal(a.poses(0.7), b.poses(0.7))
        assert [g.texture_seed for g in a.geometries] == [g.texture_seed for g in b.geometries]
    two = make_scene("two_people", seed=1)
    assert sorted({g.instance for g in two.geometries if g.label >= 0}) == [0, 1]
    assert two.class_names == list(BODY_PARTS)


def test_rendering_is_deterministic_for_a_seed(dribble):
    rig = make_rig("tiny4").subset([1])
    a = next(Renderer(dribble, rig, seed=5).render_frame(4))
    b = next(Renderer(dribble, rig, seed=5).render_frame(4))
    c = next(Renderer(dribble, rig, seed=6).render_frame(4))
    assert np.array_equal(a.image, b.image) and np.array_equal(a.label, b.label)
    assert np.array_equal(a.depth, b.depth, equal_nan=True)
    assert not np.array_equal(a.image, c.image)  # the sensor noise differs
    assert np.array_equal(a.label, c.label)
    assert set(np.unique(a.label)) >= {-1, 0, 1, 14}


# -- ground truth ----------------------------------------------------------------------------
def test_capture_layout_and_loader(capture):
    from pointtraj.labelset import LabelSet
    from pointtraj.session import Capture

    out, summary = capture
    assert summary.frames == 3 and summary.cameras == 4 and summary.images == 12
    cap = Capture.open(out)
    assert cap.num_frames == 3 and cap.fps == 30.0 and len(cap.rig) == 4
    assert cap.read("cam02", 2).shape == (256, 320, 3)
    labels = LabelSet.load(out / "labels.toml")
    assert list(labels.names) == [*BODY_PARTS, "ball"]
    assert labels.kinds[-1] == "object" and labels.kinds[0] == "body"
    assert dict(labels.recognizers["object-detector"]) == {"sports_ball": "ball"}
    assert len({tuple(c) for c in labels.colors.tolist()}) == len(labels.names)  # distinct
    gt = load_ground_truth(out)
    M = 15 * 200
    assert gt.xyz.shape == (M, 3, 3) and gt.xyz.dtype == np.float32
    assert gt.visible.shape == (M, 3, 4) and gt.visible.dtype == bool
    assert gt.label.shape == (M,) and set(np.unique(gt.label)) == set(range(15))
    assert set(np.unique(gt.instance)) == {0, 1}
    assert gt.class_names == list(labels.names) and gt.camera_names == cap.camera_names
    assert gt.fps == 30.0
    assert 0.15 < gt.visible.mean() < 0.6
    lab = load_label_map(out, "cam00", 1)
    dep = load_depth_map(out, "cam00", 1)
    assert lab.shape == dep.shape == (256, 320) and lab.dtype == np.int16
    assert dep.dtype == np.float32
    assert np.array_equal(np.isnan(dep), lab == -1) is False  # the floor is background but hit
    assert np.all(np.isnan(dep[lab == -1]) | (dep[lab == -1] > 0))


def test_visible_points_land_on_their_own_label(capture):
    out, _ = capture
    gt = load_ground_truth(out)
    rig = make_rig("tiny4")
    agree = total = 0
    depth_ok = []
    for t in range(gt.num_frames):
        proj = rig.project(gt.xyz[:, t])
        for c, name in enumerate(gt.camera_names):
            v = gt.visible[:, t, c]
            px = np.rint(proj.pixels[c, v]).astype(int)
            lab = load_label_map(out, name, t)[px[:, 1], px[:, 0]]
            dep = load_depth_map(out, name, t)[px[:, 1], px[:, 0]]
            agree += np.sum(lab == gt.label[v])
            total += v.sum()
            # Depth at the pixel agrees with the point's depth: 1 cm or two pixel footprints,
            # plus the 1 mm quantisation of the PNG (the pixel centre is up to 0.7 px away).
            tol = np.maximum(0.01, 2 * proj.depth[c, v] / rig.K[c, 0, 0]) + 0.001
            depth_ok.append(np.abs(dep - proj.depth[c, v]) <= tol)
    assert total > 5000
    assert agree / total >= 0.99
    assert np.mean(np.concatenate(depth_ok)) >= 0.98


def test_visibility_agrees_with_exact_occlusion_rays(capture, dribble):
    """Independent check: cast a ray from each camera exactly through each GT point."""
    import open3d as o3d

    out, _ = capture
    gt = load_ground_truth(out)
    rig = make_rig("tiny4")
    t = 2
    renderer = Renderer(dribble, rig)
    scene, _ = renderer.build_raycasting_scene(dribble.poses(t / 30.0))
    X = gt.xyz[:, t].astype(np.float64)
    proj = rig.project(X)
    for c in range(len(rig)):
        d = X - rig.C[c]
        dist = np.linalg.norm(d, axis=1)
        rays = np.concatenate([np.broadcast_to(rig.C[c], d.shape), d / dist[:, None]], axis=1)
        hit = scene.cast_rays(o3d.core.Tensor(rays.astype(np.float32)))["t_hit"].numpy()
        free = (hit >= dist - 0.005) & proj.in_image[c]  # nothing in front of the point
        vis = gt.visible[:, t, c]
        assert np.mean(free[vis]) >= 0.99
        # Most geometrically unoccluded points are visible (only pixel-boundary cases are not).
        assert np.mean(vis[free]) >= 0.8


def test_depth_map_back_projects_onto_the_surface(capture, dribble):
    """Pixel convention check: depth-map pixels lifted to 3D lie on the posed meshes."""
    import open3d as o3d

    out, _ = capture
    rig = make_rig("tiny4")
    cam = rig[3]
    depth = load_depth_map(out, cam.name, 1)
    v, u = np.nonzero(np.isfinite(depth))
    xy = np.stack([(u - cam.K[0, 2]) / cam.K[0, 0], (v - cam.K[1, 2]) / cam.K[1, 1]], axis=1)
    Xc = np.concatenate([xy, np.ones((len(xy), 1))], axis=1) * depth[v, u, None]
    X = Xc @ cam.R + cam.C  # R^T x_cam + C
    renderer = Renderer(dribble, rig)
    scene, _ = renderer.build_raycasting_scene(dribble.poses(1 / 30.0))
    dist = scene.compute_distance(o3d.core.Tensor(X.astype(np.float32))).numpy()
    assert np.median(dist) < 0.0006  # depth is stored in whole millimetres
    assert np.quantile(dist, 0.99) < 0.002


def test_label_and_depth_maps_round_trip(tmp_path):
    lab = np.array([[-1, 0, 3], [14, -1, 2]], np.int16)
    dep = np.array([[np.nan, 1.2344, 2.0], [0.5, np.nan, 65.0]], np.float32)
    save_label_map(tmp_path, "camX", 7, lab)
    save_depth_map(tmp_path, "camX", 7, dep)
    assert np.array_equal(load_label_map(tmp_path, "camX", 7), lab)
    back = load_depth_map(tmp_path, "camX", 7)
    assert np.array_equal(np.isnan(back), np.isnan(dep))
    assert np.allclose(back, dep, atol=5e-4, equal_nan=True)
    with pytest.raises(FileFormatError, match="no such file"):
        load_label_map(tmp_path, "camX", 8)
    with pytest.raises(ValidationError, match="below 255"):
        save_label_map(tmp_path, "camX", 0, np.full((2, 2), 300))


def test_to_trajectories_splits_runs():
    visible = np.zeros((3, 6, 3), bool)
    visible[0, 1:3, :2] = True  # run 1..2
    visible[0, 4:6, :] = True  # run 4..5
    visible[1, :, 0] = True  # only one camera: never a trajectory
    visible[2, :, :] = True  # whole clip
    xyz = np.arange(3 * 6 * 3, dtype=np.float32).reshape(3, 6, 3)
    gt = GroundTruth(
        xyz, visible, np.array([0, 1, 2]), np.zeros(3, int), ["a", "b", "c"],
        ["c0", "c1", "c2"], 30.0, np.zeros((3, 3), np.uint8), np.zeros(3, int), ["g"],
    )  # fmt: skip
    point, first, length = gt.segments()
    assert point.tolist() == [0, 0, 2] and first.tolist() == [1, 4, 0]
    assert length.tolist() == [2, 2, 6]
    tr = gt.to_trajectories()
    assert tr.num_trajectories == 3 and tr.num_frames == 6
    dense = tr.dense_positions()
    assert np.array_equal(dense[0, 1:3], xyz[0, 1:3]) and np.isnan(dense[0, 0]).all()
    assert np.array_equal(dense[2], xyz[2])
    vis = tr.frame(1).visibility
    assert np.allclose(vis[0], [1, 1, 0])
    assert gt.to_trajectories(min_visible=4).num_trajectories == 0


def test_missing_ground_truth_frame_is_a_clear_error(capture, tmp_path):
    import shutil

    out = tmp_path / "cap"
    shutil.copytree(capture[0] / "gt", out / "gt")
    (out / "gt" / "frames" / "000001.npz").unlink()
    with pytest.raises(FileFormatError, match="frame 1 is missing"):
        load_ground_truth(out)
    with pytest.raises(FileFormatError, match="no such file"):
        load_ground_truth(tmp_path)


# -- texture quality -------------------------------------------------------------------------
def test_texture_gives_many_orb_features(close_views):
    import cv2

    _, _, views = close_views
    view = views[0]
    gray = cv2.cvtColor(view.image, cv2.COLOR_RGB2GRAY)
    mask = ((view.label >= 0) * 255).astype(np.uint8)
    kps = cv2.ORB_create(nfeatures=5000).detect(gray, mask)
    assert len(kps) > 300


def test_lk_flow_follows_ground_truth_points(close_views, dribble):
    import cv2

    from pointtraj.synth.groundtruth import sample_ground_truth_points, visibility_in_view

    rig, _, views = close_views
    pts = sample_ground_truth_points(dribble, 300, seed=0)
    uv, vis = [], []
    for t, view in zip((10, 11), views):
        proj = rig.project(pts.world(dribble.poses(t / 30.0)))
        uv.append(proj.pixels[0])
        vis.append(
            visibility_in_view(
                proj.pixels[0], proj.depth[0], proj.in_image[0], view.depth,
                geometry=pts.geometry, geometry_map=view.geometry, focal=rig.K[0, 0, 0],
            )
        )  # fmt: skip
    both = vis[0] & vis[1]
    assert both.sum() > 300
    g0, g1 = (cv2.cvtColor(v.image, cv2.COLOR_RGB2GRAY) for v in views)
    p0 = uv[0][both].astype(np.float32).reshape(-1, 1, 2)
    p1, status, _ = cv2.calcOpticalFlowPyrLK(g0, g1, p0, None, winSize=(15, 15), maxLevel=3)
    ok = status.ravel() == 1
    err = np.linalg.norm(p1.reshape(-1, 2)[ok] - uv[1][both][ok], axis=1)
    motion = np.linalg.norm(uv[1][both] - uv[0][both], axis=1)
    assert ok.mean() > 0.9
    assert np.median(err) < 1.0
    # Points that really move (the ball, the dribbling arm) are tracked too.
    moving = motion[ok] > 1.0
    assert moving.sum() > 100
    assert np.median(err[moving]) < 1.0
    assert np.median(err[moving]) < 0.2 * np.median(motion[ok][moving])


# -- CLI -------------------------------------------------------------------------------------
def test_cli_renders_and_resumes(tmp_path):
    from pointtraj.cli import main

    out = tmp_path / "cli"
    runner = CliRunner()
    args = ["synth", "--preset", "tiny4", "--scene", "two_people", "--frames", "2"]
    args += ["--out", str(out), "--points-per-part", "20", "--image-format", "png"]
    res = runner.invoke(main, args)
    assert res.exit_code == 0, res.output
    assert "GT points 560" in res.output and "2 rendered" in res.output
    assert (out / "frames" / "cam03" / "000001.png").is_file()
    stamp = (out / "frames" / "cam00" / "000000.png").stat().st_mtime_ns
    (out / "gt" / "frames" / "000001.npz").unlink()  # as if interrupted during frame 1
    res = runner.invoke(main, args)
    assert res.exit_code == 0, res.output
    assert "1 rendered, 1 already done" in res.output
    assert (out / "frames" / "cam00" / "000000.png").stat().st_mtime_ns == stamp
    assert load_ground_truth(out).xyz.shape == (560, 2, 3)
    # Fewer frames than the folder holds, or a different capture, are refused.
    res = runner.invoke(main, [*args[:6], "1", *args[7:]])
    assert res.exit_code == 1 and "already holds 2 frames" in res.output
    res = runner.invoke(main, [*args, "--seed", "4"])
    assert res.exit_code == 1 and "holds a different synthetic capture" in res.output


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--preset", "nope"], "unknown preset 'nope'"),
        (["--scene", "nope"], "unknown scene 'nope'"),
        (["--frames", "0"], "must be at least 1"),
        (["--points-per-part", "0"], "must be at least 1"),
        (["--image-format", "gif"], "'gif' is not one of"),
    ],
)
def test_cli_bad_options_are_clear(tmp_path, extra, message):
    from pointtraj.cli import main

    res = CliRunner().invoke(main, ["synth", "--out", str(tmp_path / "x"), *extra])
    assert res.exit_code == 2
    assert message in res.output


def test_cli_refuses_a_non_capture_folder(tmp_path):
    from pointtraj.cli import main

    (tmp_path / "notes.txt").write_text("hello")
    res = CliRunner().invoke(main, ["synth", "--out", str(tmp_path), "--frames", "1"])
    assert res.exit_code == 1 and "is not a synthetic capture" in res.output


def test_cli_lists_presets_and_scenes(tmp_path):
    from pointtraj.cli import main

    res = CliRunner().invoke(main, ["synth", "--list"])
    assert res.exit_code == 0
    for name in ("paper69", "ring12", "ring8", "tiny4", "dribble", "two_people", "static_room"):
        assert name in res.output
    res = CliRunner().invoke(main, ["synth", "--frames", "1"])
    assert res.exit_code == 2 and "Missing option '--out'" in res.output


def test_distorted_cameras_render_consistently_with_projection(dribble):
    """Rays of a distorted camera go through the pixels that ``CameraRig.project`` predicts."""
    from pointtraj.camera import Camera, CameraRig
    from pointtraj.synth.groundtruth import sample_ground_truth_points, visibility_exact

    # Strong barrel distortion, the figure near the left image border where it matters most.
    cam = Camera.look_at(
        "dist0", (2.0, -0.9, 1.3), (0.1, 1.4, 0.9), (320, 256), 200.0, dist=(-0.3, 0.08, 0, 0, 0)
    )
    rig = CameraRig([cam])
    renderer = Renderer(dribble, rig)
    t = 6
    view = next(renderer.render_frame(t))
    pts = sample_ground_truth_points(dribble, 300, seed=1)
    X = pts.world(dribble.poses(t / 30.0))
    proj = rig.project(X)
    free = renderer.unoccluded(X)[:, 0] & proj.in_image[0]
    vis = visibility_exact(proj.pixels[0], free, pts.geometry, view.geometry)
    assert free.sum() > 500
    shift = np.linalg.norm(proj.pixels[0] - rig.undistort_pixels(proj.pixels)[0], axis=1)
    assert np.median(shift[free]) > 5  # the distortion moves these points by pixels
    assert vis[free].mean() > 0.8
    px = np.rint(proj.pixels[0, vis]).astype(int)
    err = np.abs(view.depth[px[:, 1], px[:, 0]] - proj.depth[0, vis])
    assert np.median(err) < 0.5 * np.median(proj.depth[0, vis]) / 200.0  # half a pixel footprint


def test_render_capture_rejects_bad_arguments(tmp_path):
    afile = tmp_path / "afile"
    afile.write_text("x")
    with pytest.raises(ValidationError, match="is a file"):
        render_capture(afile, frames=1)
    with pytest.raises(ValidationError, match="frames must be a positive integer"):
        render_capture(tmp_path / "a", frames=0)
    with pytest.raises(ValidationError, match="image_format must be 'jpg' or 'png'"):
        render_capture(tmp_path / "a", image_format="gif")
    with pytest.raises(ValidationError, match="points_per_part must be positive"):
        render_capture(tmp_path / "a", points_per_part=0)
    with pytest.raises(ValidationError, match="unknown rig preset 'zzz'"):
        render_capture(tmp_path / "a", preset="zzz")
    assert not (tmp_path / "a").exists()  # nothing written on a bad call


@pytest.mark.slow
def test_texture_supports_orb_gms_matching_between_neighbour_cameras(dribble):
    """ORB + GMS between two neighbouring paper69 cameras gives many geometrically right matches."""
    import cv2

    rig = make_rig("paper69").subset([0, 1])
    views = list(Renderer(dribble, rig).render_frame(5))
    orb = cv2.ORB_create(10000, fastThreshold=10)
    kps, descs = [], []
    for v in views:
        gray = cv2.cvtColor(v.image, cv2.COLOR_RGB2GRAY)
        k, d = orb.detectAndCompute(gray, ((v.label >= 0) * 255).astype(np.uint8))
        kps.append(k)
        descs.append(d)
    raw = cv2.BFMatcher(cv2.NORM_HAMMING).match(descs[0], descs[1])
    size = (views[0].image.shape[1], views[0].image.shape[0])
    gms = cv2.xfeatures2d.matchGMS(size, size, kps[0], kps[1], raw, thresholdFactor=6)
    assert len(gms) > 1000
    # Lift camera 0's keypoints with its depth map and project them into camera 1.
    p0 = np.array([kps[0][m.queryIdx].pt for m in gms])
    p1 = np.array([kps[1][m.trainIdx].pt for m in gms])
    cam = rig[0]
    u = np.rint(p0).astype(int)
    z = views[0].depth[u[:, 1], u[:, 0]]
    ray = np.stack(
        [(p0[:, 0] - cam.K[0, 2]) / cam.K[0, 0], (p0[:, 1] - cam.K[1, 2]) / cam.K[1, 1], np.ones(len(p0))],
        axis=1,
    )  # fmt: skip
    X = (ray * z[:, None]) @ cam.R + cam.C
    err = np.linalg.norm(rig.project(X).pixels[1] - p1, axis=1)
    assert np.median(err) < 3.0
    assert np.mean(err < 10.0) > 0.8


def test_two_bone_ik_keeps_bone_lengths_and_reaches():
    from pointtraj.synth.figure import solve_two_bone

    rng = np.random.default_rng(0)
    shoulder = np.array([0.1, -0.2, 1.4])
    for _ in range(50):
        target = shoulder + rng.normal(size=3) * 0.3
        elbow, wrist = solve_two_bone(shoulder, target, 0.29, 0.26, np.array([-1.0, 0, 0]))
        assert np.linalg.norm(elbow - shoulder) == pytest.approx(0.29, abs=1e-9)
        assert np.linalg.norm(wrist - elbow) == pytest.approx(0.26, abs=1e-9)
        reach = np.linalg.norm(target - shoulder)
        if 0.04 < reach < 0.54:
            assert np.allclose(wrist, target, atol=1e-9)
        else:  # out of reach: as close as possible along the same direction
            direction = (wrist - shoulder) / np.linalg.norm(wrist - shoulder)
            assert np.allclose(direction, (target - shoulder) / reach, atol=1e-9)


def _moved(rig, R, t):
    """The same cameras in a world frame ``X' = R X + t`` (a rig file from another tool)."""
    from pointtraj.camera import Camera, CameraRig

    return CameraRig([Camera(c.name, c.K, c.R @ R.T, R @ c.C + t, c.size, c.dist) for c in rig])


def test_twin_of_a_moved_rig_sees_the_stage_as_the_preset_does():
    from scipy.spatial.transform import Rotation

    from pointtraj.synth.presets import STAGE_CENTRE, axes_meeting_point, twin_rig

    rig = make_rig("ring8")  # aimed at (0, 0, 0.85)
    R = Rotation.from_rotvec([0.9, -0.4, 0.3]).as_matrix()  # y-up-ish, shifted: another tool
    t = np.array([3.0, -1.0, 7.0])
    moved = _moved(rig, R, t)
    aim = R @ np.array([0.0, 0.0, 0.85]) + t
    assert np.allclose(axes_meeting_point(moved), aim, atol=1e-9)
    twin, how = twin_rig(moved, up=R @ np.array([0.0, 0.0, 1.0]))
    assert "where the optical axes meet" in how
    # A rigid move to the stage, up to a turn about the vertical: the points on the vertical
    # through the stage centre project to the same pixels as in the preset.
    stage = np.array(STAGE_CENTRE)
    line = stage + np.outer([-0.8, -0.3, 0.0, 0.5], [0.0, 0.0, 1.0])
    line_preset = line + np.array([0.0, 0.0, 0.85 - 0.9])
    assert np.allclose(twin.project(line).pixels, rig.project(line_preset).pixels, atol=1e-6)
    assert np.allclose(twin.C[:, 2], rig.C[:, 2] + 0.05, atol=1e-9)  # heights kept
    # The subject placed explicitly, and the up axis detected from the ring.
    twin2, how2 = twin_rig(moved, at=aim)
    assert "as given" in how2 and np.allclose(twin2.C[:, 2], twin.C[:, 2], atol=1e-6)


def test_twin_rejects_bad_placements():
    from pointtraj.synth.presets import axes_meeting_point, twin_rig

    rig = make_rig("tiny4")
    with pytest.raises(ValidationError, match="at must be 3 finite numbers"):
        twin_rig(rig, at=(1.0, 2.0))
    with pytest.raises(ValidationError, match="scale must be a positive"):
        twin_rig(rig, scale=0.0)
    with pytest.raises(ValidationError, match="up"):
        twin_rig(rig, up="sideways")
    parallel = _moved(make_rig("tiny4"), np.eye(3), np.zeros(3))
    from pointtraj.camera import Camera, CameraRig

    same = CameraRig(
        [Camera(f"c{i}", c.K, parallel[0].R, c.C, c.size) for i, c in enumerate(parallel)]
    )
    with pytest.raises(ValidationError, match="optical axes do not meet"):
        axes_meeting_point(same)


def test_cli_renders_a_twin_of_a_rig_file(tmp_path):
    from pointtraj.cli import main
    from pointtraj.rigio import load_rig, save_rig
    from pointtraj.synth.presets import twin_rig

    rig = make_rig("tiny4")
    R = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # z-up to y-up
    save_rig(_moved(rig, R, np.array([0.5, 0.2, -2.0])), tmp_path / "rig.toml")
    out = tmp_path / "twin"
    args = ["synth", "--rig", str(tmp_path / "rig.toml"), "--up", "+y", "--frames", "1"]
    args += ["--out", str(out), "--points-per-part", "20", "--fps", "50", "--workers", "1"]
    res = CliRunner().invoke(main, args)
    assert res.exit_code == 0, res.output
    from pointtraj.session import Capture

    cap = Capture.open(out)
    expected, _ = twin_rig(load_rig(tmp_path / "rig.toml"), up="+y")
    assert (
        cap.fps == 50 and np.allclose(cap.rig.C, expected.C) and np.allclose(cap.rig.R, expected.R)
    )
    gt = load_ground_truth(out)
    assert gt.visible[:, 0].any(axis=0).all()  # every camera sees the subject
    # Another rig in the same folder is another capture.
    save_rig(rig, tmp_path / "other.toml")
    res = CliRunner().invoke(main, [*args[:2], str(tmp_path / "other.toml"), *args[3:]])
    assert res.exit_code == 1 and "holds a different synthetic capture" in res.output
    res = CliRunner().invoke(main, ["synth", "--at", "0,0,1", "--out", str(tmp_path / "x")])
    assert res.exit_code != 0 and "give --rig" in res.output


def test_paper69t_is_paper69_at_an_eighth_and_10_hz():
    """The rig of pipelines/paper_table1.toml: paper69's geometry and fields of view."""
    full, small = make_rig("paper69"), make_rig("paper69t")
    np.testing.assert_allclose(small.C, full.C)
    assert all(tuple(c.size) == (160, 128) for c in small)
    # The same fields of view: a point projects to an eighth of its full-size pixel.
    X = np.array([[0.2, -0.1, 1.2], [0.0, 0.3, 0.4]])
    np.testing.assert_allclose(
        (small.project(X).pixels + 0.5) * 8, full.project(X).pixels + 0.5, atol=1e-6
    )
    assert PRESETS["paper69t"].fps == 10.0 and PRESETS["paper69"].fps == 30.0
