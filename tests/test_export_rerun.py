"""``pointtraj export rerun``: the recording read back with Rerun's own reader
(``rerun.chunk.RrdReader``) holds, frame by frame, the store's points with their label and
person colours, the trajectories' tails, the cameras and their images; the export streams."""

from __future__ import annotations

import sys
import tracemalloc
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from pointtraj.atomic import save_npz_atomic
from pointtraj.cli import main
from pointtraj.errors import FileFormatError, ValidationError
from pointtraj.export.rerun import (
    NO_CLASS,
    PERSON_COLORS,
    RerunConfig,
    cycle_colors,
    export_rerun,
    tail_rows,
    write_recording,
)
from pointtraj.labelfile import TrajectoryLabels, save_labels
from pointtraj.render.palette import UNLABELLED_COLOR, class_palette, label_colors
from pointtraj.results import load
from pointtraj.trajectories import Trajectories

pytest.importorskip("rerun", reason="rerun-sdk is not installed (pip install 'pointtraj[export]')")


# -- reading a recording back -----------------------------------------------------------------
def _cells(column, row: int) -> np.ndarray:
    """One row's list cell of an Arrow column as a numpy array (fixed-size lists as rows)."""
    import pyarrow as pa

    values = column[row].values
    if pa.types.is_fixed_size_list(values.type):
        width = values.type.list_size
        return np.asarray(values.flatten().to_numpy(zero_copy_only=False)).reshape(-1, width)
    return np.asarray(values.to_numpy(zero_copy_only=False))


def read_recording(path: Path) -> tuple[dict, dict]:
    """The recording's temporal rows by entity and frame, and its static rows by entity.

    Returns
    -------
    frames : dict of entity -> dict of frame -> dict of component -> ndarray (or list of
        ndarrays for line strips)
    static : dict of entity -> dict of component -> its (one) value, as Python objects
    """
    from rerun.chunk import RrdReader

    frames: dict = defaultdict(dict)
    static: dict = defaultdict(dict)
    recordings = RrdReader(path).recordings()
    assert len(recordings) == 1
    for chunk in RrdReader(path).stream():
        batch = chunk.to_record_batch()
        names = [n for n in batch.schema.names if n not in ("rerun.controls.RowId", "time")]
        if chunk.is_static:
            for n in names:
                static[chunk.entity_path][n] = batch.column(n)[0].as_py()[0]
            continue
        assert "frame" in chunk.timeline_names and "time" in chunk.timeline_names
        frame_col = batch.column("frame").to_numpy()
        for r in range(batch.num_rows):
            row = frames[chunk.entity_path].setdefault(int(frame_col[r]), {})
            for n in names:
                if n == "frame":
                    continue
                if n == "LineStrips3D:strips":
                    row[n] = [
                        np.asarray(s.values.flatten().to_numpy()).reshape(-1, 3)
                        for s in batch.column(n)[r].values
                    ]
                elif n.startswith("EncodedImage"):
                    row[n] = batch.column(n)[r]
                else:
                    row[n] = _cells(batch.column(n), r)
    return frames, static


def _rgb(packed: np.ndarray) -> np.ndarray:
    """(N,) uint32 RGBA colours (Rerun's packing) as (N, 3) uint8 RGB."""
    p = np.asarray(packed, np.uint32)
    return np.stack([(p >> 24) & 255, (p >> 16) & 255, (p >> 8) & 255], axis=1).astype(np.uint8)


