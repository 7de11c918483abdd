"""Rendering: Open3D off-screen views agree with the camera model; tails; overlays; video;
``render_work`` and ``pointtraj render`` on a small labelled work folder (real files, real
Open3D and OpenCV rendering)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from pointtraj.camera import Camera, CameraRig
from pointtraj.cli import main
from pointtraj.errors import FileFormatError, ValidationError
from pointtraj.labelset import LabelSet
from pointtraj.render import (
    RenderConfig,
    TrajectoryRenderer,
    class_palette,
    draw_legend,
    draw_overlay,
    draw_scene,
    floor_grid,
    label_colors,
    legend_image,
    orbit_cameras,
    read_png,
    render_work,
    tail_segments,
    write_png,
    write_video,
)
from pointtraj.session import Capture
from pointtraj.trajectories import Trajectories

RED, BLUE = (255, 0, 0), (0, 0, 255)


@pytest.fixture
def spinning_blob() -> Trajectories:
    rng = np.random.default_rng(1)
    M, T = 400, 12
    base = rng.normal(size=(M, 3)) * 0.1 + [0, 0, 1]
    ang = 0.05 * np.arange(T)
    xyz = np.empty((M, T, 3))
    xyz[..., 0] = base[:, None, 0] * np.cos(ang) - base[:, None, 1] * np.sin(ang)
    xyz[..., 1] = base[:, None, 0] * np.sin(ang) + base[:, None, 1] * np.cos(ang)
    xyz[..., 2] = base[:, None, 2]
    start = rng.integers(0, 6, M)
    xyz[np.arange(T)[None] < start[:, None]] = np.nan
    return Trajectories.from_dense(xyz)


def test_tail_segments_follow_each_trajectory(spinning_blob):
    tr = spinning_blob
    seg, track, age = tail_segments(tr, 10, 3)
    # Every trajectory alive at 10 contributes min(3, age) segments.
    alive = tr.row_track[tr.frame_rows(10)]
    expected = np.minimum(3, 10 - tr.first_frame[alive]).sum()
    assert len(seg) == len(track) == len(age) == expected
    assert set(age.tolist()) == {1, 2, 3}
    # Segments join consecutive positions of their own trajectory, ``age`` frames back.
    dense = tr.dense_positions()
    np.testing.assert_allclose(dense[track, 10 - age], seg[:, 0], atol=1e-6)
    np.testing.assert_allclose(dense[track, 11 - age], seg[:, 1], atol=1e-6)
    assert tail_segments(tr, 10, 0)[0].shape == (0, 2, 3)


def test_label_colors_unlabelled_grey():
    pal = np.array([[255, 0, 0], [0, 0, 255]], np.uint8)
    out = label_colors(np.array([0, 1, -1, 7]), pal)
    assert out.tolist() == [[255, 0, 0], [0, 0, 255], [128, 128, 128], [128, 128, 128]]


def test_class_palette_by_name_with_fallbacks():
    own = LabelSet(["ball", "stick"], [[1, 2, 3], [4, 5, 6]])
    pal = class_palette(["stick", "head", "unknown_a", "unknown_b"], own)
    assert pal.shape == (4, 3) and pal.dtype == np.uint8
    assert pal[0].tolist() == [4, 5, 6]  # from the capture's label set, by name
    default = LabelSet.default()
    assert pal[1].tolist() == default.colors[default.index("head")].tolist()
    assert pal[2].tolist() != pal[3].tolist()  # generated colours are distinct


def test_open3d_render_matches_projection(spinning_blob):
    """The off-screen renderer's camera set-up must agree with CameraRig.project."""
    tr = spinning_blob
    cam = orbit_cameras([0, 0, 1], 2.0, 0.5, 3, size=(320, 240))[1]
    colors = np.tile(np.array([[200, 0, 0]], np.uint8), (tr.num_trajectories, 1))
    with TrajectoryRenderer(cam.size, point_size=2.0) as renderer:
        img = renderer.render_frame(tr, 8, cam, colors, tail=0)
        with pytest.raises(ValidationError, match="renderer"):
            renderer.render(orbit_cameras([0, 0, 1], 2.0, 0.5, 1, size=(64, 48))[0], [], [])
        with pytest.raises(ValidationError, match="another TrajectoryRenderer is open"):
            TrajectoryRenderer((64, 48))
    assert img.shape == (240, 320, 3)
    drawn = (img[..., 0] > 150) & (img[..., 1] < 100)
    assert drawn.sum() > 50
    ys, xs = np.nonzero(drawn)
    proj = CameraRig([cam]).project(tr.frame(8).xyz)
    centroid = proj.pixels[0][proj.in_image[0]].mean(axis=0)
    assert np.hypot(xs.mean() - centroid[0], ys.mean() - centroid[1]) < 3.0
    with pytest.raises(ValidationError, match="closed"):
        renderer.render(cam, [], [])


