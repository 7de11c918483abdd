"""Tracking in temporal chunks: the chunk plan, and joining trajectories across boundaries.

A long frame range is cut at fixed boundaries every ``chunk_frames`` frames
(:func:`plan_chunks`). Each chunk is tracked by its own :class:`~.track.Tracker`, as one task of
the executor, starting ``chunk_overlap`` frames before its boundary to warm up: over those
frames both the chunk before and this one have points. The plan depends only on the
configuration and the frame range, so serial and cluster runs track the same chunks and give
the same output.

:func:`merge_chunks` then makes one store of the chunks' stores:

- each frame's points come from exactly one chunk: frames before a boundary from the chunk
  before it, frames from the boundary on from the chunk after it (a chunk's warm-up rows are
  dropped), so no point is duplicated;
- a trajectory of the chunk before that is alive at the boundary's last frame continues as the
  trajectory of the chunk after that is the same physical point (:func:`join_boundary`): the
  two stay within ``chunk_join_m`` over every overlap frame where both exist, their positions
  project within twice ``ransac_threshold_px`` of each other in every camera where both are
  seen at the boundary (at least one), and each is the other's best candidate (mutual best
  match on the mean 3D distance).

What no join continues ends at the boundary; the stitching of the whole store
(:mod:`~.stitch`) may still join it to a point born at the boundary.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from ..camera import CameraRig
from ..errors import ValidationError
from ..trajectories import Trajectories, dequantize_visibility

__all__ = ["Chunk", "JoinCount", "plan_chunks", "join_boundary", "merge_chunks"]

logger = logging.getLogger(__name__)

#: Candidates per trajectory (nearest at the boundary's last frame) scored over the overlap.
_CANDIDATES = 4
#: Pairs whose projections are compared at once (bounds the (C, n, 2) arrays).
_BATCH = 20000


@dataclass(frozen=True)
class Chunk:
    """Frames ``start:stop`` tracked by one tracker; its points are kept from ``boundary`` on.

    Attributes
    ----------
    start : int
        First frame tracked (``boundary`` minus the warm-up).
    boundary : int
        First frame whose points this chunk gives.
    stop : int
        One past the last frame.
    """

    start: int
    boundary: int
    stop: int

    @property
    def name(self) -> str:
        """The chunk's sub-folder name, ``<start>-<stop>`` (six digits each)."""
        return f"{self.start:06d}-{self.stop:06d}"

    @property
    def frames(self) -> range:
        """The frames tracked."""
        return range(self.start, self.stop)


@dataclass(frozen=True)
class JoinCount:
    """What happened at one chunk boundary.

    Attributes
    ----------
    boundary : int
    ending : int
        Trajectories of the chunk before alive at ``boundary - 1``.
    candidates : int
        Trajectories of the chunk after alive at both ``boundary - 1`` and ``boundary``.
    joined : int
        Pairs joined into one trajectory.
    """

    boundary: int
    ending: int
    candidates: int
    joined: int


def plan_chunks(frames: range, chunk_frames: int, overlap: int) -> list[Chunk]:
    """Cut a frame range into chunks (a function of its arguments only).

    Parameters
    ----------
    frames : range
        Step 1, non-empty.
    chunk_frames : int
        Frames per chunk; 0, or a range of at most this many frames, gives one chunk.
    overlap : int
        Warm-up frames before each boundary after the first.

    Returns
    -------
    list of Chunk
        In frame order; boundaries at ``frames.start + k * chunk_frames``.
    """
    if frames.step != 1 or len(frames) == 0:
        raise ValidationError(f"plan_chunks: frames must be a non-empty step-1 range: {frames}")
    if chunk_frames < 0 or overlap < 0:
        raise ValidationError("plan_chunks: chunk_frames and overlap must be >= 0")
    if chunk_frames == 0 or len(frames) <= chunk_frames:
        return [Chunk(frames.start, frames.start, frames.stop)]
    bounds = [*range(frames.start, frames.stop, chunk_frames), frames.stop]
    return [Chunk(max(frames.start, b - overlap), b, e) for b, e in zip(bounds[:-1], bounds[1:])]


def _rows(store: Trajectories, tracks: np.ndarray, t: np.ndarray | int) -> np.ndarray:
    """Rows of trajectories ``tracks`` at frames ``t`` (which they must cover)."""
    return store.offsets[tracks] + (t - store.first_frame[tracks])


