"""Tests of the trajectory affinity (pointtraj.affinity) and the affinity/label CLI."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from click.testing import CliRunner

from pointtraj.affinity import (
    AffinityConfig,
    AffinityGraph,
    LocalTransforms,
    candidate_pairs,
    compute_affinity,
    filter_neighbors,
    find_all_pairs,
    fit_local_rigid,
    load_affinity,
    nearest_neighbors,
    pair_errors,
    pair_max_distance,
    sample_neighbors,
    save_affinity,
)
from pointtraj.errors import FileFormatError, ValidationError
from pointtraj.trajectories import Trajectories


def rotation_z(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def articulated_scene(
    rng: np.random.Generator, n: int = 600, T: int = 8, noise: float = 0.0, fragment: bool = True
):
    """Two touching rigid boxes (0.3 m) turning in opposite directions; fragmented tracks.

    Returns (trajectories, body label per trajectory, dense (M, T, 3) positions).
    """
    dense, body = [], []
    for b, (centre, omega, vel) in enumerate(
        [((0.0, 0.0, 0.0), 0.06, (0.01, 0.0, 0.0)), ((0.3, 0.0, 0.0), -0.06, (0.0, 0.02, 0.0))]
    ):
        p = rng.uniform(-0.15, 0.15, (n, 3))
        X = np.stack(
            [p @ rotation_z(omega * t).T + np.array(centre) + np.array(vel) * t for t in range(T)],
            axis=1,
        )
        dense.append(X)
        body.append(np.full(n, b))
    X = np.concatenate(dense) + rng.normal(0, noise, (2 * n, T, 3))
    if fragment:
        first = rng.integers(0, T - 2, 2 * n)
        last = np.minimum(first + rng.integers(2, T + 1, 2 * n), T)
        t = np.arange(T)
        X[(t[None] < first[:, None]) | (t[None] >= last[:, None])] = np.nan
    return Trajectories.from_dense(X.astype(np.float32)), np.concatenate(body), X


def test_pair_max_distance_matches_dense():
    rng = np.random.default_rng(1)
    traj, _, X = articulated_scene(rng, n=50)
    i = rng.integers(0, 100, 300)
    j = rng.integers(0, 100, 300)
    dmax, shared = pair_max_distance(traj, i, j)
    d = np.linalg.norm(X[i] - X[j], axis=2)  # (Q, T), NaN outside the shared lifetime
    alive = np.isfinite(d)
    np.testing.assert_array_equal(shared, alive.sum(1))
    expect = np.where(alive.any(1), np.nanmax(np.where(alive, d, -1.0), axis=1), np.inf)
    np.testing.assert_allclose(dmax, expect, rtol=1e-5)


def test_find_all_pairs_is_exact_superset():
    rng = np.random.default_rng(2)
    traj, _, X = articulated_scene(rng, n=150)
    i, j = find_all_pairs(traj, 0.05)
    assert np.all(i < j)
    got = set(zip(i.tolist(), j.tolist()))
    assert len(got) == i.size  # unique
    M = traj.num_trajectories
    ii, jj = np.triu_indices(M, 1)
    dmax, shared = pair_max_distance(traj, ii, jj)
    truth = (dmax < 0.05) & (shared >= 1)
    want = set(zip(ii[truth].tolist(), jj[truth].tolist()))
    assert want <= got


def test_sample_neighbors_within_radius_and_filter():
    rng = np.random.default_rng(3)
    traj, _, _ = articulated_scene(rng, n=300)
    nb = sample_neighbors(traj, 0.1, 12, np.random.default_rng(0))
    assert nb.shape == (600, 12) and nb.dtype == np.int64
    own = np.arange(600)[:, None]
    assert not np.any(nb == own)
    valid = nb >= 0
    assert valid.sum(1).mean() > 5
    # valid entries first and no repeats within a row
    assert np.all(np.diff(valid.astype(int), axis=1) <= 0)
    for r in nb[:50]:
        v = r[r >= 0]
        assert np.unique(v).size == v.size
    kept = filter_neighbors(traj, nb, 0.1)
    src = np.repeat(np.arange(600), 12)[kept.ravel() >= 0]
    dmax, shared = pair_max_distance(traj, src, kept.ravel()[kept.ravel() >= 0])
    assert np.all(dmax < 0.1) and np.all(shared >= 2)


def test_fit_local_rigid_noise_free_recovers_body_rotation():
    rng = np.random.default_rng(4)
    traj, body, _ = articulated_scene(rng, n=400, fragment=False)
    cfg = AffinityConfig()
    nb = filter_neighbors(traj, sample_neighbors(traj, cfg.epsilon, 12, rng), cfg.epsilon)
    tf = fit_local_rigid(traj, nb, cfg)
    assert tf.rotation.shape == (traj.num_point_frames, 3, 3)
    first_rows = traj.offsets[:-1]
    assert np.all(np.isnan(tf.rotation[first_rows]))
    fitted = np.flatnonzero(tf.inliers >= 0)
    assert fitted.size > 0.9 * (traj.num_point_frames - traj.num_trajectories)
    # body 0 turns +0.06 rad per frame, body 1 -0.06 rad (RANSAC rejects the other body's
    # neighbours near the seam)
    b = body[traj.row_track[fitted]]
    R_true = np.where((b == 0)[:, None, None], rotation_z(0.06), rotation_z(-0.06))
    err = np.abs(tf.rotation[fitted] - R_true).max(axis=(1, 2))
    assert np.mean(err < 1e-4) > 0.95
    np.testing.assert_allclose(np.linalg.det(tf.rotation[fitted]), 1.0, atol=1e-5)
    # the translation anchors the transform at the trajectory itself
    t = tf.translation(traj)
    r = fitted[:10]
    pred = (tf.rotation[r] @ traj.xyz[r - 1][:, :, None])[:, :, 0] + t[r]
    np.testing.assert_allclose(pred, traj.xyz[r], atol=1e-5)


@pytest.mark.parametrize("mode", ["step", "accumulated"])
def test_affinity_separates_rigid_bodies(mode):
    rng = np.random.default_rng(5)
    traj, body, _ = articulated_scene(rng, n=600)
    cfg = AffinityConfig(mode=mode, seed=1, min_affinity=0.0)  # keep every candidate pair
    g = compute_affinity(traj, cfg)
    assert g.num_nodes == traj.num_trajectories
    assert np.all(g.row < g.col)
    assert np.unique(g.row * g.num_nodes + g.col).size == g.num_edges
    assert np.all((g.weight >= 0) & (g.weight <= 1))
    same = body[g.row] == body[g.col]
    assert same.sum() > 2 * traj.num_trajectories and (~same).sum() > 100
    # the paper's A: ~1 on one rigid body, ~0 across the two bodies
    assert np.median(g.affinity[same]) > 0.99
    assert g.affinity[~same].mean() < 0.6 * g.affinity[same].mean()
    # the default threshold drops the edges whose weight is negligible, nothing else
    kept = compute_affinity(traj, AffinityConfig(mode=mode, seed=1))
    assert kept.num_edges == int((g.weight >= kept.params["min_affinity"]).sum())
    # the edge weight is A times the spatial kernel of the largest distance over the lifetime
    d, _ = pair_max_distance(traj, g.row, g.col)
    np.testing.assert_allclose(g.distance, d, rtol=1e-5)
    np.testing.assert_allclose(
        g.weight, g.affinity * np.exp(-((d / cfg.distance_scale) ** 2)), rtol=1e-4, atol=1e-7
    )
    assert np.all(d < cfg.epsilon_a)
    assert (g.weight * same).sum() > 0.95 * g.weight.sum()
    S = g.to_sparse()
    assert (S != S.T).nnz == 0


def test_paper_graph_without_kernel_or_near_neighbours():
    """distance_scale = 0 and near_neighbors = 0 give the paper's graph: weight == A."""
    rng = np.random.default_rng(15)
    traj, body, _ = articulated_scene(rng, n=300)
    cfg = AffinityConfig(near_neighbors=0, distance_scale=0.0, missing_affinity=0.0, seed=2)
    g = compute_affinity(traj, cfg)
    np.testing.assert_array_equal(g.weight, g.affinity)
    # uniform draws in the 30 cm ball reach farther than the near neighbours do
    near = compute_affinity(traj, AffinityConfig(max_neighbors=0, seed=2))
    assert np.median(g.distance) > 2 * np.median(near.distance)