def test_overlay_draws_points_and_video(tmp_path, spinning_blob):
    tr = spinning_blob
    cam = orbit_cameras([0, 0, 1], 2.0, 0.5, 2, size=(320, 240))[0]
    colors = np.tile(np.array([[0, 0, 255]], np.uint8), (tr.num_trajectories, 1))
    canvas = np.full((240, 320, 3), 255, np.uint8)
    out = draw_overlay(canvas, cam, tr, 8, colors, tail=4, radius=2)
    blue = (out[..., 2] > 200) & (out[..., 0] < 100)
    assert blue.sum() > 100
    assert np.all(canvas == 255), "draw_overlay must not modify its input"
    n = write_video(tmp_path / "v.mp4", [out, out, out], fps=5)
    assert n == 3 and (tmp_path / "v.mp4").stat().st_size > 0
    import cv2

    cap = cv2.VideoCapture(str(tmp_path / "v.mp4"))
    assert int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == 3
    with pytest.raises(ValidationError, match="no frames"):
        write_video(tmp_path / "empty.mp4", [])
    assert not (tmp_path / "empty.mp4").exists()


def test_draw_scene_nearest_point_wins_and_distortion():
    cam = Camera.look_at("c", [0, 0, 0], [0, 0, 1], (64, 48), 50.0, up=(0, -1, 0))
    canvas = np.zeros((48, 64, 3), np.uint8)
    near, far = [0.0, 0.0, 1.0], [0.0, 0.0, 3.0]  # both on the optical axis
    for order in ([near, far], [far, near]):
        cols = np.array([RED, BLUE] if order[0] is near else [BLUE, RED], np.uint8)
        out = draw_scene(canvas, cam, np.array(order), cols, radius=1)
        px = np.rint(cam.project([near])[0][0]).astype(int)
        assert tuple(out[px[1], px[0]]) == RED
    # The OpenCV engine uses the distortion model.
    dcam = Camera(cam.name, cam.K, cam.R, cam.C, cam.size, dist=[-0.3, 0.1, 0, 0, 0])
    pt = np.array([[0.25, 0.2, 1.0]])
    out = draw_scene(canvas, dcam, pt, np.array([RED], np.uint8), radius=0)
    px = np.rint(dcam.project(pt)[0][0]).astype(int)
    assert tuple(out[px[1], px[0]]) == RED
    assert np.count_nonzero(out.any(axis=2)) == 1


def test_floor_grid_lies_in_its_plane():
    up = np.array([0.0, 1.0, 1.0]) / np.sqrt(2)
    seg = floor_grid([1.0, 2.0, 3.0], up, 1.0, 0.5)
    assert seg.ndim == 3 and seg.shape[1:] == (2, 3)
    heights = seg.reshape(-1, 3) @ up
    np.testing.assert_allclose(heights, np.array([1.0, 2.0, 3.0]) @ up, atol=1e-9)
    # 5 lines each way, each 2 m long.
    np.testing.assert_allclose(np.linalg.norm(seg[:, 1] - seg[:, 0], axis=1).sum(), 20.0)
    with pytest.raises(ValidationError, match="positive"):
        floor_grid([0, 0, 0], [0, 0, 1], 1.0, 0.0)


