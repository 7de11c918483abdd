"""Tracking in temporal chunks: the chunk plan, and joining trajectories across boundaries.

A long frame range is cut at fixed boundaries every ``chunk_frames`` frames
(:func:`plan_chunks`). Each chunk is tracked by its own :class:`~.track.Tracker`, as one task of
the executor, starting ``chunk_overlap`` frames before its boundary to warm up: over those
frames both the chunk before and this one have points. The plan depends only on the
configuration and the frame range, so serial and cluster runs track the same chunks and give
the same output.

:func:`merge_chunks` then makes one store of the chunks' stores:

- each frame's tracked points come from one chunk: frames before a boundary from the chunk
  before it, frames from the boundary on from the chunk after it (a chunk's warm-up rows are
  dropped), so the overlap duplicates no point;
- a trajectory of the chunk before that is alive at the boundary's last frame continues as the
  trajectory of the chunk after that is the same physical point (:func:`join_boundary`): the
  two stay within ``chunk_join_m`` over every overlap frame where both exist, their positions
  project within twice ``ransac_threshold_px`` of each other in every camera where both are
  seen at the boundary (at least one), and each is the other's best candidate (mutual best
  match on the mean 3D distance);
- a trajectory of the chunk before that the overlap does not join is carried on over the chunk
  after by the earlier chunk's own tracker, without new points, until it ends (the chunk's
  *tail*, a :class:`Bridge` tracked in the same executor task as the chunk, so that chunks
  stay independent tasks) or meets a trajectory of the chunk after that is the same point at
  two frames in a row (:func:`join_tail`: :func:`match_points`, the criteria above on one
  frame), which continues it from the second frame on: its carried rows stop there, and that
  trajectory's rows before are dropped. A fresh tracker only has the points matched since its
  warm-up began, most of them other surface points than the earlier tracker's (on the demo
  about 90 % of the trajectories alive at a boundary have no counterpart within 5 mm);
  without tails they would all end at the boundary.

The stitching of the whole store (:mod:`~.stitch`) then runs as without chunks.
"""

from __future__ import annotations

import dataclasses
import logging
import os
from dataclasses import dataclass

import numpy as np

from ..atomic import save_npz_atomic
from ..camera import CameraRig
from ..errors import ValidationError
from ..geometry import pixel_distance
from ..npzfile import load_npz
from ..trajectories import Trajectories, dequantize_visibility

__all__ = [
    "Bridge",
    "Chunk",
    "JoinCount",
    "agree_in_shared_cameras",
    "join_boundary",
    "join_tail",
    "match_points",
    "merge_chunks",
    "plan_chunks",
]

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
        Pairs joined into one trajectory over the overlap.
    carried : int
        Trajectories of the chunk before that its tail carried on past the boundary.
    joined_later : int
        Of those, how many joined a trajectory of the chunk after at a later frame.
    """

    boundary: int
    ending: int
    candidates: int
    joined: int
    carried: int = 0
    joined_later: int = 0


@dataclass(frozen=True)
class Bridge:
    """Trajectories of a chunk carried on into the next chunk's frames by its own tracker.

    A chunk's tail: the trajectories alive at its last frame go on being tracked (without new
    points) over the next chunk's frames until they end; :func:`join_tail` then drops those
    that the overlap joined, and joins the rest to the next chunk's trajectories where they
    meet the same point.

    Attributes
    ----------
    ids : (R,) int64 ndarray
        Trajectory of the chunk before, per row.
    frame : (R,) int64 ndarray
    xyz : (R, 3) float32 ndarray
    visibility : (R, C) uint8 ndarray
    error : (R,) float32 ndarray
    color : (R, 3) uint8 ndarray
    joins : (J, 3) int64 ndarray
        ``(a, b, t)``: trajectory a of the chunk before continues as trajectory b of the chunk
        after from frame t on (b's rows before t are dropped: a's carried rows stand for
        them). Empty in a tail as tracked.
    """

    ids: np.ndarray
    frame: np.ndarray
    xyz: np.ndarray
    visibility: np.ndarray
    error: np.ndarray
    color: np.ndarray
    joins: np.ndarray

    def save(self, path: str | os.PathLike) -> None:
        """Write it atomically as an npz."""
        save_npz_atomic(path, **dataclasses.asdict(self))

    @classmethod
    def load(cls, path: str | os.PathLike) -> Bridge:
        """Read what :meth:`save` wrote."""
        fields = [f.name for f in dataclasses.fields(cls)]
        d = load_npz(path, fields, "a chunk tail")
        return cls(**{k: d[k] for k in fields})


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
    i, j, _ = _near_pairs(
        before.xyz[_rows(before, A, t_end)], after.xyz[_rows(after, B, t_end)], tolerance_m
    )
    a, b = A[i], B[j]  # (L,)
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
    mutual = _mutual_best(a, b, cost, before.num_trajectories, after.num_trajectories)
    a, b = a[mutual], b[mutual]
    rows_a, rows_b = _rows(before, a, t_end), _rows(after, b, t_end)
    keep = agree_in_shared_cameras(
        before.xyz[rows_a],
        before.visibility[rows_a],
        after.xyz[rows_b],
        after.visibility[rows_b],
        rig,
        tolerance_px,
        visibility_threshold,
    )
    pairs = np.column_stack([a[keep], b[keep]]).astype(np.int64)
    pairs = pairs[np.argsort(pairs[:, 0], kind="stable")]
    return pairs, JoinCount(boundary, int(A.size), int(B.size), len(pairs))


def _near_pairs(
    xyz_a: np.ndarray, xyz_b: np.ndarray, tolerance_m: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Candidate pairs: each point of a with its nearest ``_CANDIDATES`` points of b within
    ``tolerance_m``.

    Parameters
    ----------
    xyz_a : (nA, 3) float ndarray
    xyz_b : (nB, 3) float ndarray, nB >= 1
    tolerance_m : float

    Returns
    -------
    i, j : (L,) int ndarray
        Indices into a and b, by increasing i.
    dist : (L,) float ndarray
    """
    from scipy.spatial import cKDTree

    k = min(_CANDIDATES, len(xyz_b))
    dist, idx = cKDTree(np.asarray(xyz_b, np.float64)).query(
        np.asarray(xyz_a, np.float64), k=k, distance_upper_bound=tolerance_m
    )
    dist, idx = dist.reshape(len(xyz_a), k), idx.reshape(len(xyz_a), k)
    found = np.isfinite(dist)
    return np.repeat(np.arange(len(xyz_a)), k)[found.ravel()], idx[found], dist[found]