def test_nearest_neighbors_match_brute_force():
    rng = np.random.default_rng(16)
    traj, _, X = articulated_scene(rng, n=120)
    k, radius = 5, 0.08
    nb = nearest_neighbors(traj, radius, k)
    M = traj.num_trajectories
    assert nb.shape == (M, k)
    mid = traj.first_frame + (traj.lengths - 1) // 2
    for i in range(0, M, 7):
        d = np.linalg.norm(X[:, mid[i]] - X[i, mid[i]], axis=1)  # NaN where not alive
        d[i] = np.nan
        alive = np.flatnonzero(np.isfinite(d) & (d < radius))
        want = alive[np.argsort(d[alive], kind="stable")][:k]
        got = nb[i][nb[i] >= 0]
        np.testing.assert_allclose(np.sort(d[got]), np.sort(d[want]), rtol=1e-6)
    assert np.all(nb != np.arange(M)[:, None])


def test_candidate_pairs_are_unique_and_within_radius():
    rng = np.random.default_rng(17)
    traj, _, _ = articulated_scene(rng, n=200)
    i, j, d = candidate_pairs(traj, 0.3, 6, 6, np.random.default_rng(0))
    assert np.all(i < j)
    assert np.unique(i * traj.num_trajectories + j).size == i.size
    dmax, shared = pair_max_distance(traj, i, j)
    np.testing.assert_allclose(d, dmax)
    assert np.all((d < 0.3) & (shared >= 2))
    # every near neighbour that passes the lifetime criterion is a candidate
    nb = nearest_neighbors(traj, 0.3, 6)
    src = np.repeat(np.arange(traj.num_trajectories), 6)[nb.ravel() >= 0]
    dst = nb.ravel()[nb.ravel() >= 0]
    dm, sh = pair_max_distance(traj, src, dst)
    ok = (dm < 0.3) & (sh >= 2)
    keys = set((np.minimum(src, dst) * 10**6 + np.maximum(src, dst))[ok].tolist())
    assert keys <= set((i * 10**6 + j).tolist())


