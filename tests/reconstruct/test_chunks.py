"""Tracking in temporal chunks: the plan, joins across boundaries, and whole runs on an executor."""

from __future__ import annotations

import dataclasses
import shutil
from pathlib import Path

import numpy as np
import pytest
from helpers.rigs import plane_rig

from pointtraj.errors import ValidationError
from pointtraj.reconstruct.chunks import (
    Bridge,
    Chunk,
    join_boundary,
    join_tail,
    merge_chunks,
    plan_chunks,
)
from pointtraj.reconstruct.config import ReconstructConfig
from pointtraj.trajectories import Trajectories

# -- the plan ------------------------------------------------------------------------------------


def test_plan_chunks_cuts_at_fixed_boundaries_with_a_warm_up():
    assert plan_chunks(range(0, 30), 100, 5) == [Chunk(0, 0, 30)]
    assert plan_chunks(range(3, 13), 10, 5) == [Chunk(3, 3, 13)]  # exactly one chunk
    assert plan_chunks(range(5, 30), 0, 0) == [Chunk(5, 5, 30)]
    assert plan_chunks(range(2, 27), 10, 3) == [
        Chunk(2, 2, 12),
        Chunk(9, 12, 22),
        Chunk(19, 22, 27),
    ]
    assert plan_chunks(range(0, 6), 3, 1)[1].name == "000002-000006"
    with pytest.raises(ValidationError):
        plan_chunks(range(0), 10, 2)


def test_config_validates_the_chunk_keys():
    assert ReconstructConfig(chunk_frames=0, chunk_overlap=0).chunk_frames == 0
    for bad in ({"chunk_frames": -1}, {"chunk_frames": 4, "chunk_overlap": 4}, {"chunk_join_m": 0}):
        with pytest.raises(ValidationError, match="chunk_"):
            ReconstructConfig(**bad)


# -- joins ---------------------------------------------------------------------------------------


def _store(xyz: np.ndarray, first: np.ndarray, vis: np.ndarray, T: int) -> Trajectories:
    """A store of trajectories with positions ``xyz[m]`` (L_m, 3) from ``first[m]``."""
    lengths = np.array([len(x) for x in xyz])
    P = int(lengths.sum())
    return Trajectories(
        first_frame=np.asarray(first, np.int64),
        offsets=np.concatenate([[0], np.cumsum(lengths)]),
        xyz=np.concatenate(xyz).astype(np.float32),
        visibility=np.repeat(vis, lengths, axis=0).astype(np.uint8),
        reprojection_error=np.full(P, 0.2, np.float32),
        color=np.full((P, 3), 128, np.uint8),
        camera_names=["c0", "c1", "c2"],
        fps=10.0,
        num_frames=T,
    )


def _path(p0: np.ndarray, frames: range) -> np.ndarray:
    """A point moving 1 cm a frame along x, at the given frames."""
    return np.array([p0 + [0.01 * t, 0.0, 0.0] for t in frames])


def test_join_boundary_joins_the_same_points_and_nothing_else():
    rig = plane_rig(3)
    T, boundary, overlap = 12, 6, 3
    pts = np.array([[-0.2, -0.1, 0.0], [0.0, 0.0, 0.0], [0.1, 0.05, 0.0], [0.2, -0.05, 0.0]])
    seen = np.array([[255, 255, 0]])
    # before: four points alive at frame 5 (point 3 only until frame 4)
    before = _store(
        [_path(pts[0], range(0, 6)), _path(pts[1], range(2, 6)), _path(pts[2], range(0, 6)),
         _path(pts[3], range(0, 5))],
        [0, 2, 0, 0], np.repeat(seen, 4, axis=0), T,
    )  # fmt: skip
    # after (warm-up frames 3-5): point 0 within 2 mm; point 1 drifts 3 cm away at frame 3;
    # point 2 seen by another camera only (no shared view); point 3 starts afresh at frame 6
    drift = _path(pts[1], range(3, 12))
    drift[0] += [0.03, 0.0, 0.0]
    after = _store(
        [_path(pts[0] + [0.002, 0, 0], range(4, 12)), drift, _path(pts[2], range(3, 12)),
         _path(pts[3], range(6, 12))],
        [4, 3, 3, 6], np.array([[255, 255, 0], [255, 255, 0], [0, 0, 255], [255, 255, 0]]), T,
    )  # fmt: skip
    pairs, count = join_boundary(before, after, boundary, overlap, rig, 0.01, 4.0, 0.05)
    assert pairs.tolist() == [[0, 0]]
    assert (count.ending, count.candidates, count.joined) == (3, 3, 1)
    # with a looser 3D tolerance point 1 joins too; point 2 never (no camera sees both)
    pairs, _ = join_boundary(before, after, boundary, overlap, rig, 0.05, 400.0, 0.05)
    assert pairs.tolist() == [[0, 0], [1, 1]]
    # no overlap: nothing to compare
    pairs, _ = join_boundary(before, after, boundary, 0, rig, 0.01, 4.0, 0.05)
    assert len(pairs) == 0


