"""Tests of pointtraj.trajectories: the ragged store, its index, files and Open3D views."""

from __future__ import annotations

import numpy as np
import pytest

from pointtraj.errors import FileFormatError, ValidationError
from pointtraj.trajectories import Trajectories, dequantize_visibility, quantize_visibility


def dense_scene(rng: np.random.Generator, M: int = 40, T: int = 12, C: int = 3):
    """Dense (M, T, 3) positions with random contiguous lifetimes, and (M, T, C) visibility."""
    xyz = rng.normal(size=(M, T, 3))
    start = rng.integers(0, T, size=M)
    length = rng.integers(1, T + 1, size=M)
    end = np.minimum(start + length, T)
    t = np.arange(T)
    alive = (t >= start[:, None]) & (t < end[:, None])
    xyz[~alive] = np.nan
    vis = rng.uniform(size=(M, T, C))
    return xyz, vis, alive


@pytest.fixture
def store() -> tuple[Trajectories, np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(0)
    xyz, vis, alive = dense_scene(rng)
    color = rng.integers(0, 256, size=xyz.shape, dtype=np.uint8)
    tr = Trajectories.from_dense(xyz, vis, camera_names=["a", "b", "c"], color=color, fps=25.0)
    return tr, xyz, vis, alive


def test_from_dense_round_trip(store):
    tr, xyz, vis, alive = store
    M, T, _ = xyz.shape
    assert tr.num_trajectories == M and tr.num_frames == T and tr.num_cameras == 3
    assert tr.num_point_frames == alive.sum()
    assert tr.xyz.dtype == np.float32 and tr.visibility.dtype == np.uint8
    np.testing.assert_allclose(tr.dense_positions(), xyz.astype(np.float32), equal_nan=True)
    np.testing.assert_array_equal(tr.first_frame, np.argmax(alive, axis=1))
    np.testing.assert_array_equal(tr.lengths, alive.sum(axis=1))
    np.testing.assert_array_equal(tr.row_frame, np.nonzero(alive)[1])
    np.testing.assert_array_equal(tr.row_track, np.nonzero(alive)[0])
    # visibility is quantised to 1/255
    np.testing.assert_allclose(
        dequantize_visibility(tr.visibility), vis[alive], atol=0.5 / 255 + 1e-7
    )


def test_empty_store(tmp_path):
    tr = Trajectories.empty(("a", "b"), fps=25.0, num_frames=4)
    assert tr.num_trajectories == 0 and tr.num_point_frames == 0 and tr.num_cameras == 2
    assert tr.camera_names == ["a", "b"] and tr.fps == 25.0 and tr.num_frames == 4
    assert tr.visibility.shape == (0, 2) and tr.visibility.dtype == np.uint8
    assert tr.xyz.dtype == np.float32 and tr.color.dtype == np.uint8
    np.testing.assert_array_equal(tr.offsets, [0])
    assert len(tr.frame(3).track_id) == 0
    tr.save(tmp_path / "empty.npz")
    back = Trajectories.load(tmp_path / "empty.npz")
    assert back.num_trajectories == 0 and back.camera_names == ["a", "b"] and back.num_frames == 4


def test_frame_index(store):
    tr, xyz, vis, alive = store
    for t in range(tr.num_frames):
        fs = tr.frame(t)
        expected = np.nonzero(alive[:, t])[0]
        np.testing.assert_array_equal(fs.track_id, expected)
        np.testing.assert_allclose(fs.xyz, xyz[expected, t].astype(np.float32))
        assert fs.visibility.shape == (len(expected), 3) and fs.visibility.dtype == np.float32
        np.testing.assert_array_equal(tr.row_frame[fs.rows], t)
    with pytest.raises(ValidationError, match=r"frame 12 out of range \[0, 12\)"):
        tr.frame(tr.num_frames)
    with pytest.raises(ValidationError, match="out of range"):
        tr.frame_rows(-1)


def test_subset_and_concatenate(store):
    tr, xyz, _, _ = store
    pick = np.array([5, 0, 17])
    sub = tr.subset(pick)
    assert sub.num_trajectories == 3 and sub.camera_names == tr.camera_names
    np.testing.assert_allclose(sub.dense_positions(), tr.dense_positions(pick), equal_nan=True)
    for k, m in enumerate(pick):
        np.testing.assert_array_equal(sub.track(k), tr.track(m))
        rows = tr.rows_of([m])
        np.testing.assert_array_equal(sub.color[sub.rows_of([k])], tr.color[rows])
    both = Trajectories.concatenate([sub, tr.subset([1])])
    np.testing.assert_allclose(
        both.dense_positions(), tr.dense_positions([5, 0, 17, 1]), equal_nan=True
    )


def test_save_load_round_trip(store, tmp_path):
    tr = store[0]
    path = tmp_path / "work" / "trajectories.npz"
    tr.save(path)
    back = Trajectories.load(path)
    for name in ("first_frame", "offsets", "xyz", "visibility", "reprojection_error", "color"):
        np.testing.assert_array_equal(getattr(back, name), getattr(tr, name))
    assert back.camera_names == tr.camera_names and back.fps == 25.0 and back.num_frames == 12
    assert [p.name for p in path.parent.iterdir()] == ["trajectories.npz"]  # no temporaries left


def test_load_corrupt_files(store, tmp_path):
    """Truncated and empty files used to escape as zipfile.BadZipFile / EOFError."""
    tr = store[0]
    good = tmp_path / "good.npz"
    tr.save(good)
    data = good.read_bytes()
    cases = {
        "truncated.npz": data[: len(data) // 2],
        "empty.npz": b"",
        "text.npz": b"this is not an npz file\n" * 4,
    }
    np.save(tmp_path / "array.npy", np.zeros(3))
    cases["array.npz"] = (tmp_path / "array.npy").read_bytes()
    for name, content in cases.items():
        (tmp_path / name).write_bytes(content)
        with pytest.raises(FileFormatError, match="not a readable .npz file"):
            Trajectories.load(tmp_path / name)
    with pytest.raises(FileFormatError, match="no such file"):
        Trajectories.load(tmp_path / "missing.npz")
    np.savez(tmp_path / "partial.npz", xyz=tr.xyz)
    with pytest.raises(FileFormatError, match="missing array.*first_frame"):
        Trajectories.load(tmp_path / "partial.npz")
    fields = dict(np.load(good))
    fields["offsets"] = fields["offsets"][::-1]
    np.savez(tmp_path / "bad_offsets.npz", **fields)
    with pytest.raises(FileFormatError, match="offsets must start at 0"):
        Trajectories.load(tmp_path / "bad_offsets.npz")
    fields = dict(np.load(good))
    fields["format_version"] = np.int64(99)
    np.savez(tmp_path / "future.npz", **fields)
    with pytest.raises(FileFormatError, match="format_version 99 is newer"):
        Trajectories.load(tmp_path / "future.npz")


def test_ply_attributes_survive(store, tmp_path):
    """Positions, colours, visibility, track_id and label read back with Open3D.

    Writing used to fail: PLY has no Int64 and track_id was Int64. Open3D writes the (N, C)
    visibility as per-camera properties ``visibility_<c>``.
    """
    import open3d as o3d

    tr = store[0]
    labels = np.arange(tr.num_trajectories, dtype=np.int64) % 5
    t = 6
    path = tmp_path / "clouds" / f"{t:06d}.ply"
    tr.write_frame_ply(t, path, labels=labels)
    pcd = o3d.t.io.read_point_cloud(str(path))
    fs = tr.frame(t)
    np.testing.assert_array_equal(pcd.point.positions.numpy(), fs.xyz)
    np.testing.assert_array_equal(pcd.point.track_id.numpy().ravel(), fs.track_id)
    np.testing.assert_array_equal(pcd.point.label.numpy().ravel(), labels[fs.track_id])
    vis = np.stack([pcd.point[f"visibility_{c}"].numpy().ravel() for c in range(3)], axis=1)
    np.testing.assert_array_equal(vis, fs.visibility)
    np.testing.assert_allclose(pcd.point.colors.numpy() * 255, tr.color[fs.rows], atol=1e-3)


def test_load_cloud_round_trips_the_view_counts(store, tmp_path):
    """The per-point view count and the verified flag (>= 3 views) survive the PLY."""
    from pointtraj.trajectories import load_cloud, view_counts

    tr = store[0]
    labels = np.arange(tr.num_trajectories, dtype=np.int64) % 5
    for t in range(tr.num_frames):
        path = tmp_path / f"{t:06d}.ply"
        tr.write_frame_ply(t, path, labels=labels)
        cloud = load_cloud(path)
        fs = tr.frame(t)
        views = (tr.visibility[fs.rows] >= 13).sum(axis=1)
        np.testing.assert_array_equal(cloud["num_views"], views)
        np.testing.assert_array_equal(view_counts(tr.visibility[fs.rows]), views)
        np.testing.assert_array_equal(cloud["verified"], views >= 3)
        np.testing.assert_array_equal(cloud["track_id"], fs.track_id)
        np.testing.assert_array_equal(cloud["label"], labels[fs.track_id])
        np.testing.assert_array_equal(cloud["visibility"], fs.visibility)
        assert cloud["track_id"].dtype == np.int64
    assert {2, 3} <= set(np.unique(view_counts(tr.visibility)))  # both kinds occur
    path.write_bytes(path.read_bytes()[:-7])
    with pytest.raises(FileFormatError, match="not a complete PLY file"):
        load_cloud(path)


@pytest.mark.parametrize("form", ["full", "uint8", "sparse"])
def test_every_cloud_visibility_form_round_trips(store, tmp_path, form):
    """Each visibility form reads back through load_cloud; Open3D reads every form's vertices.

    ``uint8`` is exact against the store; ``sparse`` keeps the observed views (>= 13/255)
    exactly and reads 0 elsewhere.
    """
    import open3d as o3d

    from pointtraj.trajectories import OBSERVED_MIN, load_cloud

    tr = store[0]
    sizes = {}
    for t in range(tr.num_frames):
        path = tmp_path / f"{t:06d}.ply"
        tr.write_frame_ply(t, path, visibility_form=form)
        cloud = load_cloud(path)
        fs = tr.frame(t)
        q = tr.visibility[fs.rows]
        want = fs.visibility if form != "sparse" else np.where(q >= OBSERVED_MIN, fs.visibility, 0)
        assert cloud["visibility"].dtype == np.float32
        assert cloud["visibility"].shape == (len(fs.rows), 3)
        np.testing.assert_array_equal(cloud["visibility"], want)
        np.testing.assert_array_equal(cloud["track_id"], fs.track_id)
        np.testing.assert_array_equal(cloud["xyz"], fs.xyz)
        pcd = o3d.t.io.read_point_cloud(str(path))
        np.testing.assert_array_equal(pcd.point.positions.numpy(), fs.xyz)
        sizes[t] = path.stat().st_size
    if form == "sparse":  # some views were below the threshold and are gone
        assert (tr.visibility < OBSERVED_MIN).any()
    empty = Trajectories.empty(["a", "b", "c"], num_frames=1)
    empty.write_frame_ply(0, tmp_path / "empty.ply", visibility_form=form)
    assert load_cloud(tmp_path / "empty.ply")["visibility"].shape[0] == 0
    with pytest.raises(ValidationError, match="visibility_form must be one of"):
        tr.write_frame_ply(0, tmp_path / "x.ply", visibility_form="float16")


def test_a_sparse_cloud_whose_views_disagree_is_refused(store, tmp_path):
    from pointtraj.trajectories import load_cloud

    tr = store[0]
    path = tmp_path / "s.ply"
    tr.write_frame_ply(6, path, visibility_form="sparse")
    data = path.read_bytes()
    head = data[: data.index(b"end_header")]
    count = int(head.split(b"element view ")[1].split(b"\n")[0])
    bad = data.replace(f"element view {count}".encode(), f"element view {count - 1}".encode())
    path.write_bytes(bad[:-2])
    with pytest.raises(FileFormatError, match="views do not match the vertices' num_views"):
        load_cloud(path)


def test_pointcloud_in_memory(store):
    tr = store[0]
    pcd = tr.to_pointcloud(3)
    fs = tr.frame(3)
    assert pcd.point.visibility.numpy().shape == (len(fs.rows), 3)
    assert "label" not in pcd.point
    with pytest.raises(ValidationError, match=r"labels: expected shape \(40,\)"):
        tr.to_pointcloud(3, labels=np.zeros(3))


def test_validation():
    with pytest.raises(ValidationError, match="gap"):
        Trajectories.from_dense(np.array([[[0, 0, 0], [np.nan] * 3, [1, 1, 1.0]]]))
    with pytest.raises(ValidationError, match="at least one finite frame"):
        Trajectories.from_dense(np.full((1, 3, 3), np.nan))
    with pytest.raises(ValidationError, match=r"xyz: expected shape \(N, N, 3\)"):
        Trajectories.from_dense(np.zeros((2, 3)))
    ok = dict(
        first_frame=[0],
        offsets=[0, 2],
        xyz=np.zeros((2, 3)),
        visibility=np.zeros((2, 1), np.uint8),
        reprojection_error=np.zeros(2),
        color=np.zeros((2, 3), np.uint8),
        camera_names=["a"],
    )
    Trajectories(**ok)
    with pytest.raises(ValidationError, match="quantised uint8"):
        Trajectories(**{**ok, "visibility": np.zeros((2, 1))})
    with pytest.raises(ValidationError, match=r"xyz: expected shape \(2, 3\)"):
        Trajectories(**{**ok, "xyz": np.zeros((3, 3))})
    with pytest.raises(ValidationError, match="non-negative"):
        Trajectories(**{**ok, "first_frame": [-1]})


def test_quantize_visibility():
    v = np.array([0.0, 1.0, 0.5, np.nan, 2.0, -1.0])
    q = quantize_visibility(v)
    np.testing.assert_array_equal(q, [0, 255, 128, 0, 255, 0])
    np.testing.assert_allclose(dequantize_visibility(q)[:2], [0.0, 1.0])


def test_load_cloud_round_trips_the_instance(store, tmp_path):
    """The int32 ``instance`` attribute (person id, -1 none) reads back through load_cloud,
    in every visibility form; a cloud written without it has none."""
    from pointtraj.trajectories import load_cloud

    tr = store[0]
    labels = np.arange(tr.num_trajectories, dtype=np.int64) % 5
    instances = np.arange(tr.num_trajectories, dtype=np.int64) % 3 - 1  # -1, 0, 1, ...
    t = 6
    fs = tr.frame(t)
    for form in ("full", "uint8", "sparse"):
        path = tmp_path / f"{form}.ply"
        tr.write_frame_ply(t, path, visibility_form=form, labels=labels, instances=instances)
        cloud = load_cloud(path)
        assert cloud["instance"].dtype == np.int32
        np.testing.assert_array_equal(cloud["instance"], instances[fs.track_id])
        np.testing.assert_array_equal(cloud["label"], labels[fs.track_id])
    tr.write_frame_ply(t, tmp_path / "plain.ply", labels=labels)
    assert "instance" not in load_cloud(tmp_path / "plain.ply")
    with pytest.raises(ValidationError, match="instances"):
        tr.to_pointcloud(t, instances=np.zeros(2))