def _mutual_best(a: np.ndarray, b: np.ndarray, cost: np.ndarray, Ma: int, Mb: int) -> np.ndarray:
    """(L,) bool: candidate pairs (a, b) that are the cheapest of both their a and their b
    (ties broken by position, a strict order)."""
    rank = np.empty(len(cost), np.int64)
    rank[np.lexsort((np.arange(len(cost)), cost))] = np.arange(len(cost))
    big = np.iinfo(np.int64).max
    best_a = np.full(Ma, big)
    best_b = np.full(Mb, big)
    np.minimum.at(best_a, a, rank)
    np.minimum.at(best_b, b, rank)
    return (best_a[a] == rank) & (best_b[b] == rank)


def agree_in_shared_cameras(
    xyz_a: np.ndarray,
    vis_a: np.ndarray,
    xyz_b: np.ndarray,
    vis_b: np.ndarray,
    rig: CameraRig,
    tolerance_px: float,
    visibility_threshold: float,
) -> np.ndarray:
    """Whether pairs of points are seen by a common camera and project close in all of them.

    Parameters
    ----------
    xyz_a, xyz_b : (n, 3) float ndarray
    vis_a, vis_b : (n, C) uint8 ndarray
        Quantised visibilities.
    rig : CameraRig
    tolerance_px : float
    visibility_threshold : float

    Returns
    -------
    (n,) bool ndarray
    """
    keep = np.zeros(len(xyz_a), bool)
    for s in range(0, len(xyz_a), _BATCH):
        sl = slice(s, s + _BATCH)
        shared = (dequantize_visibility(vis_a[sl]) > visibility_threshold) & (
            dequantize_visibility(vis_b[sl]) > visibility_threshold
        )  # (n, C)
        px_a = rig.project(np.asarray(xyz_a[sl], np.float64)).pixels  # (C, n, 2)
        px_b = rig.project(np.asarray(xyz_b[sl], np.float64)).pixels
        with np.errstate(invalid="ignore"):
            near = pixel_distance(px_a, px_b).T <= tolerance_px  # (n, C)
        keep[sl] = shared.any(axis=1) & (near | ~shared).all(axis=1)
    return keep