def test_legend_swatches_and_overflow():
    names, cols = ["red_thing", "blue_thing"], np.array([RED, BLUE], np.uint8)
    img = legend_image(names, cols)
    for c in (RED, BLUE):
        assert np.all(img == c, axis=2).sum() > 20
    small = np.zeros((60, 200, 3), np.uint8)
    out = draw_legend(small, [f"class{i}" for i in range(10)], np.tile(RED, (10, 1)))
    assert out.shape == small.shape and out.any()  # clipped, not crashing


# -- a tiny labelled work folder -------------------------------------------------------------
T = 6
SIZE = (160, 128)


def make_work(root: Path, *, labels: bool = True) -> Path:
    """Capture (2 cameras, T frames, labels.toml) + work folder with a labelled store.

    Class 0 (red) is a cluster at y = -0.3, class 1 (blue) one at y = +0.3, both drifting
    in z; one trajectory is unlabelled (-1).
    """
    rng = np.random.default_rng(0)
    rig = CameraRig(
        [
            Camera.look_at("cam0", [2.0, 0.0, 1.0], [0, 0, 1.0], SIZE, 120.0),
            Camera.look_at("cam1", [0.3, 2.0, 1.2], [0, 0, 1.0], SIZE, 120.0),
        ]
    )
    cap = Capture.create(root / "cap", rig, fps=10.0, image_format="png")
    for c in range(len(rig)):
        for t in range(T):
            img = np.zeros((SIZE[1], SIZE[0], 3), np.uint8)
            img[..., 1] = 40 + 20 * t
            cap.write_frame(c, t, img)
    LabelSet(["red_thing", "blue_thing"], [RED, BLUE]).save(root / "cap" / "labels.toml")
    M = 41
    lab = np.repeat([0, 1], 20)
    base = rng.normal(size=(40, 3)) * [0.05, 0.05, 0.1]
    base[:, 1] += np.where(lab == 0, -0.3, 0.3)
    base[:, 2] += 1.0
    base = np.vstack([base, [[0.0, 0.0, 0.5]]])
    lab = np.append(lab, -1)
    xyz = base[:, None, :] + np.array([0, 0, 0.02])[None, None] * np.arange(T)[None, :, None]
    xyz[::3, :2] = np.nan  # some trajectories start late
    work = root / "work"
    work.mkdir()
    Trajectories.from_dense(xyz, np.ones((M, T, 2)), camera_names=rig.names, fps=10.0).save(
        work / "trajectories.npz"
    )
    (work / "work.toml").write_text(f'capture = "{(root / "cap").as_posix()}"\n')
    if labels:
        np.savez(
            work / "labels.npz",
            labels=lab.astype(np.int64),
            class_names=np.array(["red_thing", "blue_thing"]),
        )
    return work


@pytest.fixture
def tiny_work(tmp_path) -> Path:
    return make_work(tmp_path)


@pytest.mark.parametrize("engine", ["open3d", "opencv"])
def test_render_work_colours_land_where_projected(tiny_work, engine):
    cfg = RenderConfig(
        engine=engine,
        views=("cam0",),
        frames=(3, 4),
        tail=0,
        overlays=False,
        video=False,
        legend=False,
        caption=False,
        floor=False,
    )
    res = render_work(tiny_work, cfg)
    assert res.color_source == "labels.npz"
    assert res.classes == ["red_thing", "blue_thing", "unlabelled"]
    assert res.rendered == 1 and res.outputs[0].video is None
    img = read_png(tiny_work / "renders" / "views" / "cam0" / "000003.png")
    assert img.shape == (SIZE[1], SIZE[0], 3)
    tr = Trajectories.load(tiny_work / "trajectories.npz")
    with np.load(tiny_work / "labels.npz") as z:
        lab = z["labels"]
    fs = tr.frame(3)
    cam = Capture.open(tiny_work.parent / "cap").rig["cam0"]
    px = np.rint(cam.project(fs.xyz)[0]).astype(int)
    got = img[px[:, 1], px[:, 0]]  # (N, 3)
    for k, col in ((0, RED), (1, BLUE), (-1, (128, 128, 128))):
        sel = lab[fs.track_id] == k
        assert sel.any()
        assert np.mean(np.all(got[sel] == col, axis=1)) > 0.9, (engine, k)
    # Red is on the left of cam0's image (world -y), blue on the right; background white.
    assert px[lab[fs.track_id] == 0, 0].max() < px[lab[fs.track_id] == 1, 0].min()
    assert tuple(img[2, 2]) == (255, 255, 255)


