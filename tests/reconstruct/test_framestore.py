"""The reconstruction's per-frame files: records, the live state, resuming and the streamed store."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from helpers.rigs import plane_rig
from helpers.scenes import plane_frames

from pointtraj.errors import FileFormatError, ValidationError
from pointtraj.reconstruct.config import ReconstructConfig
from pointtraj.reconstruct.framestore import FrameStore
from pointtraj.reconstruct.matching import MatchingConfig
from pointtraj.reconstruct.stage import assemble_trajectories, reconstruct_capture
from pointtraj.reconstruct.track import FrameRecord, TrackState
from pointtraj.session import Capture
from pointtraj.trajectories import Trajectories

T = 5
CONFIG = ReconstructConfig(matching=MatchingConfig(num_features=800))


class Interrupted(Exception):
    """Raised by a progress callback to stop a run after some frames, as a crash would."""


@pytest.fixture(scope="module")
def capture(tmp_path_factory) -> Path:
    """A capture of a moving textured plane, 3 cameras, 5 frames."""
    root = tmp_path_factory.mktemp("framestore")
    rig = plane_rig(angles=(-15.0, 0.0, 15.0), size=(400, 300), focal=340.0, names="cam{i}")
    cap = Capture.create(root / "capture", rig, fps=25.0, image_format="png")
    for t, images in enumerate(plane_frames(rig, T, seed=5, velocity=(0.01, 0.0, 0.02))):
        for cam, image in zip(rig, images):
            cap.write_frame(cam.name, t, image)
    return root / "capture"


@pytest.fixture(scope="module")
def reference(capture, tmp_path_factory) -> Path:
    """An uninterrupted run's work folder."""
    work = tmp_path_factory.mktemp("reference") / "work"
    reconstruct_capture(Capture.open(capture), work, config=CONFIG)
    return work


def _stop_after(k: int, work: Path | None = None, keep_live_of: int | None = None):
    """An on_frame that raises once frame k is complete (optionally copying frame
    ``keep_live_of``'s live state aside)."""
    seen = []

    def on_frame(rec: FrameRecord) -> None:
        seen.append(rec.frame)
        if work is not None and rec.frame == keep_live_of:
            shutil.copy(work / "state" / "live.npz", work / "live.keep")
        if rec.frame == k:
            raise Interrupted

    return on_frame, seen


def _assert_same_outputs(work: Path, reference: Path) -> None:
    a = np.load(work / "trajectories.npz")
    b = np.load(reference / "trajectories.npz")
    assert sorted(a.files) == sorted(b.files)
    for key in a.files:
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)
    for ply in sorted((reference / "clouds").glob("*.ply")):
        assert (work / "clouds" / ply.name).read_bytes() == ply.read_bytes(), ply.name


def test_the_state_folder_holds_records_and_one_live_state(reference):
    names = sorted(p.name for p in (reference / "state").iterdir())
    assert names == [f"{t:06d}.npz" for t in range(T)] + ["live.npz"]
    store = FrameStore(reference, 3)
    assert all(store.record_version(t) == 2 for t in range(T))
    assert store.read_live().frame == T - 1
    # the records hold the store: assembling them again gives trajectories.npz (before
    # stitching, which this plane does not need)
    traj = Trajectories.load(reference / "trajectories.npz")
    again = store.assemble(range(T), traj.camera_names, traj.fps, traj.num_frames)
    np.testing.assert_array_equal(again.offsets, traj.offsets)
    np.testing.assert_array_equal(again.xyz, traj.xyz)


@pytest.mark.parametrize("k", [0, 2, 3])
def test_an_interrupted_run_resumes_byte_identical(capture, reference, tmp_path, k):
    work = tmp_path / "work"
    on_frame, _ = _stop_after(k)
    with pytest.raises(Interrupted):
        reconstruct_capture(Capture.open(capture), work, config=CONFIG, on_frame=on_frame)
    assert FrameStore(work, 3).read_live().frame == k
    assert not (work / "trajectories.npz").exists()
    on_frame, seen = _stop_after(-1)
    reconstruct_capture(Capture.open(capture), work, config=CONFIG, on_frame=on_frame)
    assert seen == list(range(T))  # resumed frames are reported too
    _assert_same_outputs(work, reference)


