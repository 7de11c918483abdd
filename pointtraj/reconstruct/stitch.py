"""Stitching: join a trajectory that ended to one born where it would have gone.

A point that loses its views for a frame or two (an occlusion, a flow failure) ends, and
matching gives it back a frame later as a new trajectory. Stitching joins the two:

- a trajectory ``a`` that ends at frame ``t`` and a trajectory ``b`` that starts at frame
  ``t + 1 + g``, for a gap ``g`` of at most ``max_gap`` frames;
- ``b``'s first position lies within ``radius_m`` (plus ``speed_factor`` times the distance
  ``a`` moved in its last frame, per frame of the prediction) of ``a``'s position predicted by
  its last velocity;
- their colours differ by at most ``max_color_diff`` (mean absolute difference over RGB).

Each end and each start joins at most once, nearest first; chains form (``a`` to ``b`` to ``c``).
The frames of a gap are filled by linear interpolation between the two positions; they carry no
view (visibility 0 in every camera) and a NaN reprojection error, so that they can be told apart
(``num_views`` 0 in the clouds).
"""

from __future__ import annotations

import itertools
import logging
from dataclasses import dataclass

import numpy as np

from ..errors import ValidationError
from ..scale import SceneLength
from ..trajectories import Trajectories

__all__ = ["StitchConfig", "stitch_trajectories"]

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class StitchConfig:
    """Parameters of stitching (TOML table ``[reconstruct.stitch]``).

    Attributes
    ----------
    enabled : bool
    max_gap : int
        Frames without the point that a stitch may bridge (0: only a start in the very next
        frame).
    radius_m : float
        Largest distance between the predicted and the new position.
    speed_factor : float
        The radius grows by this times the last frame's motion, per predicted frame.
    max_color_diff : float
        Largest mean absolute RGB difference (0-255) between the two trajectories' colours.
    """

    enabled: bool = True
    max_gap: int = 2
    radius_m: float = SceneLength(0.015)
    speed_factor: float = 0.5
    max_color_diff: float = 40.0

    def __post_init__(self) -> None:
        checks = {
            "max_gap": self.max_gap >= 0,
            "radius_m": self.radius_m > 0,
            "speed_factor": self.speed_factor >= 0,
            "max_color_diff": self.max_color_diff >= 0,
        }
        bad = [k for k, ok in checks.items() if not ok]
        if bad:
            raise ValidationError(f"StitchConfig.{bad[0]} out of range: {getattr(self, bad[0])!r}")


def _links(traj: Trajectories, cfg: StitchConfig) -> np.ndarray:
    """(L, 2) pairs (a, b): trajectory a continues as trajectory b."""
    from scipy.spatial import cKDTree

    M = traj.num_trajectories
    first = traj.first_frame
    last = traj.last_frame
    start_rows = traj.offsets[:-1]
    end_rows = traj.offsets[1:] - 1
    x_end = traj.xyz[end_rows].astype(np.float64)
    x_prev = traj.xyz[np.where(traj.lengths > 1, end_rows - 1, end_rows)].astype(np.float64)
    velocity = x_end - x_prev  # (M, 3) per frame
    x_start = traj.xyz[start_rows].astype(np.float64)
    color = traj.color.astype(np.float64)
    c_end, c_start = color[end_rows], color[start_rows]
    starts_at = {int(t): np.flatnonzero(first == t) for t in np.unique(first)}
    pairs, dists = [], []
    for g in range(cfg.max_gap + 1):
        step = g + 1
        for t, b_idx in starts_at.items():
            a_idx = np.flatnonzero(last == t - step)
            if a_idx.size == 0:
                continue
            pred = x_end[a_idx] + step * velocity[a_idx]
            reach = cfg.radius_m + cfg.speed_factor * step * np.linalg.norm(velocity[a_idx], axis=1)
            found = cKDTree(x_start[b_idx]).query_ball_point(pred, reach)
            counts = np.fromiter(map(len, found), np.int64, len(found))
            if not counts.any():
                continue
            i = np.repeat(np.arange(len(a_idx)), counts)  # (k,) row of pred
            bb = b_idx[np.fromiter(itertools.chain.from_iterable(found), np.int64, counts.sum())]
            aa = a_idx[i]
            ok = np.abs(c_end[aa] - c_start[bb]).mean(axis=1) <= cfg.max_color_diff
            pairs.append(np.column_stack([aa[ok], bb[ok]]))
            dists.append(np.linalg.norm(x_start[bb[ok]] - pred[i[ok]], axis=1) + 1e-6 * g)
    if not pairs:
        return np.zeros((0, 2), np.int64)
    return _greedy_matching(np.concatenate(pairs), np.concatenate(dists), M)