def test_join_boundary_takes_mutual_best_matches():
    rig = plane_rig(3)
    seen = np.array([[255, 255, 0]] * 2)
    p = np.array([[0.0, 0.0, 0.0], [0.004, 0.0, 0.0]])
    before = _store([_path(p[0], range(0, 4))], [0], seen[:1], 8)
    after = _store([_path(p[1], range(2, 8)), _path(p[0] + [0.001, 0, 0], range(2, 8))], [2, 2],
                   seen, 8)  # fmt: skip
    pairs, count = join_boundary(before, after, 4, 2, rig, 0.01, 40.0, 0.05)
    assert pairs.tolist() == [[0, 1]] and count.candidates == 2


def test_merge_chunks_takes_each_frame_from_one_chunk_and_continues_joined_points():
    rig = plane_rig(3)
    T = 12
    pts = np.array([[-0.1, 0.0, 0.0], [0.1, 0.05, 0.0]])
    seen = np.array([[255, 255, 0]] * 2)
    chunks = plan_chunks(range(T), 6, 2)
    a = _store([_path(pts[0], range(0, 6)), _path(pts[1], range(1, 4))], [0, 1], seen, T)
    b = _store([_path(pts[1] + [0.3, 0, 0], range(4, 12)), _path(pts[0], range(4, 10))], [4, 4],
               seen, T)  # fmt: skip
    merged, counts = merge_chunks([a, b], chunks, rig, 0.01, 4.0, 0.05)
    assert [c.joined for c in counts] == [1]
    assert merged.num_trajectories == 3
    assert merged.first_frame.tolist() == [0, 1, 6]
    assert merged.lengths.tolist() == [10, 3, 6]  # point 0 from frame 0 to 9 in one trajectory
    np.testing.assert_allclose(merged.track(0), _path(pts[0], range(0, 10)), atol=1e-6)
    for t in range(T):  # no point twice: frame t's rows all come from one chunk
        owner = a if t < 6 else b
        assert merged.frame_rows(t).size == owner.frame_rows(t).size


def test_merge_chunks_continues_bridged_trajectories_and_drops_what_they_replace():
    rig = plane_rig(3)
    T = 12
    pts = np.array([[-0.1, 0.0, 0.0], [0.1, 0.05, 0.0]])
    seen = np.array([[255, 255, 0]] * 2)
    chunks = plan_chunks(range(T), 6, 2)
    a = _store([_path(pts[0], range(0, 6)), _path(pts[1], range(1, 6))], [0, 1], seen, T)
    # the next chunk sees point 1 3 cm off until frame 7 (no join over the overlap), then on it
    late = _path(pts[1], range(4, 12))
    late[:4] += [0.03, 0.0, 0.0]
    b = _store([late], [4], seen[:1], T)
    carried = _path(pts[1], range(6, 8))
    bridge = Bridge(
        ids=np.array([1, 1]),
        frame=np.array([6, 7]),
        xyz=carried.astype(np.float32),
        visibility=np.array([[255, 255, 0]] * 2, np.uint8),
        error=np.full(2, 0.2, np.float32),
        color=np.full((2, 3), 128, np.uint8),
        joins=np.array([[1, 0, 8]]),
    )
    merged, counts = merge_chunks(
        [a, b], chunks, rig, 0.01, 4.0, 0.05, tails=[bridge], resolve=False
    )
    assert (counts[0].joined, counts[0].carried, counts[0].joined_later) == (0, 1, 1)
    assert merged.num_trajectories == 2
    assert merged.first_frame.tolist() == [0, 1] and merged.lengths.tolist() == [6, 11]
    np.testing.assert_allclose(merged.track(1), _path(pts[1], range(1, 12)), atol=1e-6)
    for t in range(6, T):  # point 1 once per frame: the bridge's rows replace b's first rows
        assert merged.frame_rows(t).size == 1
    with pytest.raises(ValidationError, match="twice"):
        twice = dataclasses.replace(bridge, joins=np.array([[1, 0, 8], [0, 0, 9]]))
        merge_chunks([a, b], chunks, rig, 0.01, 4.0, 0.05, tails=[twice], resolve=False)