def test_render_work_can_hide_unlabelled(tiny_work, tmp_path):
    cfg = RenderConfig(
        engine="opencv", views=("cam0",), frames=(3, 4), tail=0, overlays=False, video=False,
        legend=False, caption=False, floor=False, unlabelled=False,
    )  # fmt: skip
    res = render_work(tiny_work, cfg)
    assert res.classes == ["red_thing", "blue_thing"]
    img = read_png(tiny_work / "renders" / "views" / "cam0" / "000003.png")
    assert not np.all(img == 128, axis=2).any()  # no grey point
    assert np.all(img == RED, axis=2).any() and np.all(img == BLUE, axis=2).any()
    grey = make_work(tmp_path / "g", labels=False)
    with pytest.raises(ValidationError, match="nothing to render: no trajectory is labelled"):
        render_work(grey, dataclasses.replace(cfg, colors="grey"))


def test_render_work_colours_by_person(tiny_work):
    """color_by = "instance": one colour per person id of labels.npz, grey for no person; a
    labels.npz without person ids is a one-line error."""
    from pointtraj.errors import FileFormatError
    from pointtraj.render.palette import person_palette

    cfg = RenderConfig(
        engine="opencv", views=("cam0",), frames=(3, 4), tail=0, overlays=False, video=False,
        legend=False, caption=False, floor=False, color_by="instance",
    )  # fmt: skip
    with pytest.raises(FileFormatError, match="has no instance"):
        render_work(tiny_work, cfg)
    with np.load(tiny_work / "labels.npz") as z:
        lab = z["labels"]
    # the red cluster is two people (split by trajectory parity), the blue one nobody
    person = np.where(lab == 0, np.arange(len(lab)) % 2, -1)
    np.savez(
        tiny_work / "labels.npz",
        labels=lab,
        class_names=np.array(["red_thing", "blue_thing"]),
        instance=person,
    )
    res = render_work(tiny_work, cfg)
    assert res.classes == ["person 0", "person 1", "no person"]
    img = read_png(tiny_work / "renders" / "views" / "cam0" / "000003.png")
    tr = Trajectories.load(tiny_work / "trajectories.npz")
    fs = tr.frame(3)
    cam = Capture.open(tiny_work.parent / "cap").rig["cam0"]
    px = np.rint(cam.project(fs.xyz)[0]).astype(int)
    got = img[px[:, 1], px[:, 0]]
    colours = person_palette(2)
    for p, col in ((0, colours[0]), (1, colours[1]), (-1, (128, 128, 128))):
        sel = person[fs.track_id] == p
        assert sel.any()
        assert np.mean(np.all(got[sel] == col, axis=1)) > 0.6, p
    with pytest.raises(ValidationError, match="color_by"):
        RenderConfig(color_by="person")