def join_boundary(
    before: Trajectories,
    after: Trajectories,
    boundary: int,
    overlap: int,
    rig: CameraRig,
    tolerance_m: float,
    tolerance_px: float,
    visibility_threshold: float,
) -> tuple[np.ndarray, JoinCount]:
    """Pairs of trajectories of two consecutive chunks that are the same point.

    Parameters
    ----------
    before, after : Trajectories
        The stores of the chunk before the boundary and of the chunk after it (with its
        warm-up frames ``boundary - overlap .. boundary - 1``).
    boundary : int
        The first frame of ``after``'s own frames.
    overlap : int
        Frames both chunks tracked before the boundary.
    rig : CameraRig
        The C cameras of both stores.
    tolerance_m : float
        Largest 3D distance between the two over any common overlap frame.
    tolerance_px : float
        Largest distance between their projections, at ``boundary - 1``, in each camera that
        sees both.
    visibility_threshold : float
        A camera sees a point where its visibility exceeds this.

    Returns
    -------
    pairs : (K, 2) int64 ndarray
        ``(a, b)``: trajectory a of ``before`` continues as trajectory b of ``after``; each a and
        each b at most once, in increasing a.
    count : JoinCount
    """
    t_end = boundary - 1
    A = np.flatnonzero(before.last_frame == t_end)
    B = np.flatnonzero((after.first_frame <= t_end) & (after.last_frame >= boundary))
    none = np.zeros((0, 2), np.int64)
    if overlap < 1 or A.size == 0 or B.size == 0:
        return none, JoinCount(boundary, int(A.size), int(B.size), 0)
    from scipy.spatial import cKDTree

    pa = before.xyz[_rows(before, A, t_end)].astype(np.float64)  # (nA, 3)
    pb = after.xyz[_rows(after, B, t_end)].astype(np.float64)  # (nB, 3)
    k = min(_CANDIDATES, B.size)
    dist, idx = cKDTree(pb).query(pa, k=k, distance_upper_bound=tolerance_m)
    dist, idx = dist.reshape(len(A), k), idx.reshape(len(A), k)
    found = np.isfinite(dist)
    a = A[np.repeat(np.arange(len(A)), k)[found.ravel()]]  # (L,)
    b = B[idx[found]]
    # every overlap frame where both exist
    ts = np.arange(boundary - overlap, boundary)  # (O,)
    lo = np.maximum(np.maximum(before.first_frame[a], after.first_frame[b]), ts[0])
    common = ts[None] >= lo[:, None]  # (L, O); the last column is always True
    ra = np.where(common, _rows(before, a[:, None], ts[None]), 0)
    rb = np.where(common, _rows(after, b[:, None], ts[None]), 0)
    d = np.linalg.norm(before.xyz[ra].astype(np.float64) - after.xyz[rb].astype(np.float64), axis=2)
    d = np.where(common, d, 0.0)
    ok = (d <= tolerance_m).all(axis=1)
    a, b = a[ok], b[ok]
    cost = d[ok].sum(axis=1) / common[ok].sum(axis=1)
    # mutual best on the mean distance (ties broken by position: a strict order)
    rank = np.empty(len(cost), np.int64)
    rank[np.lexsort((np.arange(len(cost)), cost))] = np.arange(len(cost))
    big = np.iinfo(np.int64).max
    best_a = np.full(before.num_trajectories, big)
    best_b = np.full(after.num_trajectories, big)
    np.minimum.at(best_a, a, rank)
    np.minimum.at(best_b, b, rank)
    mutual = (best_a[a] == rank) & (best_b[b] == rank)
    a, b = a[mutual], b[mutual]
    # their projections agree in the cameras that see both at the boundary's last frame
    keep = np.zeros(len(a), bool)
    for s in range(0, len(a), _BATCH):
        sa, sb = a[s : s + _BATCH], b[s : s + _BATCH]
        rows_a, rows_b = _rows(before, sa, t_end), _rows(after, sb, t_end)
        shared = (dequantize_visibility(before.visibility[rows_a]) > visibility_threshold) & (
            dequantize_visibility(after.visibility[rows_b]) > visibility_threshold
        )  # (n, C)
        px_a = rig.project(before.xyz[rows_a].astype(np.float64)).pixels  # (C, n, 2)
        px_b = rig.project(after.xyz[rows_b].astype(np.float64)).pixels
        with np.errstate(invalid="ignore"):
            near = np.linalg.norm(px_a - px_b, axis=2).T <= tolerance_px  # (n, C)
        keep[s : s + _BATCH] = shared.any(axis=1) & (near | ~shared).all(axis=1)
    pairs = np.column_stack([a[keep], b[keep]]).astype(np.int64)
    pairs = pairs[np.argsort(pairs[:, 0], kind="stable")]
    return pairs, JoinCount(boundary, int(A.size), int(B.size), len(pairs))