def test_untestable_pairs_get_missing_affinity():
    """Without ε-neighbours no pair can be tested: A = missing_affinity (1 keeps the kernel)."""
    rng = np.random.default_rng(18)
    traj, _, _ = articulated_scene(rng, n=100)
    g = compute_affinity(traj, AffinityConfig(epsilon=1e-6, seed=3))
    assert g.num_edges > 0
    np.testing.assert_array_equal(g.affinity, 1.0)
    np.testing.assert_allclose(g.weight, np.exp(-((g.distance / 0.1) ** 2)), rtol=1e-5)
    g0 = compute_affinity(traj, AffinityConfig(epsilon=1e-6, missing_affinity=0.0, seed=3))
    assert g0.num_edges == 0


def test_accumulated_error_restarts_after_missing_transform():
    """A frame without a transform of i must not hide the error of the frames after it."""
    rng = np.random.default_rng(19)
    traj, body, _ = articulated_scene(rng, n=300, fragment=False)
    cfg = AffinityConfig()
    nb = filter_neighbors(traj, sample_neighbors(traj, cfg.epsilon, 12, rng), cfg.epsilon)
    tf = fit_local_rigid(traj, nb, cfg)
    fitted = (tf.inliers.reshape(-1, 8)[:, 1:] >= 0).all(axis=1)  # a transform at every frame
    i = np.flatnonzero((body == 0) & fitted)[:30]
    j = np.flatnonzero(body == 1)[:30]
    full = pair_errors(traj, tf, i, j, "accumulated")
    # remove i's transform at its second frame: the prediction restarts from j's position at
    # that frame, so the error is the one of a pair whose shared lifetime starts there
    rot = tf.rotation.copy()
    rot[traj.offsets[i] + 1] = np.nan
    gap = pair_errors(traj, LocalTransforms(rot, tf.inliers), i, j, "accumulated")
    fin = np.isfinite(full)
    assert fin.all()
    assert np.all(np.isfinite(gap[fin]))  # formerly NaN: the prediction stayed NaN
    # the same error as in a store whose lifetimes start at frame 1 (restart from j there)
    later = Trajectories.from_dense(traj.dense_positions()[:, 1:])
    M = later.num_trajectories
    rot_later = np.concatenate(
        [np.full((M, 1, 3, 3), np.nan, np.float32), rot.reshape(M, 8, 3, 3)[:, 2:]], axis=1
    )
    tf_later = LocalTransforms(rot_later.reshape(-1, 3, 3), np.zeros(M * 7, np.int16))
    ref = pair_errors(later, tf_later, i, j, "accumulated")
    np.testing.assert_allclose(gap[fin], ref[fin], rtol=1e-5, atol=1e-7)
    assert np.median(ref[fin]) > 1e-3  # the bodies drift apart: a real error, not 0