# -- inputs -----------------------------------------------------------------------------------
def _store(M: int, T: int, rng: np.random.Generator) -> Trajectories:
    """M random-walk trajectories over T frames, each alive on a random contiguous run."""
    xyz = np.cumsum(rng.normal(scale=0.01, size=(M, T, 3)), axis=1) + rng.normal(size=(M, 1, 3))
    first = rng.integers(0, max(1, T // 2), M)
    last = first + rng.integers(1, T, M)
    f = np.arange(T)
    xyz[(f[None] < first[:, None]) | (f[None] > last[:, None])] = np.nan
    return Trajectories.from_dense(xyz.astype(np.float32), camera_names=["a", "b"], fps=25.0)


@pytest.fixture
def work_without_capture(tmp_path) -> Path:
    """A work folder of a store, labels with ``instance``, and no capture."""
    rng = np.random.default_rng(7)
    work = tmp_path / "work"
    traj = _store(60, 8, rng)
    traj.save(work / "trajectories.npz")
    names = ("head", "torso", "left_hand")
    labels = rng.integers(-1, 3, traj.num_trajectories)
    save_npz_atomic(
        work / "labels.npz",
        format_version=np.int64(1),
        labels=labels,
        class_names=np.array(names),
        instance=rng.integers(-1, 3, traj.num_trajectories),
    )
    return work


# -- tests ------------------------------------------------------------------------------------
def test_tail_rows_match_dense_positions():
    rng = np.random.default_rng(0)
    traj = _store(40, 12, rng)
    dense = traj.dense_positions()  # (M, T, 3)
    for t in (0, 3, 11):
        rows = traj.frame_rows(t)
        track = traj.row_track[rows]
        idx, offsets, strip_track = tail_rows(traj, rows, track, t, 4)
        assert len(offsets) == len(strip_track) + 1
        for s, m in enumerate(strip_track):
            f0 = max(int(traj.first_frame[m]), t - 4)
            want = dense[m, f0 : t + 1]
            np.testing.assert_array_equal(traj.xyz[idx[offsets[s] : offsets[s + 1]]], want)
        # Every live trajectory with a frame before t has a strip; the others have none.
        assert set(strip_track) == set(track[traj.first_frame[track] < t])


def test_tiny_work_folder_reads_back(tiny_reference, tmp_path):
    """Points, colours, class ids, confidences, tails, cameras and images, frame by frame."""
    work = tiny_reference / "work"
    out = tmp_path / "tiny.rrd"
    cfg = RerunConfig(tail=2, image_scale=0.5)
    result = export_rerun(work, out, cfg)
    res = load(work)
    traj = res.trajectories
    frames, static = read_recording(out)

    assert result.frames == traj.occupied_frames and len(result.frames) == 3
    assert result.color_source == "labels.npz"
    instance = res.labels.instance
    people = 0 if instance is None else int(instance.max(initial=-1)) + 1
    assert result.people == people
    assert ("/world/people" in frames) == (instance is not None)
    labels = res.labels.labels
    from pointtraj.labelset import LabelSet

    palette = class_palette(res.class_names, LabelSet.load(tiny_reference / "cap/labels.toml"))
    colors = label_colors(labels, palette)
    conf = res.semantic_map.L3D[res.labels.pooling]
    points = frames["/world/points"]
    assert sorted(points) == list(result.frames)
    total = 0
    for t in result.frames:
        rows = traj.frame_rows(t)
        track = traj.row_track[rows]
        got = points[t]
        assert len(got["Points3D:positions"]) == len(rows)
        np.testing.assert_array_equal(got["Points3D:positions"], traj.xyz[rows])
        np.testing.assert_array_equal(got["track_id"], track)
        np.testing.assert_array_equal(got["label"], labels[track])
        np.testing.assert_array_equal(_rgb(got["Points3D:colors"]), colors[track])
        want_ids = np.where(labels[track] >= 0, labels[track], NO_CLASS)
        np.testing.assert_array_equal(got["Points3D:class_ids"], want_ids)
        for k, name in enumerate(res.class_names):
            np.testing.assert_array_equal(got[f"Confidence:{name}"], conf[track, k])
        strips = frames["/world/tracks"][t]["LineStrips3D:strips"]
        idx, offsets, strip_track = tail_rows(traj, rows, track, t, 2)
        assert len(strips) == len(strip_track)
        assert (len(strips) == 0) == (t == 0)
        for s, strip in enumerate(strips):
            np.testing.assert_array_equal(strip, traj.xyz[idx[offsets[s] : offsets[s + 1]]])
        total += len(rows)
    assert result.points == total

    # The class names and colours travel in the annotation context.
    context = static["/world/points"]["AnnotationContext:context"]
    by_id = {c["class_id"]: c["class_description"]["info"] for c in context}
    assert by_id[NO_CLASS]["label"] == "unlabelled"
    for k, name in enumerate(res.class_names):
        assert by_id[k]["label"] == name
        np.testing.assert_array_equal(_rgb([by_id[k]["color"]])[0], palette[k])

    # Cameras: pose, scaled pinhole, and one JPEG per frame.
    rig = _rig(tiny_reference)
    assert result.cameras == len(rig) and result.images == 3 * len(rig)
    for cam in rig:
        pose = static[f"/world/cameras/{cam.name}"]
        np.testing.assert_allclose(pose["Transform3D:translation"], cam.C, atol=1e-6)
        # Rerun keeps 3x3 matrices column-major; the camera's axes in the world are R^T.
        np.testing.assert_allclose(
            np.reshape(pose["Transform3D:mat3x3"], (3, 3)).T, cam.R.T, atol=1e-6
        )
        pin = static[f"/world/cameras/{cam.name}/image"]
        half = cam.resized(0.5)
        K, size = half.K, half.size
        assert tuple(pin["Pinhole:resolution"]) == size
        np.testing.assert_allclose(
            np.reshape(pin["Pinhole:image_from_camera"], (3, 3)).T, K, atol=1e-4
        )
        images = frames[f"/world/cameras/{cam.name}/image"]
        assert sorted(images) == list(result.frames)
        for row in images.values():
            assert row["EncodedImage:media_type"].as_py() == ["image/jpeg"]


def _rig(root: Path):
    from pointtraj.session import Capture

    with Capture.open(root / "cap") as cap:
        return cap.rig


def test_instances_and_missing_capture(work_without_capture, tmp_path):
    work = work_without_capture
    out = tmp_path / "people.rrd"
    result = export_rerun(work, out, RerunConfig(tail=0))
    traj = Trajectories.load(work / "trajectories.npz")
    z = np.load(work / "labels.npz")
    instance, labels = z["instance"], z["labels"]
    frames, static = read_recording(out)
    assert result.people == int(instance.max()) + 1 and result.cameras == 0
    assert "/world/tracks" not in frames
    assert not any(e.startswith("/world/cameras") for e in frames)
    person = cycle_colors(PERSON_COLORS)
    for t in result.frames:
        rows = traj.frame_rows(t)
        track = traj.row_track[rows]
        got = frames["/world/people"][t]
        np.testing.assert_array_equal(got["Points3D:positions"], traj.xyz[rows])
        inst = instance[track]
        np.testing.assert_array_equal(got["instance"], inst)
        np.testing.assert_array_equal(
            got["Points3D:class_ids"], np.where(inst >= 0, inst, NO_CLASS)
        )
        want = np.where((inst >= 0)[:, None], person[np.maximum(inst, 0)], UNLABELLED_COLOR)
        np.testing.assert_array_equal(_rgb(got["Points3D:colors"]), want)
        # The label colours of the same points (default palette: no labels.toml).
        np.testing.assert_array_equal(
            _rgb(frames["/world/points"][t]["Points3D:colors"]),
            label_colors(labels, class_palette(("head", "torso", "left_hand")))[track],
        )
    context = static["/world/people"]["AnnotationContext:context"]
    assert {c["class_id"] for c in context} == {*range(result.people), NO_CLASS}


def test_unlabelled_work_folder_colours_by_trajectory(tmp_path):
    work = tmp_path / "work"
    traj = _store(30, 5, np.random.default_rng(3))
    traj.save(work / "trajectories.npz")
    result = export_rerun(work, config=RerunConfig(tail=3))
    assert result.path == work / "export" / "recording.rrd"
    assert result.color_source == "trajectory"
    frames, static = read_recording(result.path)
    t = result.frames[-1]
    track = traj.row_track[traj.frame_rows(t)]
    got = frames["/world/points"][t]
    assert "Points3D:class_ids" not in got and "label" not in got
    np.testing.assert_array_equal(
        _rgb(got["Points3D:colors"]), cycle_colors(PERSON_COLORS)[track % PERSON_COLORS]
    )
    assert "/world/points" not in static  # no annotation context without classes


def test_errors_name_the_file(tmp_path, work_without_capture, monkeypatch):
    with pytest.raises(FileFormatError, match="trajectories.npz: no such file"):
        export_rerun(tmp_path, tmp_path / "x.rrd")
    with pytest.raises(FileFormatError, match="work folder does not exist"):
        export_rerun(tmp_path / "nowhere", tmp_path / "x.rrd")
    work = work_without_capture
    z = dict(np.load(work / "labels.npz"))
    z["instance"] = z["instance"][:-1]
    save_npz_atomic(work / "labels.npz", **z)
    with pytest.raises(FileFormatError, match=r"labels.npz: instance: expected shape \(60,\)"):
        export_rerun(work, tmp_path / "x.rrd")
    assert not (tmp_path / "x.rrd").exists()
    with pytest.raises(ValidationError, match="image_scale must be in"):
        RerunConfig(image_scale=0.0)
    with pytest.raises(ValidationError, match="tail must be 0 or more"):
        RerunConfig(tail=-1)
    # Without rerun-sdk: one line naming the extra.
    monkeypatch.setitem(sys.modules, "rerun", None)
    with pytest.raises(ValidationError, match=r"pip install 'pointtraj\[export\]'"):
        export_rerun(work, tmp_path / "x.rrd")


def test_labels_of_another_store_are_refused(tmp_path):
    work = tmp_path / "work"
    traj = _store(10, 4, np.random.default_rng(1))
    traj.save(work / "trajectories.npz")
    save_labels(
        TrajectoryLabels(np.zeros(9, np.int64), np.zeros(9), np.zeros(9), ("a",)),
        work / "labels.npz",
    )
    with pytest.raises(FileFormatError, match="labels.npz: has 9 trajectories, not 10"):
        export_rerun(work, tmp_path / "x.rrd")


def _peak_bytes(T: int) -> int:
    """Python-side peak allocation of exporting N = 3000 points per frame over T frames, beyond
    the store and its frame-major index (built before)."""
    rng = np.random.default_rng(5)
    M, K = 3000, 6
    xyz = np.broadcast_to(rng.normal(size=(M, 1, 3)), (M, T, 3)).astype(np.float32)
    traj = Trajectories.from_dense(xyz, camera_names=["a"])
    traj.frame_rows(0)  # the index, O(P), is the store's
    labels = rng.integers(-1, K, M)
    conf = rng.random((M, K)).astype(np.float32)
    names = tuple(f"c{k}" for k in range(K))
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        tracemalloc.start()
        try:
            write_recording(
                Path(d) / "r.rrd",
                traj,
                labels=labels,
                class_names=names,
                confidences=conf,
                instance=labels,
                config=RerunConfig(tail=10),
            )
            return tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()


def test_export_streams_memory_does_not_grow_with_frames():
    """The peak over 40 frames is that over 10 (one frame's arrays, not all of them): within
    25 % plus 1 MiB (about 1.3 MiB each measured), where holding 40 frames' arrays would take
    about 20 MiB. A first export is left out: it allocates rerun's and Arrow's one-time
    tables."""
    _peak_bytes(2)
    p10, p40 = _peak_bytes(10), _peak_bytes(40)
    assert p40 < 1.25 * p10 + 2**20, (p10, p40)


def test_cli_writes_recording_without_images(tiny_reference, tmp_path):
    out = tmp_path / "cli.rrd"
    work = tiny_reference / "work"
    res = CliRunner().invoke(
        main,
        [
            "export",
            "rerun",
            str(work),
            "-o",
            str(out),
            "--no-images",
            "--tail",
            "0",
            "--no-confidences",
            "--frames",
            "1:",
        ],
    )
    assert res.exit_code == 0, res.output
    assert "2 frames (1:3)" in res.output and "0 images" in res.output
    frames, static = read_recording(out)
    assert sorted(frames) == ["/world/people", "/world/points"]  # no tracks with --tail 0
    assert sorted(frames["/world/points"]) == [1, 2]
    assert not any(k.startswith("Confidence:") for k in frames["/world/points"][1])
    assert "/world/cameras/cam00" in static  # poses and pinholes are logged without images
    bad = CliRunner().invoke(main, ["export", "rerun", str(work), "--image-scale", "2"])
    assert bad.exit_code == 2 and "image_scale must be in (0, 1]" in bad.output