def test_join_tail_joins_on_the_second_frame_of_agreement():
    rig = plane_rig(3)
    T = 12
    pts = np.array([[-0.1, 0.0, 0.0], [0.1, 0.05, 0.0]])
    seen = np.array([[255, 255, 0]])
    # the next chunk has point 1 from frame 7 on, and another point (taken over the overlap)
    after = _store([_path(pts[0], range(4, 12)), _path(pts[1], range(7, 12))], [4, 7],
                   np.repeat(seen, 2, axis=0), T)  # fmt: skip
    # the tail carries point 0 (joined over the overlap) and point 1 over frames 6-10
    frames = np.array([6, 7, 8, 9, 10])
    tail = Bridge(
        ids=np.array([0] * 5 + [1] * 5),
        frame=np.concatenate([frames, frames]),
        xyz=np.concatenate([_path(pts[0], frames), _path(pts[1], frames)]).astype(np.float32),
        visibility=np.repeat(seen, 10, axis=0).astype(np.uint8),
        error=np.full(10, 0.2, np.float32),
        color=np.full((10, 3), 128, np.uint8),
        joins=np.zeros((0, 3), np.int64),
    )
    out = join_tail(tail, after, np.array([0]), np.array([0]), rig, 0.005, 4.0, 0.05)
    assert out.joins.tolist() == [[1, 1, 8]]  # matched at 7 and 8: joined at 8
    assert out.ids.tolist() == [1, 1] and out.frame.tolist() == [6, 7]
    # point 1 carried 2 cm off at frame 7: it matches at 8 and 9 first, and joins at 9
    moved = dataclasses.replace(tail, xyz=tail.xyz.copy())
    moved.xyz[6] += [0.02, 0.0, 0.0]
    out = join_tail(moved, after, np.array([0]), np.array([0]), rig, 0.005, 4.0, 0.05)
    assert out.joins.tolist() == [[1, 1, 9]] and out.frame.tolist() == [6, 7, 8]


# -- whole runs ----------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def tiny6(tmp_path_factory) -> Path:
    """A rendered tiny4 capture of 6 frames."""
    from pointtraj.stages import SynthConfig, synthesize

    cap = tmp_path_factory.mktemp("chunks") / "cap"
    synthesize(cap, SynthConfig(preset="tiny4", frames=6, points_per_part=40))
    return cap


CHUNKED = ReconstructConfig(chunk_frames=3, chunk_overlap=2)


def _arrays(work: Path) -> dict[str, np.ndarray]:
    with np.load(work / "trajectories.npz") as d:
        return {k: d[k] for k in d.files}


def _same_outputs(w1: Path, w2: Path) -> None:
    a, b = _arrays(w1), _arrays(w2)
    assert a.keys() == b.keys()
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)
    clouds = sorted(p.name for p in (w1 / "clouds").iterdir())
    assert clouds == sorted(p.name for p in (w2 / "clouds").iterdir())
    for name in clouds:
        assert (w1 / "clouds" / name).read_bytes() == (w2 / "clouds" / name).read_bytes(), name


@pytest.mark.slow
def test_chunked_run_on_a_local_cluster_equals_the_serial_run(tiny6: Path, tmp_path: Path):
    from pointtraj.executor import ExecutorConfig, open_executor
    from pointtraj.stages import reconstruct_work

    serial = reconstruct_work(tmp_path / "serial", tiny6, CHUNKED)
    assert (tmp_path / "serial" / "chunks" / "000000-000003" / "trajectories.npz").is_file()
    assert (tmp_path / "serial" / "chunks" / "000001-000006" / "trajectories.npz").is_file()
    assert (tmp_path / "serial" / "chunks" / "000000-000003" / "tail.npz").is_file()
    assert not (tmp_path / "serial" / "chunks" / "000001-000006" / "tail.npz").exists()
    assert serial.occupied_frames == range(6)
    with open_executor(ExecutorConfig(workers=2)) as ex:
        assert ex.workers == 2
        cluster = reconstruct_work(tmp_path / "cluster", tiny6, CHUNKED, executor=ex)
    assert cluster.num_trajectories == serial.num_trajectories
    _same_outputs(tmp_path / "serial", tmp_path / "cluster")
    # the workers' files are the work folder's: a restart removes them
    reconstruct_work(tmp_path / "cluster", tiny6, ReconstructConfig(), restart=True)
    assert not (tmp_path / "cluster" / "chunks").exists()
    _same_outputs(tmp_path / "cluster", _one_chunk(tiny6, tmp_path))


def _one_chunk(capture: Path, tmp_path: Path) -> Path:
    from pointtraj.stages import reconstruct_work

    work = tmp_path / "one"
    if not (work / "trajectories.npz").is_file():
        reconstruct_work(work, capture, ReconstructConfig(chunk_frames=0, chunk_overlap=0))
    return work