def test_pair_errors_nan_without_transforms():
    rng = np.random.default_rng(7)
    traj, _, _ = articulated_scene(rng, n=40)
    nb = np.full((traj.num_trajectories, 4), -1, dtype=np.int64)  # no ε-neighbours at all
    tf = fit_local_rigid(traj, nb, AffinityConfig())
    assert np.all(tf.inliers == -1)
    e = pair_errors(traj, tf, np.array([0, 1]), np.array([2, 3]))
    assert np.all(np.isnan(e))
    with pytest.raises(ValidationError, match="mode"):
        pair_errors(traj, tf, np.array([0]), np.array([1]), "both")


def test_config_validation():
    with pytest.raises(ValidationError, match="tau"):
        AffinityConfig(tau=0.0)
    with pytest.raises(ValidationError, match="mode"):
        AffinityConfig(mode="composed")
    with pytest.raises(ValidationError, match="symmetrize"):
        AffinityConfig(symmetrize="sum")
    with pytest.raises(ValidationError, match="distance_scale"):
        AffinityConfig(distance_scale=-0.1)
    with pytest.raises(ValidationError, match="missing_affinity"):
        AffinityConfig(missing_affinity=2.0)
    with pytest.raises(ValidationError, match="near_neighbors"):
        AffinityConfig(near_neighbors=0, max_neighbors=0)


def test_save_load_roundtrip(tmp_path):
    g = AffinityGraph(
        row=np.array([0, 1]),
        col=np.array([2, 3]),
        weight=np.array([0.5, 1.0], np.float32),
        num_nodes=4,
        params={"tau": 0.02},
        affinity=np.array([0.9, 1.0], np.float32),
        distance=np.array([0.07, 0.01], np.float32),
    )
    save_affinity(g, tmp_path / "affinity.npz")
    h = load_affinity(tmp_path / "affinity.npz")
    np.testing.assert_array_equal(h.row, g.row)
    np.testing.assert_array_equal(h.weight, g.weight)
    np.testing.assert_array_equal(h.affinity, g.affinity)
    np.testing.assert_array_equal(h.distance, g.distance)
    assert h.num_nodes == 4 and h.params == {"tau": 0.02}
    # the optional arrays may be absent (files of the first version)
    save_affinity(AffinityGraph(g.row, g.col, g.weight, 4, {}), tmp_path / "plain.npz")
    p = load_affinity(tmp_path / "plain.npz")
    assert p.affinity is None and p.distance is None
    with pytest.raises(FileFormatError, match="no such file"):
        load_affinity(tmp_path / "missing.npz")
    np.savez(tmp_path / "bad.npz", row=np.array([1]), col=np.array([0]))
    with pytest.raises(FileFormatError, match="weight"):
        load_affinity(tmp_path / "bad.npz")
    np.savez(
        tmp_path / "bad2.npz",
        row=np.array([1]),
        col=np.array([0]),
        weight=np.array([1.0]),
        shape=np.array([2, 2]),
    )
    with pytest.raises(FileFormatError, match="row < col"):
        load_affinity(tmp_path / "bad2.npz")