def test_render_work_orbit_overlay_and_semantic_map_fallback(tmp_path):
    from pointtraj.semantics.semantic_map import SemanticMap

    work = make_work(tmp_path, labels=False)
    M = Trajectories.load(work / "trajectories.npz").num_trajectories
    L = np.zeros((M, 2), np.float32)
    L[:20, 0] = L[20:40, 1] = 1.0
    SemanticMap(
        ("red_thing", "blue_thing"),
        {"view": L},
        {"view": np.where(np.arange(M) < 40, 3, 0).astype(np.int32)},
    ).save(work / "semantic_map.npz")
    cfg = RenderConfig(engine="opencv", size=(200, 160), tail=3, overlay_cameras=("cam1",))
    res = render_work(work, cfg)
    assert res.color_source == "semantic_map.npz (argmax)"
    assert [(o.kind, o.name) for o in res.outputs] == [("view", "orbit"), ("overlay", "cam1")]
    orbit = read_png(work / "renders" / "views" / "orbit" / "000005.png")
    assert orbit.shape == (160, 200, 3)
    for c in (RED, BLUE):
        assert np.all(orbit == c, axis=2).sum() > 30
    ov = read_png(work / "renders" / "overlays" / "cam1" / "000005.png")
    assert np.all(ov == RED, axis=2).sum() > 30
    assert (ov[..., 1] == 40 + 20 * 5).sum() > 0.5 * ov[..., 1].size  # the camera image below
    assert read_png(res.legend).shape[2] == 3


def test_render_work_errors(tmp_path, tiny_work):
    with pytest.raises(FileFormatError, match="trajectories.npz: no such file"):
        render_work(tmp_path / "cap")
    with pytest.raises(ValidationError, match=r"unknown view or camera 'cam9' \(valid: orbit"):
        render_work(tiny_work, RenderConfig(views=("cam9",)))
    with pytest.raises(ValidationError, match="frames 4:2 is not a non-empty range"):
        render_work(tiny_work, RenderConfig(frames=(4, 2)))
    with pytest.raises(ValidationError, match="within the store's frames 0:6"):
        render_work(tiny_work, RenderConfig(frames=(0, 9)))
    with pytest.raises(ValidationError, match="tail_fade"):
        RenderConfig(tail_fade=2.0)
    with pytest.raises(ValidationError, match="nothing to render"):
        RenderConfig(views=(), overlays=False)
    unlabelled = make_work(tmp_path / "u", labels=False)
    with pytest.raises(FileFormatError, match="not labelled"):
        render_work(unlabelled)
    res = render_work(
        unlabelled, RenderConfig(engine="opencv", colors="grey", size=(64, 48), frames=(0, 1))
    )
    assert res.classes == ["unlabelled"]


def test_render_work_without_capture_renders_orbit_only(tmp_path):
    work = make_work(tmp_path)
    (work / "work.toml").unlink()
    res = render_work(work, RenderConfig(engine="opencv", size=(64, 48), frames=(0, 2)))
    assert [(o.kind, o.name, o.rendered) for o in res.outputs] == [("view", "orbit", 2)]
    with pytest.raises(ValidationError, match="'cam0' needs the capture's cameras"):
        render_work(work, RenderConfig(views=("cam0",)))
    with pytest.raises(ValidationError, match="nothing to render"):
        render_work(work, RenderConfig(views=()))


def _pngs(folder: Path) -> dict[str, int]:
    return {p.name: p.stat().st_mtime_ns for p in sorted(folder.glob("*.png"))}