@pytest.mark.slow
def test_chunks_resume_and_track_as_one_run_would(tiny6: Path, tmp_path: Path):
    from pointtraj.reconstruct.stage import ChunkTask, reconstruct_chunk
    from pointtraj.session import Capture
    from pointtraj.stages import reconstruct_work

    work = tmp_path / "w"
    reconstruct_work(work, tiny6, CHUNKED)
    reference = _arrays(work)
    # the first chunk tracks frames 0-2 exactly as an unchunked run does
    one = _one_chunk(tiny6, tmp_path)
    from pointtraj.reconstruct.framestore import FrameStore

    for t in range(3):
        a = FrameStore(work / "chunks" / "000000-000003", 4).read_record(t)
        b = FrameStore(one, 4).read_record(t)
        np.testing.assert_array_equal(a.xyz, b.xyz)
        np.testing.assert_array_equal(a.ids, b.ids)
    # a complete chunk is not recomputed; one without its tail only tracks the tail
    cap = Capture.open(tiny6)
    first = work / "chunks" / "000000-000003"
    task = ChunkTask(str(tiny6), cap.rig, str(first), 0, 3, 6, CHUNKED)
    assert reconstruct_chunk(task).tracked == 0
    tail = (first / "tail.npz").read_bytes()
    (first / "tail.npz").unlink()
    result = reconstruct_chunk(task)
    assert result.tracked == 0 and (first / "tail.npz").read_bytes() == tail
    # an interrupted chunk resumes after its last complete frame, to the same result: the
    # interruption after frame 3 is a run of the chunk's first frames into a fresh folder
    second = work / "chunks" / "000001-000006"
    store = dict(np.load(second / "trajectories.npz"))
    shutil.rmtree(second)
    reconstruct_chunk(ChunkTask(str(tiny6), cap.rig, str(second), 1, 4, 4, CHUNKED))
    (second / "trajectories.npz").unlink()
    task = ChunkTask(str(tiny6), cap.rig, str(second), 1, 6, 6, CHUNKED)
    assert reconstruct_chunk(task).tracked == 2
    for k, v in np.load(second / "trajectories.npz").items():
        np.testing.assert_array_equal(v, store[k], err_msg=k)
    (second / "trajectories.npz").unlink()
    (first / "tail.npz").unlink()
    (work / "trajectories.npz").unlink()
    reconstruct_work(work, tiny6, CHUNKED)
    for k, v in reference.items():
        np.testing.assert_array_equal(_arrays(work)[k], v, err_msg=k)


@pytest.mark.slow
def test_a_range_within_one_chunk_is_reconstructed_as_without_chunks(tiny6: Path, tmp_path: Path):
    from pointtraj.stages import reconstruct_work

    reconstruct_work(tmp_path / "big", tiny6, ReconstructConfig(chunk_frames=6, chunk_overlap=2))
    assert not (tmp_path / "big" / "chunks").exists()
    _same_outputs(tmp_path / "big", _one_chunk(tiny6, tmp_path))


def test_tracking_runs_blas_on_one_thread():
    """``one_blas_thread`` limits every BLAS pool to one thread, as Dask's worker environment
    does, so that tracking rounds alike in the calling process and in a worker; the limit is
    lifted after."""
    from threadpoolctl import threadpool_info

    from pointtraj.reconstruct.stage import one_blas_thread

    before = {i["filepath"]: i["num_threads"] for i in threadpool_info()}
    with one_blas_thread():
        blas = [i for i in threadpool_info() if i["user_api"] == "blas"]
        assert blas and all(i["num_threads"] == 1 for i in blas)
    assert {i["filepath"]: i["num_threads"] for i in threadpool_info()} == before


def _gained_views(tail) -> int:
    """Rows of a tail where a trajectory is seen by a camera that its row before did not have."""
    from pointtraj.trajectories import dequantize_visibility

    seen = dequantize_visibility(tail.visibility) > ReconstructConfig().visibility_threshold
    order = np.lexsort((tail.frame, tail.ids))
    ids, seen = tail.ids[order], seen[order]
    same = ids[1:] == ids[:-1]
    return int(np.count_nonzero(same & (seen[1:] & ~seen[:-1]).any(axis=1)))


@pytest.mark.slow
def test_a_tail_without_discovery_only_tracks_the_views_it_has(tiny6: Path, tmp_path: Path):
    from pointtraj.reconstruct.chunks import Bridge
    from pointtraj.stages import reconstruct_work

    tails = {}
    for search in (True, False):
        work = tmp_path / f"search_{search}"
        cfg = dataclasses.replace(CHUNKED, chunk_tail_discovery=search)
        reconstruct_work(work, tiny6, cfg)
        tails[search] = Bridge.load(work / "chunks" / "000000-000003" / "tail.npz")
    assert len(tails[True].ids) and len(tails[False].ids)
    assert _gained_views(tails[True]) > 0  # discovery finds views in the tail
    assert _gained_views(tails[False]) == 0  # without it, views are only lost