def test_cli_affinity_and_label(tmp_path):
    from pointtraj.cli import main
    from pointtraj.semantics.semantic_map import SemanticMap

    rng = np.random.default_rng(8)
    traj, body, _ = articulated_scene(rng, n=300)
    M = traj.num_trajectories
    traj.save(tmp_path / "trajectories.npz")
    # a noisy semantic map: 20 % of trajectories have the wrong dominant class
    l3d = np.full((M, 3), 0.1, np.float32)
    dominant = body.copy()
    wrong = rng.random(M) < 0.2
    dominant[wrong] = 1 - body[wrong]
    l3d[np.arange(M), dominant] = 0.6
    SemanticMap(
        class_names=("left", "right", "other"),
        L3D={"view": l3d},
        count={"view": np.ones(M, np.int32)},
    ).save(tmp_path / "semantic_map.npz")
    traj.write_frame_ply(0, tmp_path / "clouds" / "000000.ply")
    runner = CliRunner()
    res = runner.invoke(main, ["affinity", str(tmp_path)])
    assert res.exit_code == 0, res.output
    assert (tmp_path / "affinity.npz").is_file()
    res = runner.invoke(main, ["label", str(tmp_path), "--lambda", "1.0"])
    assert res.exit_code == 0, res.output
    with np.load(tmp_path / "labels.npz") as z:
        labels = z["labels"]
        energy = z["energy"]
        assert list(z["class_names"]) == ["left", "right", "other"]
    assert np.all(np.diff(energy) <= 1e-9)
    assert (labels == body).mean() > 0.95 > (dominant == body).mean()
    lines = (tmp_path / "labels.csv").read_text().splitlines()
    assert lines[0] == "track_id,label,label_name,confidence,first_frame,length,instance"
    assert len(lines) == M + 1
    import open3d as o3d

    pcd = o3d.t.io.read_point_cloud(str(tmp_path / "clouds" / "000000.ply"))
    assert "label" in pcd.point and "instance" in pcd.point
    # user mistakes are one-line errors
    res = runner.invoke(main, ["label", str(tmp_path), "--pooling", "average"])
    assert res.exit_code != 0 and "average" in res.output
    (tmp_path / "affinity.npz").unlink()
    res = runner.invoke(main, ["label", str(tmp_path)])
    assert res.exit_code != 0 and "affinity.npz" in res.output


def jumping_pair_scene(T: int = 10, jump: float = 0.02, at: int = 5):
    """A rigid cluster turning about z; trajectory 0 is re-triangulated from a third camera
    from frame ``at`` on, and its position jumps by ``jump`` there (a measurement, not motion).

    Returns (trajectories, index of the jumping trajectory).
    """
    rng = np.random.default_rng(31)
    p = rng.uniform(-0.02, 0.02, (40, 3))
    X = np.stack([p @ rotation_z(0.05 * t).T for t in range(T)], axis=1)  # (40, T, 3)
    # from `at` on, trajectory 0 is a point of the body `jump` away from where it was
    moved = p[0] + np.array([jump, 0.0, 0.0])
    X[0, at:] = np.stack([rotation_z(0.05 * t) @ moved for t in range(at, T)])
    vis = np.zeros((40, T, 3), np.float32)
    vis[:, :, :2] = 1.0
    vis[0, at:, 2] = 1.0  # a third view from frame `at`
    traj = Trajectories.from_dense(X.astype(np.float32), visibility=vis)
    return traj, 0