def merge_chunks(
    stores: list[Trajectories],
    chunks: list[Chunk],
    rig: CameraRig,
    tolerance_m: float,
    tolerance_px: float,
    visibility_threshold: float,
) -> tuple[Trajectories, list[JoinCount]]:
    """One store from the chunks' stores, joined across the boundaries.

    Parameters
    ----------
    stores : list of Trajectories
        One per chunk, each over its chunk's frames (warm-up included), same cameras.
    chunks : list of Chunk
        From :func:`plan_chunks`, consecutive.
    rig, tolerance_m, tolerance_px, visibility_threshold
        See :func:`join_boundary`.

    Returns
    -------
    trajectories : Trajectories
        Frame t's points are those of the chunk that owns t; a joined trajectory is one
        trajectory. Trajectories are numbered in the order of their first chunk, then of their
        index in it.
    counts : list of JoinCount
        One per boundary after the first chunk.
    """
    if len(stores) != len(chunks) or not stores:
        raise ValidationError("merge_chunks: one store per chunk, at least one")
    for prev, ch in zip(chunks[:-1], chunks[1:]):
        if prev.stop != ch.boundary:
            raise ValidationError(f"merge_chunks: chunks {prev.name} and {ch.name} do not meet")
    counts: list[JoinCount] = []
    parts: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []  # (gid, frame, rows) per chunk
    prev_gid = np.zeros(0, np.int64)
    next_id = 0
    for k, (store, ch) in enumerate(zip(stores, chunks)):
        own = np.flatnonzero(store.row_frame >= ch.boundary)  # rows of the chunk's own frames
        has_rows = np.zeros(store.num_trajectories, bool)
        has_rows[store.row_track[own]] = True
        gid = np.full(store.num_trajectories, -1, np.int64)
        if k > 0:
            pairs, count = join_boundary(
                stores[k - 1],
                store,
                ch.boundary,
                ch.boundary - ch.start,
                rig,
                tolerance_m,
                tolerance_px,
                visibility_threshold,
            )
            gid[pairs[:, 1]] = prev_gid[pairs[:, 0]]
            counts.append(count)
        new = np.flatnonzero(has_rows & (gid < 0))
        gid[new] = next_id + np.arange(new.size)
        next_id += new.size
        parts.append((gid[store.row_track[own]], store.row_frame[own], own))
        prev_gid = gid
    track = np.concatenate([p[0] for p in parts])
    frame = np.concatenate([p[1] for p in parts])
    order = np.lexsort((frame, track))

    def gather(field: str) -> np.ndarray:
        return np.concatenate([getattr(s, field)[p[2]] for s, p in zip(stores, parts)])[order]

    n = np.bincount(track, minlength=next_id)
    offsets = np.concatenate([[0], np.cumsum(n)]).astype(np.int64)
    frame_s = frame[order]
    first = frame_s[offsets[:-1]] if next_id else np.zeros(0, np.int64)
    if next_id and np.any(frame_s[offsets[1:] - 1] - first + 1 != n):
        raise ValidationError("merge_chunks: a joined trajectory skips a frame")
    merged = Trajectories(
        first_frame=first.astype(np.int64),
        offsets=offsets,
        xyz=gather("xyz"),
        visibility=gather("visibility"),
        reprojection_error=gather("reprojection_error"),
        color=gather("color"),
        camera_names=list(stores[0].camera_names),
        fps=stores[0].fps,
        num_frames=max(s.num_frames for s in stores),
    )
    for c in counts:
        logger.info(
            "chunk boundary at frame %d: %d of %d trajectories joined across it (%d candidates)",
            c.boundary,
            c.joined,
            c.ending,
            c.candidates,
        )
    return merged, counts