def test_cli_writes_pngs_and_mp4_and_resumes(tiny_work):
    import cv2

    runner = CliRunner()
    args = ["render", str(tiny_work), "--engine", "opencv", "--view", "orbit", "--view", "cam1"]
    args += ["--size", "160x120", "--tail", "3"]
    res = runner.invoke(main, args)
    assert res.exit_code == 0, res.output
    renders = tiny_work / "renders"
    folders = [
        renders / "views" / "orbit",
        renders / "views" / "cam1",
        renders / "overlays" / "cam1",
    ]
    for folder in folders:
        assert list(_pngs(folder)) == [f"{t:06d}.png" for t in range(T)]
        video = cv2.VideoCapture(str(folder.with_suffix(".mp4")))
        assert int(video.get(cv2.CAP_PROP_FRAME_COUNT)) == T
        assert int(video.get(cv2.CAP_PROP_FRAME_HEIGHT)) == (120 if folder.name == "orbit" else 128)
        video.release()
    assert (renders / "legend.png").is_file()
    assert "18 images rendered" in res.output and "0 kept" in res.output

    # A rerun keeps everything; a lost frame is re-rendered alone.
    before = _pngs(folders[0])
    (folders[1] / "000002.png").unlink()
    res = runner.invoke(main, args)
    assert res.exit_code == 0, res.output
    assert "1 images rendered" in res.output and "17 kept" in res.output
    assert _pngs(folders[0]) == before
    # --force re-renders; other settings make old frames stale (and drop those out of range).
    res = runner.invoke(main, [*args, "--force", "--no-overlays", "--frames", "0:2"])
    assert "4 images rendered" in res.output
    assert _pngs(folders[0])["000000.png"] != before["000000.png"]
    res = runner.invoke(main, [*args[:-1], "5", "--frames", "1:3", "--no-video"])
    assert res.exit_code == 0, res.output
    assert list(_pngs(folders[0])) == ["000001.png", "000002.png"]


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--view", "cam7"], "unknown view or camera 'cam7' (valid: orbit, cam0, cam1)"),
        (["--frames", "3:99"], "frames 3:99 is not a non-empty range"),
        (["--frames", "three"], "expected A:B"),
        (["--size", "big"], "expected WIDTHxHEIGHT"),
        (["--tail", "-2"], "tail: must be non-negative"),
        (["--up", "sideways"], "up: expected 'auto', one of +x, -x, +y, -y, +z, -z"),
    ],
)
def test_cli_errors_are_one_line(tiny_work, extra, message):
    res = CliRunner().invoke(main, ["render", str(tiny_work), "--engine", "opencv", *extra])
    assert res.exit_code != 0
    assert message in res.output
    assert "Traceback" not in res.output
    assert not (tiny_work / "renders" / "views").exists()


def test_cli_unlabelled_and_missing_work(tmp_path):
    work = make_work(tmp_path, labels=False)
    res = CliRunner().invoke(main, ["render", str(work)])
    assert res.exit_code == 1 and "not labelled: no labels.npz or semantic_map.npz" in res.output
    res = CliRunner().invoke(main, ["render", str(tmp_path / "nowhere")])
    assert res.exit_code == 2 and "does not exist" in res.output


def test_write_png_roundtrip(tmp_path):
    img = np.random.default_rng(0).integers(0, 256, (9, 7, 3), dtype=np.uint8)
    write_png(tmp_path / "a.png", img)
    np.testing.assert_array_equal(read_png(tmp_path / "a.png"), img)
    with pytest.raises(FileFormatError, match="cannot read"):
        read_png(tmp_path / "missing.png")


# -- scale and up axis -----------------------------------------------------------------------
def make_scaled_work(root: Path, scale: float = 1.0, rotation: np.ndarray | None = None) -> Path:
    """A labelled work folder (:func:`make_work`'s scene and rig) mapped by ``X -> s Q X``:
    ``scale`` 0.01 makes the 1.2 m scene a 1.2 cm one seen from 2-3 cm, ``rotation`` Q a world
    frame that is not z-up."""
    Q = np.eye(3) if rotation is None else np.asarray(rotation, float)
    src = make_work(root / "src")
    rig = Capture.open(src.parent / "cap").rig
    moved = CameraRig(
        [Camera(c.name, c.K, c.R @ Q.T, scale * Q @ c.C, c.size, c.dist) for c in rig]
    )
    cap = Capture.create(root / "cap", moved, fps=10.0, image_format="png")
    for c in range(len(moved)):
        for t in range(T):
            cap.write_frame(c, t, np.zeros((SIZE[1], SIZE[0], 3), np.uint8))
    LabelSet(["red_thing", "blue_thing"], [RED, BLUE]).save(root / "cap" / "labels.toml")
    tr = Trajectories.load(src / "trajectories.npz")
    xyz = scale * tr.dense_positions() @ Q.T
    work = root / "work"
    work.mkdir()
    Trajectories.from_dense(
        xyz, np.ones((*xyz.shape[:2], 2)), camera_names=rig.names, fps=10.0
    ).save(work / "trajectories.npz")
    (work / "work.toml").write_text(f'capture = "{(root / "cap").as_posix()}"\n')
    (src / "labels.npz").rename(work / "labels.npz")
    return work


