"""``pointtraj reconstruct``: outputs, resume, configuration and bad input."""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from helpers.rigs import plane_rig
from helpers.scenes import plane_frames

from pointtraj.cli import main
from pointtraj.trajectories import Trajectories

T = 4


@pytest.fixture()
def plane_capture(tmp_path: Path) -> Path:
    """A real capture folder (rig.toml, capture.toml, PNG frames) of a moving textured plane."""
    from pointtraj.session import Capture

    rig = plane_rig(angles=(-15.0, 0.0, 15.0), size=(400, 300), focal=340.0, names="cam{i}")
    cap = Capture.create(tmp_path / "capture", rig, fps=25.0, image_format="png")
    for t, images in enumerate(plane_frames(rig, T, seed=5, velocity=(0.01, 0.0, 0.02))):
        for cam, image in zip(rig, images):
            cap.write_frame(cam.name, t, image)
    return tmp_path / "capture"


def _config(tmp_path: Path, extra: str = "", name: str = "reconstruct") -> Path:
    path = tmp_path / f"{name}.toml"
    path.write_text(f"[reconstruct]\nmatching = {{ num_features = 1200 }}\n{extra}")
    return path


def _run(*args: str):
    return CliRunner().invoke(main, ["reconstruct", *map(str, args)])


@pytest.mark.slow
def test_reconstruct_writes_the_work_folder_and_resumes(plane_capture: Path, tmp_path: Path):
    import open3d as o3d

    work = tmp_path / "work"
    cfg = _config(tmp_path)
    res = _run(plane_capture, "--out", work, "--config", cfg)
    assert res.exit_code == 0, res.output
    assert "trajectories" in res.output
    meta = tomllib.loads((work / "work.toml").read_text())
    assert Path(meta["capture"]) == plane_capture.resolve()
    assert meta["reconstruct"]["matching"]["num_features"] == 1200
    traj = Trajectories.load(work / "trajectories.npz")
    assert traj.num_trajectories > 200 and traj.num_frames == T and traj.fps == 25.0
    assert traj.camera_names == ["cam0", "cam1", "cam2"]
    assert np.median(traj.lengths) == T  # the plane stays in view: trajectories persist
    # per-frame clouds carry visibility and track ids that agree with the store
    for t in range(T):
        pcd = o3d.t.io.read_point_cloud(str(work / "clouds" / f"{t:06d}.ply"))
        ids = pcd.point.track_id.numpy().ravel()
        fs = traj.frame(t)
        np.testing.assert_array_equal(np.sort(ids), np.sort(fs.track_id))
        # PLY stores the (N, C) visibility as columns visibility_0 .. visibility_{C-1}
        vis = np.hstack([pcd.point[f"visibility_{c}"].numpy() for c in range(3)])
        order, ref = np.argsort(ids), np.argsort(fs.track_id)
        np.testing.assert_allclose(vis[order], fs.visibility[ref], atol=1e-6)
        np.testing.assert_allclose(pcd.point.positions.numpy()[order], fs.xyz[ref], atol=1e-6)
    # interrupted after frame 1, the resumed run reproduces the same store
    from pointtraj.stages import load_reconstruct_config, reconstruct_work

    class Crash(Exception):
        pass

    def crash_after_frame_1(label: str, done: int, total: int) -> None:
        if done == 2:
            raise Crash

    crashed = tmp_path / "crashed"
    with pytest.raises(Crash):
        reconstruct_work(
            crashed, plane_capture, load_reconstruct_config(cfg), progress=crash_after_frame_1
        )
    assert sorted(p.name for p in (crashed / "state").iterdir()) == [
        "000000.npz",
        "000001.npz",
        "live.npz",
    ]
    work = crashed
    res = _run(plane_capture, "--out", work, "--config", cfg)
    assert res.exit_code == 0, res.output
    again = Trajectories.load(work / "trajectories.npz")
    np.testing.assert_array_equal(again.offsets, traj.offsets)
    np.testing.assert_array_equal(again.xyz, traj.xyz)
    np.testing.assert_array_equal(again.visibility, traj.visibility)
    # another parameter set in the same folder is refused unless --restart
    other = _config(tmp_path, "sigma_px = 2.0\n", name="other")
    res = _run(plane_capture, "--out", work, "--config", other)
    assert res.exit_code != 0 and "--restart" in res.output
    res = _run(plane_capture, "--out", work, "--config", other, "--frames", "1:3", "--restart")
    assert res.exit_code == 0, res.output
    assert "over frames 1:3 " in res.output  # the range run, not the capture's 0:T
    part = Trajectories.load(work / "trajectories.npz")
    assert part.first_frame.min() == 1 and part.last_frame.max() == 2
    assert sorted(p.name for p in (work / "clouds").iterdir()) == ["000001.ply", "000002.ply"]