def test_a_record_written_after_the_last_live_state_is_recomputed(capture, reference, tmp_path):
    """A crash between frame 2's record and its live state: frame 1's live state resumes."""
    work = tmp_path / "work"
    on_frame, _ = _stop_after(2, work, keep_live_of=1)
    with pytest.raises(Interrupted):
        reconstruct_capture(Capture.open(capture), work, config=CONFIG, on_frame=on_frame)
    (work / "live.keep").replace(work / "state" / "live.npz")
    store = FrameStore(work, 3)
    done, state = store.resume(range(T))
    assert done == 2 and state.frame == 1
    reconstruct_capture(Capture.open(capture), work, config=CONFIG)
    _assert_same_outputs(work, reference)


def test_without_a_usable_live_state_the_run_starts_afresh(capture, reference, tmp_path, caplog):
    work = tmp_path / "work"
    on_frame, _ = _stop_after(2)
    with pytest.raises(Interrupted):
        reconstruct_capture(Capture.open(capture), work, config=CONFIG, on_frame=on_frame)
    (work / "state" / "000001.npz").unlink()  # the live state (frame 2) lies past the gap
    assert FrameStore(work, 3).resume(range(T)) == (0, None)
    assert "reconstructing afresh" in caplog.text
    reconstruct_capture(Capture.open(capture), work, config=CONFIG)
    _assert_same_outputs(work, reference)


def _write_v1(store: FrameStore, record: FrameRecord, state: TrackState) -> None:
    """A state file as versions before the split wrote it (format 1: record and live state)."""
    np.savez(
        store.record_path(record.frame),
        format_version=np.int64(1),
        frame=np.int64(record.frame),
        rec_ids=record.ids,
        rec_xyz=record.xyz,
        rec_visibility=record.visibility,
        rec_error=record.error,
        rec_color=record.color,
        rec_num_new=np.int64(record.num_new),
        live_ids=state.ids,
        live_xyz=state.xyz,
        live_visibility=state.visibility,
        live_pixels=state.pixels,
        live_lone=state.lone,
        next_id=np.int64(state.next_id),
    )


def test_a_work_folder_of_the_old_format_resumes(capture, reference, tmp_path):
    """Format 1 state files (one per frame, with the live state) are read and resumed."""
    work = tmp_path / "work"
    on_frame, _ = _stop_after(2)
    with pytest.raises(Interrupted):
        reconstruct_capture(Capture.open(capture), work, config=CONFIG, on_frame=on_frame)
    store = FrameStore(work, 3)
    live = store.read_live()
    for t in range(3):  # the old layout: the live state in the last file (and, here, in all)
        _write_v1(store, store.read_record(t), live)
    store.live_path.unlink()
    assert [store.record_version(t) for t in range(3)] == [1, 1, 1]
    done, state = store.resume(range(T))
    assert done == 3 and state.frame == 2
    np.testing.assert_array_equal(state.pixels, live.pixels)
    reconstruct_capture(Capture.open(capture), work, config=CONFIG)
    _assert_same_outputs(work, reference)
    # a format 1 file of an older version still, without live_lone: all 0
    d = dict(np.load(store.record_path(1)))
    del d["live_lone"]
    np.savez(store.record_path(1), **d)
    assert store.read_v1_live(1).lone.tolist() == [0] * len(d["live_ids"])


def _records(C: int = 2) -> list[FrameRecord]:
    rng = np.random.default_rng(0)

    def rec(t: int, ids: list[int]) -> FrameRecord:
        n = len(ids)
        return FrameRecord(
            t,
            np.array(ids, np.int64),
            rng.normal(size=(n, 3)).astype(np.float32),
            rng.integers(0, 256, (n, C)).astype(np.uint8),
            rng.random(n).astype(np.float32),
            rng.integers(0, 256, (n, 3)).astype(np.uint8),
            n,
        )

    return [rec(3, [0, 1]), rec(4, [1, 2, 0]), rec(5, []), rec(6, [4, 3]), rec(7, [3])]


