"""C3D and TRC exports of joint centres and part centroids (pointtraj.export.mocap)."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from pointtraj.cli import main
from pointtraj.errors import FileFormatError, ValidationError
from pointtraj.export.mocap import Markers, load_trc, save_c3d, save_trc, segment_markers
from pointtraj.geometry import rotation_from_rodrigues
from pointtraj.segments import JOINT_STATUS, Segments, load_segments, save_segments

T = 6


def _segments() -> Segments:
    """Two segments with exact poses (frame 2 of the head missing) and two joints, one of them
    not observable."""
    R = np.stack([rotation_from_rodrigues([0.0, 0.0, 0.1 * t]) for t in range(T)])
    rot = np.stack([R, R])  # (2, T, 3, 3)
    trans = np.stack([[[0.01 * t, 0.0, 0.0] for t in range(T)]] * 2)
    rot[1, 2] = np.nan
    trans[1, 2] = np.nan
    status = np.array([JOINT_STATUS.index("ball"), JOINT_STATUS.index("no_rotation")], np.int8)
    local = np.full((2, 2, 3), np.nan)
    local[0] = [0.0, 0.0, 1.5]
    return Segments(
        class_names=("torso", "head"),
        segment_label=[0, 1],
        segment_instance=[0, 0],
        reference_frame=[0, 0],
        origin=[[0.0, 0.0, 1.2], [0.0, 0.0, 1.7]],
        rotation=rot,
        translation=trans,
        points=np.full((2, T), 50),
        inliers=np.full((2, T), 50),
        residual=np.zeros((2, T)),
        joint_names=("neck", "jaw"),
        joint_segments=[[0, 1], [1, 0]],
        joint_instance=[0, 0],
        joint_local=local,
        joint_status=status,
        fps=25.0,
    )


def _expected() -> tuple[list[str], np.ndarray]:
    seg = _segments()
    xyz = np.stack([seg.joint_positions()[0], *seg.centroids()], axis=1)  # (T, 3, 3)
    return ["neck", "torso_centroid", "head_centroid"], xyz


def test_markers_skip_unobservable_joints():
    m = segment_markers(_segments())
    names, xyz = _expected()
    assert m.names == names and m.xyz.shape == (T, 3, 3) and m.fps == 25.0
    np.testing.assert_allclose(m.xyz, xyz)
    joint = np.array([[0.01 * t, 0.0, 1.5] for t in range(T)])
    posed = np.arange(T) != 2
    np.testing.assert_allclose(m.xyz[posed, 0], joint[posed], atol=1e-12)
    assert np.isnan(m.xyz[2, 0]).all() and np.isnan(m.xyz[2, 2]).all()  # head pose missing
    assert segment_markers(_segments(), centroids=False).names == ["neck"]


@pytest.mark.parametrize("units", ["mm", "m"])
def test_c3d_reads_back_with_ezc3d(tmp_path, units):
    ezc3d = pytest.importorskip("ezc3d")
    names, xyz = _expected()
    path = tmp_path / "out.c3d"
    save_c3d(segment_markers(_segments()), path, units=units)
    c3d = ezc3d.c3d(str(path))
    point = c3d["parameters"]["POINT"]
    assert list(point["LABELS"]["value"]) == names
    assert point["RATE"]["value"][0] == 25.0 and point["UNITS"]["value"] == [units]
    data = c3d["data"]["points"]  # (4, K, T)
    assert data.shape == (4, 3, T)
    back = np.transpose(data[:3], (2, 1, 0)) * (0.001 if units == "mm" else 1.0)
    ok = np.isfinite(xyz)
    np.testing.assert_allclose(back[ok], xyz[ok], atol=1e-6)  # C3D stores float32
    assert np.isnan(back[2, 0]).all()  # the gap survives
    assert c3d["data"]["meta_points"]["residuals"][0, 0, 2] < 0


def _pose2sim_style_read(path: Path) -> tuple[list[str], np.ndarray]:
    """A minimal independent TRC reader, as Pose2Sim reads it: marker names from line 4 every
    third tab field, data from line 6 (Frame#, Time, then X Y Z per marker)."""
    lines = path.read_text(encoding="utf-8").splitlines()
    names = lines[3].split("\t")[2:][::3]
    rows = [[float(v) if v else np.nan for v in ln.split("\t")] for ln in lines[5:]]
    return [n for n in names if n], np.array(rows)


@pytest.mark.parametrize("up", ["z", "y"])
def test_trc_round_trip(tmp_path, up):
    names, xyz = _expected()
    path = tmp_path / "out.trc"
    save_trc(segment_markers(_segments()), path, units="mm", up=up)
    header = path.read_text(encoding="utf-8").splitlines()[:3]
    assert header[0].startswith("PathFileType\t4\t(X/Y/Z)\tout.trc")
    assert header[2].split("\t")[:5] == ["25", "25", str(T), "3", "mm"]
    markers, units = load_trc(path)
    assert units == "mm" and markers.names == names and markers.fps == 25.0
    want = xyz if up == "z" else xyz[..., [1, 2, 0]]
    np.testing.assert_allclose(markers.xyz, want, atol=1e-9)  # NaN where NaN
    other_names, table = _pose2sim_style_read(path)
    assert other_names == names
    np.testing.assert_array_equal(table[:, 0], np.arange(1, T + 1))
    np.testing.assert_allclose(table[:, 1], np.arange(T) / 25.0, atol=1e-9)
    np.testing.assert_allclose(table[:, 2:] / 1000, want.reshape(T, -1), atol=1e-9)


def test_bad_input(tmp_path):
    m = segment_markers(_segments())
    with pytest.raises(ValidationError, match="units"):
        save_trc(m, tmp_path / "x.trc", units="cm")
    with pytest.raises(ValidationError, match="up"):
        save_c3d(m, tmp_path / "x.c3d", up="x")
    with pytest.raises(ValidationError, match="no markers"):
        save_trc(Markers([], np.zeros((T, 0, 3)), 25.0), tmp_path / "x.trc")
    bad = tmp_path / "bad.trc"
    bad.write_text("hello\n", encoding="utf-8")
    with pytest.raises(FileFormatError, match="bad.trc.*not a TRC"):
        load_trc(bad)
    with pytest.raises(FileFormatError, match="no such file"):
        load_trc(tmp_path / "missing.trc")
    save_trc(m, bad)
    lines = bad.read_text(encoding="utf-8").splitlines()
    lines[2] = lines[2].replace("\tmm\t", "\tinch\t")
    bad.write_text("\n".join(lines), encoding="utf-8")
    with pytest.raises(FileFormatError, match="bad.trc.*inch"):
        load_trc(bad)


def test_export_commands(tmp_path):
    """``pointtraj export c3d`` / ``trc`` on a work folder's segments.npz; a folder without
    one is a one-line error naming the file."""
    work = tmp_path / "work"
    work.mkdir()
    save_segments(_segments(), work / "segments.npz")
    runner = CliRunner()
    res = runner.invoke(main, ["export", "trc", str(work), "--units", "m"])
    assert res.exit_code == 0, res.output
    assert "3 markers x 6 frames at 25 Hz (m)" in res.output
    markers, units = load_trc(work / "segments.trc")
    assert units == "m" and markers.names == _expected()[0]
    out = tmp_path / "joints.c3d"
    res = runner.invoke(main, ["export", "c3d", str(work), "--out", str(out), "--no-centroids"])
    assert res.exit_code == 0, res.output and out.is_file()
    assert "1 markers" in res.output
    empty = tmp_path / "empty"
    empty.mkdir()
    res = runner.invoke(main, ["export", "c3d", str(empty)])
    assert res.exit_code == 1 and "segments.npz" in res.output and "Traceback" not in res.output
    assert load_segments(work / "segments.npz").joint_names == ("neck", "jaw")


def test_export_after_pipeline(tiny_reference, tmp_path):
    """The tiny pipeline's segments stage, then both exports: the markers are the part
    centroids (3 frames are too few for any joint, which the command lists as few_frames)."""
    work = tmp_path / "work"
    shutil.copytree(tiny_reference / "work", work)
    seg = load_segments(work / "segments.npz")
    assert seg.num_segments > 0 and seg.num_frames == 3
    assert all(JOINT_STATUS[s] in ("few_frames", "missing_part") for s in seg.joint_status)
    runner = CliRunner()
    res = runner.invoke(main, ["segments", str(work)])
    assert res.exit_code == 0, res.output
    assert "few_frames" in res.output
    for fmt in ("c3d", "trc"):
        res = runner.invoke(main, ["export", fmt, str(work)])
        assert res.exit_code == 0, res.output
    markers, _ = load_trc(work / "segments.trc")
    assert len(markers.names) == seg.num_segments
    assert all(n.endswith("_centroid") for n in markers.names)