def _one_line_error(res) -> str:
    assert res.exit_code != 0
    lines = [ln for ln in res.output.strip().splitlines() if ln.startswith("Error")]
    assert len(lines) == 1, res.output
    assert "Traceback" not in res.output
    return lines[0]


def test_bad_inputs_give_one_line_errors(plane_capture: Path, tmp_path: Path):
    cfg = _config(tmp_path)
    work = tmp_path / "w"
    bad_key = _config(tmp_path, "sigma = 3\n", name="bad")
    assert "unknown key 'sigma'" in _one_line_error(
        _run(plane_capture, "--out", work, "--config", bad_key)
    )
    assert "--frames" in _one_line_error(
        _run(plane_capture, "--out", work, "--config", cfg, "--frames", "7:9")
    )
    # a corrupt image in the middle of the run
    frame_file = next((plane_capture / "frames" / "cam1").glob("*000002.*"))
    frame_file.write_bytes(b"not an image")
    msg = _one_line_error(_run(plane_capture, "--out", work, "--config", cfg))
    assert "cam1" in msg and "corrupt" in msg
    # a frame missing in one camera
    frame_file.unlink()
    msg = _one_line_error(_run(plane_capture, "--out", tmp_path / "w2", "--config", cfg))
    assert "cam1" in msg or "frame" in msg
    # the rig and the frames disagree: a camera of the rig has no frames
    for f in (plane_capture / "frames" / "cam2").iterdir():
        f.unlink()
    (plane_capture / "frames" / "cam2").rmdir()
    msg = _one_line_error(_run(plane_capture, "--out", tmp_path / "w3", "--config", cfg))
    assert "cam2" in msg


@pytest.mark.slow
def test_reconstruct_tiny4_synthetic_against_ground_truth(tmp_path: Path):
    """End to end on a rendered ``tiny4`` dribble capture, checked against its GT depth maps."""
    from scipy.spatial import cKDTree

    from pointtraj.session import Capture
    from pointtraj.synth.groundtruth import load_depth_map

    cap_dir, work = tmp_path / "tiny4", tmp_path / "work"
    res = CliRunner().invoke(
        main,
        [
            "synth",
            "--preset",
            "tiny4",
            "--scene",
            "dribble",
            "--frames",
            "3",
            "--out",
            str(cap_dir),
        ],
    )
    assert res.exit_code == 0, res.output
    res = _run(cap_dir, "--out", work)
    assert res.exit_code == 0, res.output
    traj = Trajectories.load(work / "trajectories.npz")
    assert traj.num_trajectories > 50
    assert np.any(traj.lengths == 3)  # some trajectories are tracked over the whole clip
    rig = Capture.open(cap_dir).rig
    errors = []
    for t in range(3):
        surface = []
        for c, cam in enumerate(rig):  # GT surface: every camera's depth map back-projected
            z = load_depth_map(cap_dir, cam.name, t)
            v, u = np.nonzero(np.isfinite(z))
            xy = rig.subset([c]).normalized(np.stack([u, v], axis=1)[None].astype(float))[0]
            surface.append(np.column_stack([xy * z[v, u, None], z[v, u]]) @ cam.R + cam.C)
        d, _ = cKDTree(np.concatenate(surface)).query(traj.frame(t).xyz.astype(float))
        errors.append(d)
    err = np.concatenate(errors)
    # loose bounds: 320x256 images 90 degrees apart, one pixel is about 1 cm at the figure and
    # several cm on the far floor (measured: median 3-4 cm, about half within 3 cm; wrong
    # matches would give tens of cm)
    assert np.median(err) < 0.08
    assert np.mean(err < 0.03) > 0.35