def match_points(
    xyz_a: np.ndarray,
    vis_a: np.ndarray,
    xyz_b: np.ndarray,
    vis_b: np.ndarray,
    rig: CameraRig,
    tolerance_m: float,
    tolerance_px: float,
    visibility_threshold: float,
) -> np.ndarray:
    """Points of one frame from two sources that are the same point (the criteria of
    :func:`join_boundary` on a single frame).

    Parameters
    ----------
    xyz_a : (nA, 3) float ndarray
    vis_a : (nA, C) uint8 ndarray
    xyz_b : (nB, 3) float ndarray
    vis_b : (nB, C) uint8 ndarray
    rig, tolerance_m, tolerance_px, visibility_threshold
        See :func:`join_boundary`.

    Returns
    -------
    (K, 2) int64 ndarray
        Index pairs ``(i, j)`` into a and b, mutual best within ``tolerance_m``, in increasing i.
    """
    if len(xyz_a) == 0 or len(xyz_b) == 0:
        return np.zeros((0, 2), np.int64)
    i, j, dist = _near_pairs(xyz_a, xyz_b, tolerance_m)
    mutual = _mutual_best(i, j, dist, len(xyz_a), len(xyz_b))
    i, j = i[mutual], j[mutual]
    ok = agree_in_shared_cameras(
        xyz_a[i], vis_a[i], xyz_b[j], vis_b[j], rig, tolerance_px, visibility_threshold
    )
    pairs = np.column_stack([i[ok], j[ok]]).astype(np.int64)
    return pairs[np.argsort(pairs[:, 0], kind="stable")]


def _rows_in(pairs: np.ndarray, other: np.ndarray) -> np.ndarray:
    """(n,) bool: which rows of the (n, 2) int array ``pairs`` are rows of ``other``."""
    if len(pairs) == 0 or len(other) == 0:
        return np.zeros(len(pairs), bool)
    key = np.int64(max(int(pairs[:, 1].max()), int(other[:, 1].max())) + 1)
    return np.isin(pairs[:, 0] * key + pairs[:, 1], other[:, 0] * key + other[:, 1])


def join_tail(
    tail: Bridge,
    after: Trajectories,
    skip: np.ndarray,
    taken: np.ndarray,
    rig: CameraRig,
    tolerance_m: float,
    tolerance_px: float,
    visibility_threshold: float,
) -> Bridge:
    """Join a chunk's tail (its trajectories carried on over the next chunk) to the next chunk.

    Frame by frame from the boundary, a carried trajectory and a trajectory of the next chunk
    that are the same point (:func:`match_points`) at two frames in a row are joined at the
    second: the carried rows stop there, and the next chunk's trajectory continues it.

    Parameters
    ----------
    tail : Bridge
        The carried rows, without joins.
    after : Trajectories
        The next chunk's store.
    skip : (K,) int ndarray
        Trajectories already joined over the overlap: their rows are dropped.
    taken : (K,) int ndarray
        The next chunk's trajectories they joined: not joined again.
    rig, tolerance_m, tolerance_px, visibility_threshold
        See :func:`join_boundary`.

    Returns
    -------
    Bridge
        The rows kept, and ``joins`` ``(a, b, t)``.
    """
    keep = ~np.isin(tail.ids, skip)
    ids, frame = tail.ids[keep], tail.frame[keep]
    xyz, vis = tail.xyz[keep], tail.visibility[keep]
    free = np.ones(after.num_trajectories, bool)
    free[np.asarray(taken, np.int64)] = False
    ends = np.full(int(ids.max()) + 1 if ids.size else 0, np.iinfo(np.int64).max)
    previous = np.zeros((0, 2), np.int64)  # the pairs that matched at the frame before
    joins = []
    for t in np.unique(frame):
        sel = np.flatnonzero((frame == t) & (ends[ids] > t))
        cand = after.frame_rows(int(t))
        cand = cand[free[after.row_track[cand]]]
        pairs = match_points(
            xyz[sel], vis[sel], after.xyz[cand], after.visibility[cand], rig,
            tolerance_m, tolerance_px, visibility_threshold,
        )  # fmt: skip
        matched = np.column_stack([ids[sel[pairs[:, 0]]], after.row_track[cand[pairs[:, 1]]]])
        again = _rows_in(matched, previous)
        previous = matched
        a, b = matched[again, 0], matched[again, 1]
        free[b] = False
        ends[a] = t
        joins.append(np.column_stack([a, b, np.full(len(a), t)]))
    rows = np.flatnonzero(keep)[frame < ends[ids]] if ids.size else np.zeros(0, np.int64)
    return Bridge(
        ids=tail.ids[rows],
        frame=tail.frame[rows],
        xyz=tail.xyz[rows],
        visibility=tail.visibility[rows],
        error=tail.error[rows],
        color=tail.color[rows],
        joins=np.concatenate(joins).astype(np.int64) if joins else np.zeros((0, 3), np.int64),
    )