_SCALE_CFG = dict(frames=(3, 4), tail=3, overlays=False, video=False, legend=False, caption=False)


def _drawn(img: np.ndarray) -> np.ndarray:
    return np.any(img != 255, axis=2)


def test_open3d_renders_a_centimetre_scene_like_a_metre_one(tmp_path):
    """Regression: the Open3D engine drew nothing when the camera was within 10 cm of the
    scene (Filament's fixed 0.1 m near plane), and the orbit framed at least 10 cm. A scene
    and rig scaled by 0.01 must render as the full-size one does, floor grid included."""
    big = make_scaled_work(tmp_path / "big", 1.0)
    small = make_scaled_work(tmp_path / "small", 0.01)
    cfg = RenderConfig(engine="open3d", views=("orbit", "cam0"), size=SIZE, **_SCALE_CFG)
    for work in (big, small):
        render_work(work, cfg)
    for view in ("orbit", "cam0"):
        a = read_png(big / "renders" / "views" / view / "000003.png")
        b = read_png(small / "renders" / "views" / view / "000003.png")
        assert _drawn(a).sum() > 300, view
        assert np.all(b == RED, axis=2).sum() > 20 and np.all(b == BLUE, axis=2).sum() > 20
        # The same picture: pixels drawn in one and not the other are under 2 % of those drawn.
        assert np.sum(_drawn(a) ^ _drawn(b)) < 0.02 * _drawn(a).sum(), view


def test_clip_planes_follow_the_scene():
    from pointtraj.render.offscreen import clip_planes

    cam = Camera.look_at("c", [0, 0, 0], [0, 0, 1], (64, 48), 50.0, up=(0, -1, 0))
    near, far = clip_planes(cam, np.array([[0, 0, 0.02], [0.001, 0, 0.03]]))
    assert near == pytest.approx(0.01) and far == pytest.approx(0.06)
    seg = np.array([[[0, 0, 5.0], [0, 0, 40.0]]])
    near, far = clip_planes(cam, np.array([[0, 0, 1e-9]]), seg)  # near is kept above far / 1e5
    assert far == pytest.approx(80.0) and near == pytest.approx(80.0 / 1e5)
    assert clip_planes(cam, np.array([[0, 0, -1.0]])) == (0.1, 100.0)  # all behind


def test_orbit_and_floor_follow_a_y_down_world(tmp_path):
    """A world frame whose up is -y (a camera's frame, as caliscope writes it) renders as the
    z-up one does: up is detected from the cameras, or set with ``up``; a wrong ``up`` gives a
    different picture."""
    Q = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])  # z -> -y
    zup = make_scaled_work(tmp_path / "z", 1.0)
    ydown = make_scaled_work(tmp_path / "y", 1.0, Q)
    cfg = RenderConfig(engine="opencv", views=("orbit",), size=SIZE, **_SCALE_CFG)
    for up, zup_up in (("auto", "auto"), ("-y", "+z")):
        render_work(zup, dataclasses.replace(cfg, up=zup_up))
        ref = read_png(zup / "renders" / "views" / "orbit" / "000003.png")
        render_work(ydown, dataclasses.replace(cfg, up=up))
        img = read_png(ydown / "renders" / "views" / "orbit" / "000003.png")
        assert np.sum(_drawn(ref) ^ _drawn(img)) < 0.02 * _drawn(ref).sum(), up
    render_work(ydown, dataclasses.replace(cfg, up="+z"))
    wrong = read_png(ydown / "renders" / "views" / "orbit" / "000003.png")
    assert np.sum(_drawn(ref) ^ _drawn(wrong)) > 0.2 * _drawn(ref).sum()
    # capture.toml's up is used when the render's is auto.
    (ydown.parent / "cap" / "capture.toml").write_text('fps = 10.0\nup = "+z"\n')
    render_work(ydown, cfg)
    img = read_png(ydown / "renders" / "views" / "orbit" / "000003.png")
    np.testing.assert_array_equal(img, wrong)
    with pytest.raises(ValidationError, match=r"up: expected 'auto', one of \+x"):
        RenderConfig(up="sideways")


