"""Stitching: a trajectory that ends and one born where it would have gone become one."""

from __future__ import annotations

import numpy as np
import pytest

from pointtraj.errors import ValidationError
from pointtraj.reconstruct.stitch import StitchConfig, stitch_trajectories
from pointtraj.trajectories import Trajectories


def moving_points(T: int = 10, M: int = 30, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(M, T, 3) points on a grid 5 cm apart moving 1 cm a frame, and their colours (M, 3)."""
    rng = np.random.default_rng(seed)
    grid = np.stack(np.meshgrid(np.arange(6), np.arange(5)), -1).reshape(-1, 2)[:M] * 0.05
    base = np.column_stack([grid, np.zeros(M)])
    xyz = base[:, None, :] + np.arange(T)[None, :, None] * np.array([0.01, 0.0, 0.0])
    color = rng.integers(0, 256, (M, 3), dtype=np.uint8)
    return xyz, color


def store(xyz: np.ndarray, alive: np.ndarray, color: np.ndarray) -> Trajectories:
    """A store where each point's live runs (alive (M, T)) are separate trajectories."""
    M, T, C = xyz.shape[0], xyz.shape[1], 3
    pieces, colors = [], []
    for m in range(M):
        runs = np.flatnonzero(np.diff(np.concatenate([[0], alive[m].astype(int), [0]])))
        for s, e in zip(runs[::2], runs[1::2]):
            pieces.append((m, s, e))
            colors.append(color[m])
    first = np.array([s for _, s, _ in pieces])
    lengths = np.array([e - s for _, s, e in pieces])
    rows = np.concatenate([[(m, t) for t in range(s, e)] for m, s, e in pieces])
    return Trajectories(
        first_frame=first,
        offsets=np.concatenate([[0], np.cumsum(lengths)]),
        xyz=xyz[rows[:, 0], rows[:, 1]].astype(np.float32),
        visibility=np.full((len(rows), C), 200, np.uint8),
        reprojection_error=np.full(len(rows), 0.3, np.float32),
        color=np.repeat(np.array(colors), lengths, axis=0),
        camera_names=["a", "b", "c"],
        fps=10.0,
        num_frames=T,
    )


def test_one_trajectory_across_a_one_frame_gap():
    xyz, color = moving_points()
    alive = np.ones(xyz.shape[:2], bool)
    alive[3, 5] = False  # point 3 lost at frame 5: two pieces, 0-4 and 6-9
    alive[7, 4:] = False  # point 7 ends for good
    traj = store(xyz, alive, color)
    assert traj.num_trajectories == 31
    out, new_id = stitch_trajectories(traj)
    assert out.num_trajectories == 30
    m = new_id[3]  # point 3's first piece
    rows = np.arange(out.offsets[m], out.offsets[m + 1])
    assert out.first_frame[m] == 0 and len(rows) == 10
    np.testing.assert_allclose(out.xyz[rows], xyz[3], atol=1e-6)  # the gap, interpolated
    gap = rows[5]
    assert not out.visibility[gap].any() and np.isnan(out.reprojection_error[gap])
    assert out.visibility[rows[[4, 6]]].all()
    assert out.lengths[new_id[8]] == 4  # point 7 (piece 8: point 3 has two pieces)
    # every other trajectory is unchanged
    np.testing.assert_array_equal(np.sort(out.lengths), np.sort([10] * 28 + [4, 10]))


def test_no_stitch_to_a_far_or_differently_coloured_start():
    xyz, color = moving_points()
    alive = np.ones(xyz.shape[:2], bool)
    alive[3, 5] = False
    moved = xyz.copy()
    moved[3, 6:] += [0.0, 0.0, 0.04]  # reborn 4 cm off the prediction
    assert stitch_trajectories(store(moved, alive, color))[0].num_trajectories == 31
    recolored = store(xyz, alive, color)
    piece = np.flatnonzero(recolored.first_frame == 6)[0]  # point 3's second piece
    recolored.color[recolored.offsets[piece] : recolored.offsets[piece + 1]] = np.where(
        color[3] > 127, 0, 255
    ).astype(np.uint8)  # at least 128 levels off in every channel
    assert stitch_trajectories(recolored)[0].num_trajectories == 31
    # a gap longer than max_gap is not bridged
    alive[3, 5:8] = False
    assert (
        stitch_trajectories(store(xyz, alive, color), StitchConfig(max_gap=2))[0].num_trajectories
        == 31
    )
    assert (
        stitch_trajectories(store(xyz, alive, color), StitchConfig(max_gap=3))[0].num_trajectories
        == 30
    )


def test_chains_and_disabled():
    xyz, color = moving_points()
    alive = np.ones(xyz.shape[:2], bool)
    alive[0, [2, 5]] = False  # three pieces
    traj = store(xyz, alive, color)
    out, new_id = stitch_trajectories(traj)
    assert out.num_trajectories == 30
    assert out.lengths[new_id[0]] == 10
    same, ident = stitch_trajectories(traj, StitchConfig(enabled=False))
    assert same is traj and np.array_equal(ident, np.arange(traj.num_trajectories))
    with pytest.raises(ValidationError, match="StitchConfig.max_gap"):
        StitchConfig(max_gap=-1)
