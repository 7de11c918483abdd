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

import logging
from dataclasses import dataclass

import numpy as np

from ..errors import ValidationError
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
    radius_m: float = 0.015
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
            if a_idx.size == 0 or b_idx.size == 0:
                continue
            pred = x_end[a_idx] + step * velocity[a_idx]
            reach = cfg.radius_m + cfg.speed_factor * step * np.linalg.norm(velocity[a_idx], axis=1)
            tree = cKDTree(x_start[b_idx])
            for i, cand in enumerate(tree.query_ball_point(pred, reach)):
                if not cand:
                    continue
                b = b_idx[np.asarray(cand)]
                a = a_idx[i]
                ok = np.abs(c_end[a] - c_start[b]).mean(axis=1) <= cfg.max_color_diff
                for bb in b[ok]:
                    pairs.append((a, bb))
                    dists.append(np.linalg.norm(x_start[bb] - pred[i]) + 1e-6 * g)
    if not pairs:
        return np.zeros((0, 2), np.int64)
    pairs = np.asarray(pairs, np.int64)
    order = np.argsort(np.asarray(dists), kind="stable")
    used_a = np.zeros(M, bool)
    used_b = np.zeros(M, bool)
    keep = []
    for k in order:  # nearest first, each end and start once (L is small: a few per frame)
        a, b = pairs[k]
        if not used_a[a] and not used_b[b]:
            used_a[a] = used_b[b] = True
            keep.append(k)
    return pairs[np.sort(np.asarray(keep, np.int64))]


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