def test_the_streamed_store_equals_the_one_assembled_in_memory(tmp_path):
    records = _records()
    store = FrameStore(tmp_path, 2)
    for r in records:
        store.write_record(r)
    streamed = store.assemble(range(3, 8), ["a", "b"], 25.0, 10)
    memory = assemble_trajectories(records, ["a", "b"], 25.0, 10)
    for key in ("first_frame", "offsets", "xyz", "visibility", "reprojection_error", "color"):
        got, want = getattr(streamed, key), getattr(memory, key)
        assert got.dtype == want.dtype
        np.testing.assert_array_equal(got, want, err_msg=key)
    assert streamed.num_frames == 10 and streamed.camera_names == ["a", "b"]
    empty = FrameStore(tmp_path / "none", 2)
    empty.write_record(records[2])
    assert empty.assemble(range(5, 6), ["a", "b"], 25.0, 10).num_trajectories == 0


def test_the_streamed_store_refuses_broken_trajectories(tmp_path):
    r = _records()
    gap = FrameStore(tmp_path / "gap", 2)  # trajectory 0 at frames 3 and 5, not 4
    gap.write_record(r[0])
    gap.write_record(
        FrameRecord(
            4, r[3].ids[:0], r[3].xyz[:0], r[3].visibility[:0], r[3].error[:0], r[3].color[:0]
        )
    )
    gap.write_record(
        FrameRecord(5, np.array([0]), r[4].xyz, r[4].visibility, r[4].error, r[4].color)
    )
    with pytest.raises(ValidationError, match="skips a frame"):
        gap.assemble(range(3, 6), ["a", "b"], 25.0, 10)
    holes = FrameStore(tmp_path / "holes", 2)
    holes.write_record(
        FrameRecord(0, np.array([0, 2]), r[0].xyz, r[0].visibility, r[0].error, r[0].color)
    )
    with pytest.raises(ValidationError, match="0 .. M-1"):
        holes.assemble(range(1), ["a", "b"], 25.0, 10)