# -- legend placement ------------------------------------------------------------------------
def test_legend_avoids_the_subject_on_a_portrait_image():
    """Regression: the legend sat top-left whatever the image, covering the subject's head in
    portrait videos. It goes to the corner covering the fewest points drawn."""
    from pointtraj.render import legend_origin

    w, h = 180, 320
    rng = np.random.default_rng(0)
    # A subject filling the left and top of a portrait image (head top-left, body down the left).
    pts = np.vstack(
        [rng.uniform([0, 0], [w, 80], (400, 2)), rng.uniform([0, 0], [50, h], (800, 2))]
    )
    names = ["head", "torso", "left_upper_arm"]
    origin = legend_origin((w, h), names, "auto", pts)
    assert origin == legend_origin((w, h), names, "bottom-right")  # the only free corner
    assert origin[1] > h / 2
    canvas = np.zeros((h, w, 3), np.uint8)
    canvas[np.clip(pts[:, 1].astype(int), 0, h - 1), np.clip(pts[:, 0].astype(int), 0, w - 1)] = 255
    out = draw_legend(canvas, names, np.array([RED, BLUE, RED], np.uint8), origin=origin)
    changed = np.any(out != canvas, axis=2)
    assert changed.any() and not np.any(changed & np.any(canvas > 0, axis=2))
    assert legend_origin((w, h), names, "auto", None) == (10, 10)
    assert legend_origin((w, h), names, "top-right")[1] == 10
    with pytest.raises(ValidationError, match="legend corner must be 'auto' or one of"):
        legend_origin((w, h), names, "middle")


def test_portrait_legend_is_sized_like_the_landscape_one():
    """Regression: the font followed the image height, so a 1080x1920 portrait video's legend
    of the 14 body parts took a third of its width (Pose2Sim's cam01) and touched a raised hand.
    It follows the shorter side."""
    names = [f"left_upper_arm_{i}" for i in range(14)]
    cols = np.tile(RED, (14, 1))
    drawn = {}
    for size in ((1920, 1080), (1080, 1920)):
        out = draw_legend(np.zeros((size[1], size[0], 3), np.uint8), names, cols)
        cols_used = np.flatnonzero(np.any(out > 0, axis=(0, 2)))
        drawn[size] = cols_used.max() - cols_used.min() + 1
    assert drawn[(1080, 1920)] == drawn[(1920, 1080)]
    assert drawn[(1080, 1920)] < 1080 / 4


def test_overlay_legend_does_not_cover_the_points(tiny_work):
    from pointtraj.rigio.toml import save_rig_toml

    # Move cam0's principal point so that the subject is in the image's top-left corner.
    rig = Capture.open(tiny_work.parent / "cap").rig
    cam = rig["cam0"]
    K = cam.K.copy()
    K[:2, 2] -= (40, 30)
    moved = CameraRig([Camera(cam.name, K, cam.R, cam.C, cam.size, cam.dist), rig["cam1"]])
    save_rig_toml(moved, tiny_work.parent / "cap" / "rig.toml")
    cfg = RenderConfig(
        engine="opencv", views=(), overlay_cameras=("cam0",), frames=(3, 4), video=False,
        caption=False, tail=0,
    )  # fmt: skip
    render_work(tiny_work, dataclasses.replace(cfg, legend=False))
    plain = read_png(tiny_work / "renders" / "overlays" / "cam0" / "000003.png")
    render_work(tiny_work, cfg)
    with_legend = read_png(tiny_work / "renders" / "overlays" / "cam0" / "000003.png")
    changed = np.any(with_legend != plain, axis=2)
    points = np.any(plain != plain[0, 0], axis=2)  # the camera image is flat; points differ
    assert changed.sum() > 100 and points.sum() > 50
    assert not np.any(changed & points), cam.name