def _greedy_matching(pairs: np.ndarray, cost: np.ndarray, M: int) -> np.ndarray:
    """Pairs taken nearest first, each end and each start at most once.

    Vectorised in rounds: a pair that is the cheapest remaining one of both its end and its
    start is taken by the greedy order too (no cheaper pair can claim either), so each round
    takes all of those and drops the pairs they block.

    Parameters
    ----------
    pairs : (L, 2) int ndarray
        Candidate (end, start) pairs.
    cost : (L,) float ndarray
    M : int
        Trajectories.

    Returns
    -------
    (K, 2) int64 ndarray
        The pairs taken, in input order.
    """
    order = np.lexsort((np.arange(len(cost)), cost))  # ties by position: a strict order
    rank = np.empty(len(cost), np.int64)
    rank[order] = np.arange(len(cost))
    alive = np.ones(len(cost), bool)
    taken = np.zeros(len(cost), bool)
    while alive.any():
        idx = np.flatnonzero(alive)
        best_a = np.full(M, np.iinfo(np.int64).max)
        best_b = np.full(M, np.iinfo(np.int64).max)
        np.minimum.at(best_a, pairs[idx, 0], rank[idx])
        np.minimum.at(best_b, pairs[idx, 1], rank[idx])
        win = idx[(best_a[pairs[idx, 0]] == rank[idx]) & (best_b[pairs[idx, 1]] == rank[idx])]
        taken[win] = True
        used_a = np.zeros(M, bool)
        used_b = np.zeros(M, bool)
        used_a[pairs[win, 0]] = True
        used_b[pairs[win, 1]] = True
        alive &= ~(used_a[pairs[:, 0]] | used_b[pairs[:, 1]])
    return pairs[taken]


def stitch_trajectories(
    traj: Trajectories, config: StitchConfig | None = None
) -> tuple[Trajectories, np.ndarray]:
    """Join trajectories that continue each other (see the module docstring).

    Parameters
    ----------
    traj : Trajectories
    config : StitchConfig, optional

    Returns
    -------
    stitched : Trajectories
        Trajectories in the order of their first piece.
    new_id : (M,) int64 ndarray
        The stitched trajectory that each input trajectory became part of.
    """
    cfg = config or StitchConfig()
    M = traj.num_trajectories
    identity = np.arange(M, dtype=np.int64)
    if not cfg.enabled or M == 0:
        return traj, identity
    links = _links(traj, cfg)
    if len(links) == 0:
        return traj, identity
    nxt = np.full(M, -1, np.int64)
    nxt[links[:, 0]] = links[:, 1]
    has_prev = np.zeros(M, bool)
    has_prev[links[:, 1]] = True
    heads = np.flatnonzero(~has_prev)  # in id order: the stitched order
    new_id = np.full(M, -1, np.int64)
    new_id[heads] = np.arange(heads.size)
    frontier = heads
    while frontier.size:  # follow every chain one link at a time (links go forward in time)
        step = nxt[frontier]
        ok = step >= 0
        new_id[step[ok]] = new_id[frontier[ok]]
        frontier = step[ok]
    # gap rows: linear interpolation between the end of a and the start of b
    a, b = links[:, 0], links[:, 1]
    gap = traj.first_frame[b] - traj.last_frame[a] - 1  # (L,)
    rep = np.repeat(np.arange(len(links)), gap)
    k = np.arange(rep.size) - np.repeat(np.cumsum(gap) - gap, gap) + 1  # 1..gap
    x0 = traj.xyz[traj.offsets[1:][a] - 1][rep].astype(np.float64)
    x1 = traj.xyz[traj.offsets[:-1][b]][rep].astype(np.float64)
    w = (k / (gap[rep] + 1))[:, None]
    gap_xyz = ((1 - w) * x0 + w * x1).astype(np.float32)
    gap_frame = traj.last_frame[a][rep] + k
    gap_track = new_id[a][rep]
    # every row, keyed by (stitched trajectory, frame)
    track = np.concatenate([new_id[traj.row_track], gap_track])
    frame = np.concatenate([traj.row_frame, gap_frame])
    order = np.lexsort((frame, track))
    C = traj.num_cameras
    xyz = np.concatenate([traj.xyz, gap_xyz])[order]
    vis = np.concatenate([traj.visibility, np.zeros((rep.size, C), traj.visibility.dtype)])[order]
    err = np.concatenate(
        [traj.reprojection_error, np.full(rep.size, np.nan, traj.reprojection_error.dtype)]
    )[order]
    color = np.concatenate([traj.color, traj.color[traj.offsets[1:][a] - 1][rep]])[order]
    counts = np.bincount(track, minlength=heads.size)
    offsets = np.concatenate([[0], np.cumsum(counts)])
    first = frame[order][offsets[:-1]]
    out = Trajectories(
        first_frame=first,
        offsets=offsets,
        xyz=xyz,
        visibility=vis,
        reprojection_error=err,
        color=color,
        camera_names=list(traj.camera_names),
        fps=traj.fps,
        num_frames=traj.num_frames,
    )
    logger.info(
        "stitching: %d joins (%d across a gap), %d -> %d trajectories, median length %g -> %g",
        len(links),
        int((gap > 0).sum()),
        M,
        heads.size,
        float(np.median(traj.lengths)),
        float(np.median(out.lengths)),
    )
    return out, new_id