def test_a_damaged_record_is_named(tmp_path):
    records = _records()
    store = FrameStore(tmp_path, 2)
    for r in records:
        store.write_record(r)
    path = store.record_path(4)
    data = bytearray(path.read_bytes())
    data[len(data) // 2 : len(data) // 2 + 16] = b"\xff" * 16  # inside a deflated array
    path.write_bytes(bytes(data))
    with pytest.raises(FileFormatError, match=r"000004\.npz.*not a readable \.npz"):
        store.assemble(range(3, 8), ["a", "b"], 25.0, 10)
    path.write_bytes(bytes(data[:100]))  # truncated
    with pytest.raises(FileFormatError, match=r"000004\.npz"):
        store.read_record(4)
    path.unlink()
    with pytest.raises(FileFormatError, match=r"000004\.npz: no such file"):
        store.assemble(range(3, 8), ["a", "b"], 25.0, 10)
    other = FrameStore(tmp_path, 3)  # records of 2 cameras read for 3
    with pytest.raises(FileFormatError, match=r"000003\.npz.*for 3 cameras"):
        other.read_record(3)
    with pytest.raises(FileFormatError, match=r"000006\.npz: holds frame 5, expected 6"):
        shutil.copy(store.record_path(5), store.record_path(6))
        store.read_record(6)


def test_the_live_state_round_trips_bit_exact(tmp_path):
    rng = np.random.default_rng(1)
    N, C = 50, 4
    vis = rng.random((N, C)).astype(np.float32)
    vis[rng.random((N, C)) < 0.5] = 0.0
    pix = rng.normal(300, 100, (C, N, 2)).astype(np.float32)
    pix[vis.T == 0] = np.nan
    pix[0, 3, 1] = np.nan  # half a pixel: kept as it is
    misses = rng.integers(0, 5, (N, C)).astype(np.uint8)  # view discovery's back-off
    state = TrackState(
        7, rng.permutation(N), rng.normal(size=(N, 3)), vis, pix, 99, rng.integers(0, 3, N), misses
    )
    store = FrameStore(tmp_path, C)
    store.write_live(state)
    back = store.read_live()
    assert back.frame == 7 and back.next_id == 99
    for key in ("ids", "xyz", "visibility", "pixels", "lone", "misses"):
        a, b = getattr(back, key), getattr(state, key)
        assert a.dtype == b.dtype and a.shape == b.shape, key
        assert a.tobytes() == b.tobytes() or np.array_equal(a, b, equal_nan=True), key
    assert back.pixels[0, 3, 0] == pix[0, 3, 0] and np.isnan(back.pixels[0, 3, 1])
    with pytest.raises(FileFormatError, match=r"live\.npz: tracker state is for 4 cameras, not 5"):
        FrameStore(tmp_path, 5).read_live()
    d = dict(np.load(store.live_path))
    d["lone"] = np.zeros(N + 1, np.int64)
    np.savez(store.live_path, **d)
    with pytest.raises(FileFormatError, match="live_lone"):
        store.read_live()
    d["lone"] = state.lone
    del d["misses_index"], d["misses_values"]  # a state from before the back-off
    np.savez(store.live_path, **d)
    assert not store.read_live().misses.any()
    assert FrameStore(tmp_path / "none", C).read_live() is None


def test_the_cloud_visibility_option_changes_only_the_clouds(capture, reference, tmp_path):
    import dataclasses

    from pointtraj.trajectories import OBSERVED_MIN, load_cloud

    work = tmp_path / "work"
    cfg = dataclasses.replace(CONFIG, cloud_visibility="sparse")
    reconstruct_capture(Capture.open(capture), work, config=cfg)
    a, b = np.load(work / "trajectories.npz"), np.load(reference / "trajectories.npz")
    for key in b.files:
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)
    for t in range(T):
        sparse = load_cloud(work / "clouds" / f"{t:06d}.ply")
        full = load_cloud(reference / "clouds" / f"{t:06d}.ply")
        np.testing.assert_array_equal(sparse["track_id"], full["track_id"])
        observed = full["visibility"] >= (OBSERVED_MIN - 0.5) / 255
        np.testing.assert_array_equal(
            sparse["visibility"], np.where(observed, full["visibility"], 0)
        )
        assert (work / "clouds" / f"{t:06d}.ply").stat().st_size < (
            reference / "clouds" / f"{t:06d}.ply"
        ).stat().st_size


def test_a_work_folder_of_an_older_version_resumes_through_the_stage(capture, reference, tmp_path):
    """A work.toml without cloud_visibility and format 1 state files: the run resumes."""
    import tomllib

    import tomli_w

    from pointtraj.stages import reconstruct_work

    work = tmp_path / "work"

    def crash(label: str, done: int, total: int) -> None:
        if done == 2:
            raise Interrupted

    with pytest.raises(Interrupted):
        reconstruct_work(work, capture, CONFIG, progress=crash)
    doc = tomllib.loads((work / "work.toml").read_text())
    del doc["reconstruct"]["cloud_visibility"]
    (work / "work.toml").write_text(tomli_w.dumps(doc))
    store = FrameStore(work, 3)
    live = store.read_live()
    _write_v1(store, store.read_record(0), live)  # frame 0's live state is not used
    _write_v1(store, store.read_record(1), live)
    store.live_path.unlink()
    reconstruct_work(work, capture, CONFIG)
    _assert_same_outputs(work, reference)
    assert store.record_version(1) == 1 and store.record_version(2) == 2


def test_an_empty_live_state_round_trips(tmp_path):
    """A frame with no live point (black images) resumes too."""
    store = FrameStore(tmp_path, 4)
    store.write_live(TrackState.empty(4, frame=3))
    back = store.read_live()
    assert back.frame == 3 and len(back) == 0
    assert back.visibility.shape == (0, 4) and back.pixels.shape == (4, 0, 2)