def test_view_breaks_mark_changes_of_the_observing_cameras(monkeypatch):
    import pointtraj.affinity as affinity

    traj, k = jumping_pair_scene(at=5)
    brk = affinity.view_breaks(traj)
    assert brk.shape == (traj.num_point_frames,)
    np.testing.assert_array_equal(np.flatnonzero(brk), [traj.offsets[k] + 5])
    # chunked: the same answer when a chunk boundary falls anywhere
    monkeypatch.setattr(affinity, "_BREAK_ROWS", 3)
    np.testing.assert_array_equal(affinity.view_breaks(traj), brk)
    # a change between two trajectories is no break: each trajectory's first row is False
    assert not brk[traj.offsets[:-1]].any()


def test_view_break_restarts_the_rigidity_test():
    """Regression: a jump at a change of views was read as 2 cm of motion (A ~ 0)."""
    import pointtraj.affinity as affinity

    traj, k = jumping_pair_scene(jump=0.02, at=5)
    cfg = AffinityConfig(epsilon=0.1, ransac_threshold=0.005, seed=2)
    nb = filter_neighbors(traj, sample_neighbors(traj, 0.1, 12, np.random.default_rng(1)), 0.1)
    brk = affinity.view_breaks(traj)
    plain = fit_local_rigid(traj, nb, cfg)
    tf = fit_local_rigid(traj, nb, cfg, breaks=brk)
    assert tf.breaks is brk
    row = traj.offsets[k] + 5
    assert tf.inliers[row] == -1 and np.isnan(tf.rotation[row]).all()  # no transform at i's break
    others = np.arange(1, traj.num_trajectories)
    i = np.full(others.size, k)
    for mode in ("accumulated", "step"):
        e_plain = pair_errors(traj, plain, others, i, mode)  # others' transforms predict k
        e = pair_errors(traj, tf, others, i, mode)
        assert np.nanmin(e_plain) > 0.015  # the jump, read as motion
        assert np.nanmax(e) < 1e-4  # rigid once the jump is no step
    g_plain = compute_affinity(traj, cfg)
    g = compute_affinity(traj, dataclasses.replace(cfg, view_breaks=True))
    on_k = (g.row == k) | (g.col == k)
    on_k_plain = (g_plain.row == k) | (g_plain.col == k)
    assert on_k.sum() >= 5 and g.affinity[on_k].min() > 0.99
    # without breaks the direction that predicts k fails (A ~ 0); the other direction restarts
    # where k's own transform cannot be fitted, so the mean stays at most about 0.5
    assert g_plain.affinity[on_k_plain].max() < 0.51


def test_compute_affinity_with_given_transforms():
    """Known motions in place of fitted ones: each body's exact rotation separates the bodies
    even where no ε-neighbour exists to fit a transform (ε = 1 µm)."""
    rng = np.random.default_rng(23)
    traj, body, _ = articulated_scene(rng, n=150)
    P = traj.num_point_frames
    omega = np.where(body == 0, 0.06, -0.06)[traj.row_track]  # (P,) each body's turn per frame
    rot = np.stack([rotation_z(w) for w in omega]).astype(np.float32)
    rot[traj.offsets[:-1]] = np.nan  # no transform at a trajectory's first frame
    exact = LocalTransforms(rot, np.zeros(P, np.int16))
    cfg = AffinityConfig(epsilon=1e-6, seed=4)
    g = compute_affinity(traj, cfg, transforms=exact)
    same = body[g.row] == body[g.col]
    assert same.sum() > 50
    np.testing.assert_allclose(g.affinity[same], 1.0, atol=1e-4)
    fitted = compute_affinity(traj, cfg)  # nothing to fit with: every pair untestable
    np.testing.assert_array_equal(fitted.affinity, 1.0)
    assert (~same).sum() < 0.2 * (fitted.num_edges - (body[fitted.row] == body[fitted.col]).sum())
    with pytest.raises(ValidationError, match="transforms.rotation"):
        compute_affinity(traj, cfg, transforms=LocalTransforms(rot[:-1], np.zeros(P - 1, np.int16)))