def merge_chunks(
    stores: list[Trajectories],
    chunks: list[Chunk],
    rig: CameraRig,
    tolerance_m: float,
    tolerance_px: float,
    visibility_threshold: float,
    tails: list[Bridge | None] | None = None,
    *,
    resolve: bool = True,
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
    tails : list of Bridge or None, optional
        One per boundary (``len(chunks) - 1``): the chunk before it carried on over the
        chunk after it.
    resolve : bool
        The tails are as tracked, without joins: join them (:func:`join_tail`). False: take
        their rows and joins as they are.

    Returns
    -------
    trajectories : Trajectories
        Frame t's points are those of the chunk that owns t, and those the tail before it carries; a
        joined trajectory is one trajectory. Trajectories are numbered in the order of their
        first chunk, then of their index in it.
    counts : list of JoinCount
        One per boundary.
    """
    if len(stores) != len(chunks) or not stores:
        raise ValidationError("merge_chunks: one store per chunk, at least one")
    tails = tails if tails is not None else [None] * (len(chunks) - 1)
    if len(tails) != len(chunks) - 1:
        raise ValidationError("merge_chunks: one tail (or None) per boundary")
    for prev, ch in zip(chunks[:-1], chunks[1:]):
        if prev.stop != ch.boundary:
            raise ValidationError(f"merge_chunks: chunks {prev.name} and {ch.name} do not meet")
    tol = (tolerance_m, tolerance_px, visibility_threshold)
    counts: list[JoinCount] = []
    parts: list[tuple[np.ndarray, ...]] = []  # (gid, frame, xyz, visibility, error, color)
    prev_gid = np.zeros(0, np.int64)
    next_id = 0
    for k, (store, ch) in enumerate(zip(stores, chunks)):
        gid = np.full(store.num_trajectories, -1, np.int64)
        cut = np.full(store.num_trajectories, ch.boundary, np.int64)  # first frame kept
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
            br = tails[k - 1]
            if br is not None and resolve:
                br = join_tail(br, store, pairs[:, 0], pairs[:, 1], rig, *tol)
            if br is not None:
                a, b, t = br.joins.T if len(br.joins) else (np.zeros(0, np.int64),) * 3
                if (
                    np.any(gid[b] >= 0)
                    or np.any(np.isin(a, pairs[:, 0]))
                    or np.unique(a).size < a.size
                    or np.unique(b).size < b.size
                ):
                    raise ValidationError(
                        f"merge_chunks: the tail into {ch.name} joins a trajectory twice"
                    )
                gid[b] = prev_gid[a]
                cut[b] = t
                parts.append(
                    (prev_gid[br.ids], br.frame, br.xyz, br.visibility, br.error, br.color)
                )
                count = dataclasses.replace(
                    count, carried=int(np.unique(br.ids).size), joined_later=len(a)
                )
            counts.append(count)
        own = np.flatnonzero(store.row_frame >= cut[store.row_track])
        has_rows = np.zeros(store.num_trajectories, bool)
        has_rows[store.row_track[own]] = True
        new = np.flatnonzero(has_rows & (gid < 0))
        gid[new] = next_id + np.arange(new.size)
        next_id += new.size
        parts.append(
            (
                gid[store.row_track[own]],
                store.row_frame[own],
                store.xyz[own],
                store.visibility[own],
                store.reprojection_error[own],
                store.color[own],
            )
        )
        prev_gid = gid
    track = np.concatenate([p[0] for p in parts])
    frame = np.concatenate([p[1] for p in parts])
    order = np.lexsort((frame, track))
    n = np.bincount(track, minlength=next_id)
    offsets = np.concatenate([[0], np.cumsum(n)]).astype(np.int64)
    frame_s = frame[order]
    first = frame_s[offsets[:-1]] if next_id else np.zeros(0, np.int64)
    if next_id and np.any(frame_s[offsets[1:] - 1] - first + 1 != n):
        raise ValidationError("merge_chunks: a joined trajectory skips or repeats a frame")
    merged = Trajectories(
        first_frame=first.astype(np.int64),
        offsets=offsets,
        xyz=np.concatenate([p[2] for p in parts])[order],
        visibility=np.concatenate([p[3] for p in parts])[order],
        reprojection_error=np.concatenate([p[4] for p in parts])[order],
        color=np.concatenate([p[5] for p in parts])[order],
        camera_names=list(stores[0].camera_names),
        fps=stores[0].fps,
        num_frames=max(s.num_frames for s in stores),
    )
    for c in counts:
        logger.info(
            "chunk boundary at frame %d: %d of %d trajectories joined across it over the "
            "overlap (%d candidates); %d carried on past it, %d of them joined later",
            c.boundary,
            c.joined,
            c.ending,
            c.candidates,
            c.carried,
            c.joined_later,
        )
    return merged, counts
