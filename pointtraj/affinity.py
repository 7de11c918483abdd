"""Trajectory affinity from local rigid motion (the paper's Section 4.2).

Pipeline of :func:`compute_affinity`:

1. **ε-neighbours** ``N_i`` (default ε = 5 cm): trajectories j whose distance to i stays below ε at
   every frame of the shared lifetime ``S = [T_e^i, T_d^i] ∩ [T_e^j, T_d^j]`` (``|S| >= 2``).
2. **Local rigid transforms** ``(R_t^i, t_t^i)`` per trajectory i and frame t (t - 1 also alive),
   fitted by RANSAC over 3-trajectory samples {i, j, k} (j, k ∈ N_i) and refitted on the inliers
   with Kabsch (proper rotation, det sign fix). The transform is anchored at i:
   ``t_t^i = X_t^i - R_t^i X_{t-1}^i``.
3. **Candidate pairs** within ε_a (default 30 cm; distance below ε_a at every shared frame,
   ``|S| >= 2``): the ``near_neighbors`` nearest trajectories at i's middle frame, plus the
   paper's random drop-out: ``max_neighbors`` points uniform in the ε_a-ball around i snapped to
   their nearest trajectory (density independent, so a dense patch does not dominate).
4. **Affinity** ``A(i, j) = exp(-(e_ij / τ)^2)``, ``e_ij`` the largest error over the shared
   lifetime of predicting j with i's transforms: from j's position at the first shared frame by
   composing the transforms (``mode="accumulated"``, the paper's text, the default) or one step at
   a time, ``‖X_t^j - R_t^i X_{t-1}^j - t_t^i‖`` (``mode="step"``, the paper's formula).
   Symmetrised as the mean of the available directions. A pair for which neither trajectory has a
   transform cannot be tested and gets ``missing_affinity``.
5. **Edge weight** ``w(i, j) = A(i, j) · exp(-(d_ij / distance_scale)^2)``, ``d_ij`` the largest
   distance over S. The paper's graph is ``distance_scale = 0`` (no kernel).

Why the spatial kernel and the near neighbours (``docs/labeling.md`` has the measurements): the
SE(3) affinity measures rigidity, and distinct labels are often rigidly attached over a whole
clip (a hand on a still wrist, a foot on a locked ankle, points on both sides of any joint close
to its axis). With only uniform draws in a 30 cm ball, a small part's edges mostly reach the
rigidly attached neighbour part with ``A ≈ 1``; the Potts term then outweighs the part's data
evidence and the graph cut relabels the whole part (the hands fell from 50 % to 10 % correct on
the 8-camera demo). The kernel turns the smoothness into a boundary term (its cost grows with the
contact area between two labels, the data evidence with their volume), and the near neighbours
give the kernel edges to weight. The SE(3) affinity keeps its role: it removes the edges between
parts that move differently (ball and hand, the two feet), which a plain distance kernel keeps.

Candidate search uses scipy's ``cKDTree`` (see ``benchmarks/bench_graph.py`` for the measured
comparison with Open3D's ``NearestNeighborSearch``).
"""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from .atomic import save_npz_atomic
from .errors import FileFormatError, ValidationError, check_array
from .executor import Executor, SerialExecutor
from .geometry import fit_rigid, rotation_from_triads, squared_norm
from .scale import SceneLength
from .trajectories import Trajectories

__all__ = [
    "AffinityConfig",
    "AffinityGraph",
    "LocalTransforms",
    "compute_affinity",
    "sample_neighbors",
    "nearest_neighbors",
    "candidate_pairs",
    "find_all_pairs",
    "pair_max_distance",
    "filter_neighbors",
    "fit_local_rigid",
    "local_transforms",
    "view_breaks",
    "pair_errors",
    "both_pair_errors",
    "symmetric_affinity",
    "save_affinity",
    "load_affinity",
]

logger = logging.getLogger(__name__)

FORMAT_VERSION = 1
#: Pair-frames processed per chunk when gathering shared lifetimes (bounds peak memory).
_CHUNK_ROWS = 2_000_000


@dataclass(frozen=True)
class AffinityConfig:
    """Parameters of the affinity stage (paper Section 4.2; additions documented in
    ``data_specs/affinity.md`` and measured in ``docs/labeling.md``).

    Attributes
    ----------
    epsilon : float
        ε, radius of the ε-neighbourhood used to fit local transforms (m). Paper: 5 cm.
    epsilon_a : float
        ε_a, radius within which affinities are evaluated (m). Paper: 30 cm.
    tau : float
        τ of ``A = exp(-(e/τ)^2)`` (m). Default 5 mm: the residual of a pair on one rigid part is
        ~0 on ground truth and 1-3 mm (median) on reconstructed trajectories, while neighbouring
        body parts move only 2-20 mm per frame relative to each other; 2 cm gave ``A ≈ 1`` to
        nearly every pair, and 2 mm cut most same-part pairs once positions carry 0.5 mm of
        noise (graph-cut accuracy on ring8 ground truth with 0.5 mm noise: 81.9 % at 5 mm,
        78.3 % at 2 mm; on the demo's reconstructed trajectories 84.3 % and 83.8 %;
        ``docs/labeling.md``).
    near_neighbors : int
        Nearest trajectories (at i's middle frame, within ε_a) taken as candidates per
        trajectory; 0 for the paper's drop-out draws only.
    rigid_neighbors : int
        ε-neighbour candidates drawn per trajectory for RANSAC.
    max_neighbors : int
        ε_a-neighbour candidates drawn uniformly in the ε_a-ball per trajectory: the paper's
        random drop-out of connections; 0 for the near neighbours only.
    distance_scale : float
        Scale σ_d (m) of the spatial kernel ``exp(-(d/σ_d)^2)`` multiplying the affinity in the
        edge weight; 0 disables it (the paper's graph). Default 10 cm.
    missing_affinity : float
        A of a pair that cannot be tested because neither trajectory has a local transform over
        the shared lifetime (too few ε-neighbours, e.g. short or isolated trajectories): 1 keeps
        the spatial prior alone (the rigidity test can only remove an edge), 0 drops the pair.
    ransac_iterations : int
        RANSAC hypotheses per trajectory and frame.
    ransac_threshold : float
        Inlier threshold on the displacement residual ``‖ΔX_t - R ΔX_{t-1}‖`` (m).
    min_inliers : int
        Fewest inliers (besides i) for a transform; fewer gives no transform at that frame.
    mode : {"accumulated", "step"}
        Prediction composed from the emerging location in S (the paper's text; the default, it
        separates parts better: the relative motion of two parts accumulates over the lifetime
        while a per-step residual sees one frame's worth), or the per-step residual.
    symmetrize : {"mean", "max", "min"}
        How ``A(i, j)`` and ``A(j, i)`` combine (only available directions count).
    min_affinity : float
        Edges whose weight (affinity times kernel) is smaller are dropped (they change almost no
        labelling and cost time in the graph cut); 0 keeps every candidate pair.
    view_breaks : bool
        Treat a step at which a trajectory's set of observing cameras changes as a break
        (:func:`view_breaks`): its re-triangulated position jumps there, which the rigidity
        test would read as motion. Off by default (the paper's test over every step): on the
        demo's reconstruction it doubles the weighted degree but leaves the cross-part share
        of the weight where it was and lowers the cut's accuracy, and on ground-truth
        trajectories, whose positions never jump, it only removes evidence
        (``docs/labeling.md``).
    seed : int
        Seed of the drop-out and RANSAC sampling.
    """

    epsilon: float = SceneLength(0.05)
    epsilon_a: float = SceneLength(0.30)
    tau: float = SceneLength(0.005)
    near_neighbors: int = 8
    rigid_neighbors: int = 12
    max_neighbors: int = 8
    distance_scale: float = SceneLength(0.10)
    missing_affinity: float = 1.0
    ransac_iterations: int = 8
    ransac_threshold: float = SceneLength(0.01)
    min_inliers: int = 2
    mode: Literal["step", "accumulated"] = "accumulated"
    symmetrize: Literal["mean", "max", "min"] = "mean"
    min_affinity: float = 1e-3
    view_breaks: bool = False
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("epsilon", "epsilon_a", "tau", "ransac_threshold"):
            if not getattr(self, name) > 0:
                raise ValidationError(f"AffinityConfig.{name} must be > 0")
        for name in ("rigid_neighbors", "ransac_iterations"):
            if getattr(self, name) < 1:
                raise ValidationError(f"AffinityConfig.{name} must be >= 1")
        for name in ("near_neighbors", "max_neighbors"):
            if getattr(self, name) < 0:
                raise ValidationError(f"AffinityConfig.{name} must be >= 0")
        if self.near_neighbors + self.max_neighbors < 1:
            raise ValidationError(
                "AffinityConfig: near_neighbors + max_neighbors must be >= 1 (no candidate pairs)"
            )
        if not self.distance_scale >= 0:
            raise ValidationError("AffinityConfig.distance_scale must be >= 0 (0 = no kernel)")
        if not 0.0 <= self.missing_affinity <= 1.0:
            raise ValidationError("AffinityConfig.missing_affinity must be in [0, 1]")
        if not self.min_affinity >= 0:
            raise ValidationError("AffinityConfig.min_affinity must be >= 0")
        if self.mode not in ("step", "accumulated"):
            raise ValidationError(
                f"AffinityConfig.mode must be 'step' or 'accumulated', got {self.mode!r}"
            )
        if self.symmetrize not in ("mean", "max", "min"):
            raise ValidationError(
                f"AffinityConfig.symmetrize must be 'mean', 'max' or 'min', got {self.symmetrize!r}"
            )


@dataclass
class AffinityGraph:
    """A sparse symmetric weighted graph over trajectories, stored as its upper triangle.

    Attributes
    ----------
    row, col : (E,) int64 ndarray
        Edge endpoints, ``row < col``, unique.
    weight : (E,) float32 ndarray
        Edge weight in [0, 1] used by the labelling: ``A(row, col)`` times the spatial kernel
        (``AffinityConfig.distance_scale``; without it, the paper's ``A``).
    num_nodes : int
        M.
    params : dict
        The :class:`AffinityConfig` used, as a dict.
    affinity : (E,) float32 ndarray, optional
        The paper's ``A(row, col)`` alone (``missing_affinity`` for untestable pairs).
    distance : (E,) float32 ndarray, optional
        Largest distance of the pair over the shared lifetime (m).
    """

    row: np.ndarray
    col: np.ndarray
    weight: np.ndarray
    num_nodes: int
    params: dict
    affinity: np.ndarray | None = None
    distance: np.ndarray | None = None

    @property
    def num_edges(self) -> int:
        """E."""
        return int(self.row.shape[0])

    def to_sparse(self):
        """The symmetric (M, M) ``scipy.sparse.csr_array`` of the weights."""
        from scipy import sparse

        r = np.concatenate([self.row, self.col])
        c = np.concatenate([self.col, self.row])
        w = np.concatenate([self.weight, self.weight])
        return sparse.csr_array((w, (r, c)), shape=(self.num_nodes, self.num_nodes))


@dataclass
class LocalTransforms:
    """Per point-frame local rigid transforms ``X_t ≈ R (X_{t-1} - X_{t-1}^i) + X_t^i``.

    Attributes
    ----------
    rotation : (P, 3, 3) float32 ndarray
        ``R_t^i`` at the row of trajectory i at frame t; NaN at a trajectory's first frame and
        where too few ε-neighbours were alive.
    inliers : (P,) int16 ndarray
        RANSAC inliers (ε-neighbours) of the refitted transform; -1 where there is none.
    breaks : (P,) bool ndarray, optional
        Point-frames whose step from the previous frame is not motion (:func:`view_breaks`):
        they get no transform, enter no fit as neighbours, and pair errors restart there.
        None: no breaks.
    """

    rotation: np.ndarray
    inliers: np.ndarray
    breaks: np.ndarray | None = None

    def translation(self, traj: Trajectories) -> np.ndarray:
        """(P, 3) float32 ``t_t^i = X_t^i - R_t^i X_{t-1}^i`` (NaN where undefined)."""
        prev = np.arange(traj.num_point_frames) - 1
        prev[traj.offsets[:-1]] = 0
        out = traj.xyz - (self.rotation @ traj.xyz[prev][:, :, None])[:, :, 0]
        out[traj.offsets[:-1]] = np.nan
        return out.astype(np.float32)


# -- neighbours --------------------------------------------------------------------------------
def _middle_frames(traj: Trajectories) -> np.ndarray:
    return traj.first_frame + (traj.lengths - 1) // 2


def _rows_at(traj: Trajectories, tracks: np.ndarray, frames: np.ndarray) -> np.ndarray:
    """Rows of ``tracks`` at ``frames`` (caller guarantees they are alive)."""
    return traj.offsets[tracks] + (frames - traj.first_frame[tracks])


#: Point-frames per chunk of :func:`view_breaks` (bounds the (rows, C) comparison).
_BREAK_ROWS = 1_000_000


def view_breaks(traj: Trajectories) -> np.ndarray:
    """Point-frames whose set of observing cameras differs from the trajectory's previous frame.

    A reconstructed point is triangulated from the cameras that observe it; when that set
    changes, its position jumps by the difference between the two estimates (a few mm, up to
    2 cm for two-view points), which is not motion. The affinity treats such a step as a break.

    Parameters
    ----------
    traj : Trajectories

    Returns
    -------
    (P,) bool ndarray
        True at a row whose observed views (visibility >= ``trajectories.OBSERVED_MIN``) differ
        from the previous row's of the same trajectory; False at each trajectory's first row.
    """
    from .trajectories import OBSERVED_MIN

    P = traj.num_point_frames
    out = np.zeros(P, dtype=bool)
    for a in range(1, P, _BREAK_ROWS):
        b = min(a + _BREAK_ROWS, P)
        obs = traj.visibility[a - 1 : b] >= OBSERVED_MIN  # (b - a + 1, C)
        out[a:b] = np.any(obs[1:] != obs[:-1], axis=1)
    out[traj.offsets[:-1]] = False
    return out


def sample_neighbors(
    traj: Trajectories, radius: float, num_samples: int, rng: np.random.Generator
) -> np.ndarray:
    """Draw random neighbour candidates within ``radius``, density-independently.

    For each trajectory i at its middle frame t_i, ``num_samples`` points uniform in the ball of
    ``radius`` around ``X_{t_i}^i`` are snapped to the nearest point alive at t_i (a
    ``cKDTree`` per frame); hits farther than ``radius`` from i, i itself and repeats are dropped.

    Parameters
    ----------
    traj : Trajectories
    radius : float
        Ball radius (m).
    num_samples : int
        Draws per trajectory.
    rng : numpy.random.Generator

    Returns
    -------
    (M, num_samples) int64 ndarray
        Candidate neighbours per trajectory, -1 for empty slots (valid ones first).
    """
    from scipy.spatial import cKDTree

    M = traj.num_trajectories
    out = np.full((M, num_samples), -1, dtype=np.int64)
    if M == 0:
        return out
    mid = _middle_frames(traj)
    order = np.argsort(mid, kind="stable")
    bounds = np.searchsorted(mid[order], np.arange(traj.num_frames + 1))
    for t in range(traj.num_frames):
        q = order[bounds[t] : bounds[t + 1]]  # trajectories queried at frame t
        if q.size == 0:
            continue
        rows = traj.frame_rows(t)
        pts = traj.xyz[rows].astype(np.float64)
        tree = cKDTree(pts)
        centre = traj.xyz[_rows_at(traj, q, np.full(q.size, t))].astype(np.float64)  # (Q, 3)
        d = rng.normal(size=(q.size, num_samples, 3))
        d /= np.linalg.norm(d, axis=2, keepdims=True) + 1e-12
        d *= radius * rng.random((q.size, num_samples, 1)) ** (1.0 / 3.0)
        target = centre[:, None, :] + d  # (Q, S, 3)
        _, idx = tree.query(target.reshape(-1, 3), k=1, workers=-1)
        hit = traj.row_track[rows[idx]].reshape(q.size, num_samples)  # (Q, S)
        dist = np.linalg.norm(pts[idx].reshape(q.size, num_samples, 3) - centre[:, None], axis=2)
        hit[(dist >= radius) | (hit == q[:, None])] = -1
        out[q] = hit
    # drop repeats within a row, valid entries first
    out.sort(axis=1)
    dup = np.zeros_like(out, dtype=bool)
    dup[:, 1:] = out[:, 1:] == out[:, :-1]
    out[dup] = -1
    out = -np.sort(-out, axis=1)
    return out


def nearest_neighbors(traj: Trajectories, radius: float, k: int) -> np.ndarray:
    """The ``k`` nearest trajectories of each trajectory at its middle frame, within ``radius``.

    One ``cKDTree`` per frame over the points alive there, queried by the trajectories whose
    middle frame it is (``distance_upper_bound = radius``).

    Parameters
    ----------
    traj : Trajectories
    radius : float
        Largest distance (m) at the middle frame.
    k : int
        Neighbours per trajectory.

    Returns
    -------
    (M, k) int64 ndarray
        Neighbours, nearest first, -1 for empty slots.
    """
    from scipy.spatial import cKDTree

    M = traj.num_trajectories
    out = np.full((M, k), -1, dtype=np.int64)
    if M == 0 or k == 0:
        return out
    mid = _middle_frames(traj)
    order = np.argsort(mid, kind="stable")
    bounds = np.searchsorted(mid[order], np.arange(traj.num_frames + 1))
    for t in range(traj.num_frames):
        q = order[bounds[t] : bounds[t + 1]]
        if q.size == 0:
            continue
        rows = traj.frame_rows(t)
        tree = cKDTree(traj.xyz[rows].astype(np.float64))
        centre = traj.xyz[_rows_at(traj, q, np.full(q.size, t))].astype(np.float64)
        kk = min(k + 1, rows.size)
        dist, idx = tree.query(centre, k=kk, distance_upper_bound=radius, workers=-1)
        dist, idx = dist.reshape(q.size, kk), idx.reshape(q.size, kk)
        found = np.isfinite(dist)
        hit = np.where(found, traj.row_track[rows[np.where(found, idx, 0)]], -1)
        hit[hit == q[:, None]] = -1
        # drop self (usually the first column) and keep the nearest k, order preserved
        keep = np.argsort(hit < 0, axis=1, kind="stable")[:, :k]
        out[q, : keep.shape[1]] = np.take_along_axis(hit, keep, axis=1)
    return out


def candidate_pairs(
    traj: Trajectories,
    radius: float,
    near: int,
    draws: int,
    rng: np.random.Generator,
    min_shared: int = 2,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unique undirected candidate pairs within ``radius`` over their shared lifetime.

    The union of :func:`nearest_neighbors` (``near`` per trajectory) and
    :func:`sample_neighbors` (``draws`` per trajectory, the paper's drop-out), each pair once,
    kept where the distance stays below ``radius`` over at least ``min_shared`` shared frames.

    Returns
    -------
    i, j : (Q,) int64 ndarray
        Pairs with ``i < j``, sorted.
    distance : (Q,) float64 ndarray
        Largest distance over the shared lifetime (m).
    """
    M = traj.num_trajectories
    parts = []
    if near > 0:
        parts.append(nearest_neighbors(traj, radius, near))
    if draws > 0:
        parts.append(sample_neighbors(traj, radius, draws, rng))
    nb = np.concatenate(parts, axis=1) if parts else np.full((M, 0), -1, np.int64)
    src = np.repeat(np.arange(M, dtype=np.int64), nb.shape[1])
    dst = nb.ravel()
    ok = dst >= 0
    src, dst = src[ok], dst[ok]
    key = np.unique(np.minimum(src, dst) * M + np.maximum(src, dst))
    i, j = key // M, key % M
    dmax, shared = pair_max_distance(traj, i, j)
    keep = (dmax < radius) & (shared >= min_shared)
    return i[keep], j[keep], dmax[keep]


def find_all_pairs(traj: Trajectories, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """All pairs closer than ``radius`` at the first frame of their shared lifetime (exact).

    Every pair whose distance stays below ``radius`` over the shared lifetime is among them; use
    :func:`filter_neighbors` to apply the full criterion. One ``cKDTree.query_pairs`` per frame
    where some trajectory emerges, keeping pairs with one end emerging there.

    Returns
    -------
    i, j : (Q,) int64 ndarray
        Unique pairs with ``i < j``.
    """
    from scipy.spatial import cKDTree

    parts_i, parts_j = [], []
    emerging = np.zeros(traj.num_frames, dtype=bool)
    emerging[traj.first_frame] = True
    for t in np.flatnonzero(emerging):
        rows = traj.frame_rows(int(t))
        tree = cKDTree(traj.xyz[rows].astype(np.float64))
        pairs = tree.query_pairs(radius, output_type="ndarray")  # (Q, 2)
        a = traj.row_track[rows[pairs[:, 0]]]
        b = traj.row_track[rows[pairs[:, 1]]]
        keep = np.maximum(traj.first_frame[a], traj.first_frame[b]) == t
        parts_i.append(np.minimum(a, b)[keep])
        parts_j.append(np.maximum(a, b)[keep])
    if not parts_i:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    return np.concatenate(parts_i), np.concatenate(parts_j)


def _shared_chunks(traj: Trajectories, i: np.ndarray, j: np.ndarray):
    """Yield (pair index, row of i, row of j) per shared frame, in chunks of whole pairs."""
    s0 = np.maximum(traj.first_frame[i], traj.first_frame[j])
    s1 = np.minimum(traj.last_frame[i], traj.last_frame[j])
    n = np.maximum(s1 - s0 + 1, 0)
    cum = np.concatenate([[0], np.cumsum(n)])
    start = 0
    Q = i.shape[0]
    while start < Q:
        stop = int(np.searchsorted(cum, cum[start] + _CHUNK_ROWS, side="right")) - 1
        stop = min(max(stop, start + 1), Q)
        nn = n[start:stop]
        pid = np.repeat(np.arange(start, stop), nn)  # (R,)
        local = np.arange(pid.size) - np.repeat(cum[start:stop] - cum[start], nn)
        t = s0[pid] + local
        ri = traj.offsets[i[pid]] + t - traj.first_frame[i[pid]]
        rj = traj.offsets[j[pid]] + t - traj.first_frame[j[pid]]
        yield pid, ri, rj
        start = stop


def pair_max_distance(
    traj: Trajectories, i: np.ndarray, j: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Largest distance over the shared lifetime of each pair.

    Parameters
    ----------
    traj : Trajectories
    i, j : (Q,) int ndarray
        Trajectory pairs.

    Returns
    -------
    max_distance : (Q,) float64 ndarray
        ``max_{t ∈ S} ‖X_t^j - X_t^i‖`` (inf where S is empty).
    shared : (Q,) int64 ndarray
        ``|S|``.
    """
    i = np.asarray(i, np.int64)
    j = np.asarray(j, np.int64)
    out = np.full(i.shape[0], np.inf)
    shared = np.maximum(
        np.minimum(traj.last_frame[i], traj.last_frame[j])
        - np.maximum(traj.first_frame[i], traj.first_frame[j])
        + 1,
        0,
    )
    for pid, ri, rj in _shared_chunks(traj, i, j):
        if pid.size == 0:
            continue
        d = np.linalg.norm(traj.xyz[ri] - traj.xyz[rj], axis=1)
        starts = np.flatnonzero(np.r_[True, pid[1:] != pid[:-1]])
        vals = np.maximum.reduceat(d, starts)
        out[pid[starts]] = vals
    return out, shared


def filter_neighbors(
    traj: Trajectories, nbrs: np.ndarray, radius: float, min_shared: int = 2
) -> np.ndarray:
    """Keep candidates whose distance stays below ``radius`` over >= ``min_shared`` frames.

    Parameters
    ----------
    nbrs : (M, S) int64 ndarray
        Candidates per trajectory, -1 = empty (from :func:`sample_neighbors`).

    Returns
    -------
    (M, S) int64 ndarray
        The surviving neighbours, valid ones first, -1 elsewhere.
    """
    M, S = nbrs.shape
    src = np.repeat(np.arange(M), S)
    dst = nbrs.ravel()
    ok = dst >= 0
    dmax, shared = pair_max_distance(traj, src[ok], dst[ok])
    good = np.zeros(M * S, dtype=bool)
    good[np.flatnonzero(ok)] = (dmax < radius) & (shared >= min_shared)
    out = np.where(good.reshape(M, S), nbrs, -1)
    return -np.sort(-out, axis=1)


# -- local rigid transforms --------------------------------------------------------------------
def _fit_chunk(
    context: tuple[Trajectories, np.ndarray, AffinityConfig],
    item: tuple[np.ndarray, np.ndarray, np.ndarray],
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """RANSAC and Kabsch for one chunk of point-frames (a task of :func:`fit_local_rigid`).

    Parameters
    ----------
    context : (Trajectories, (M, S) int64 ndarray, AffinityConfig, (P,) bool ndarray or None)
        The store, the ε-neighbours, the settings and the breaks (:func:`view_breaks`).
    item : ((B,) int64, (B, H) float64, (B, H) float64 ndarrays)
        The rows of i at t, and the uniform draws that pick each hypothesis's two neighbours.

    Returns
    -------
    rows : (B,) int64 ndarray
    ok : (B,) bool ndarray
        Rows with a transform.
    rotation : (F, 3, 3) float32 ndarray
        The transforms of the F rows ``rows[ok]``.
    inliers : (F,) int ndarray
        Their inlier counts under the refined rotation.
    """
    traj, nbrs, cfg, breaks = context
    r, u1, u2 = item
    S = nbrs.shape[1]
    thr2 = cfg.ransac_threshold**2
    xyz = traj.xyz
    i = traj.row_track[r]
    t = traj.row_frame[r]
    nb = nbrs[i]  # (B, S)
    jj = np.maximum(nb, 0)
    alive = (
        (nb >= 0) & (traj.first_frame[jj] <= t[:, None] - 1) & (traj.last_frame[jj] >= t[:, None])
    )
    rj = traj.offsets[jj] + t[:, None] - traj.first_frame[jj]  # (B, S)
    rj = np.where(alive, rj, 0)
    if breaks is not None:  # a neighbour whose views changed at t did not move by its step
        alive &= ~breaks[rj]
    a = xyz[np.maximum(rj - 1, 0)] - xyz[r - 1][:, None]  # (B, S, 3) Δ at t-1
    b = xyz[rj] - xyz[r][:, None]  # (B, S, 3) Δ at t
    # valid neighbours first, then sample index pairs among them
    order = np.argsort(~alive, axis=1, kind="stable")
    a = np.take_along_axis(a, order[..., None], axis=1)
    b = np.take_along_axis(b, order[..., None], axis=1)
    nval = alive.sum(axis=1)  # (B,)
    ok = nval >= max(2, cfg.min_inliers)
    if breaks is not None:  # neither did i: no transform at a break of its own
        ok &= ~breaks[r]
    n = np.maximum(nval, 2)
    k1 = (u1 * n[:, None]).astype(np.int64)
    k2 = (k1 + 1 + (u2 * (n[:, None] - 1)).astype(np.int64)) % n[:, None]
    bi = np.arange(r.size)[:, None]
    Rh = rotation_from_triads(a[bi, k1], a[bi, k2], b[bi, k1], b[bi, k2])  # (B, H, 3, 3)
    Rh = Rh.astype(np.float32)
    res = b[:, None] - a[:, None] @ np.swapaxes(Rh, -1, -2)  # (B, H, S, 3)
    valid = np.arange(S)[None, :] < nval[:, None]  # (B, S)
    inlier = (squared_norm(res) < thr2) & valid[:, None]  # (B, H, S)
    best = inlier.sum(axis=2).argmax(axis=1)  # (B,)
    w = inlier[np.arange(r.size), best]  # (B, S)
    ninl = w.sum(axis=1)
    ok &= ninl >= cfg.min_inliers
    R = fit_rigid(a, b, w, center=False).rotation  # (B, 3, 3) Kabsch on the inliers
    # inlier count under the refined rotation
    res2 = b - a @ np.swapaxes(R, 1, 2).astype(np.float32)
    n2 = ((squared_norm(res2) < thr2) & valid).sum(axis=1)
    return r, ok, R[ok], n2[ok]


def fit_local_rigid(
    traj: Trajectories,
    nbrs: np.ndarray,
    config: AffinityConfig | None = None,
    *,
    progress: Callable[[int], None] | None = None,
    executor: Executor | None = None,
    breaks: np.ndarray | None = None,
) -> LocalTransforms:
    """RANSAC fit of ``(R_t^i, t_t^i)`` for every trajectory i and frame t (t - 1 alive).

    A hypothesis comes from a 3-trajectory sample {i, j, k} with j, k random ε-neighbours alive
    at t - 1 and t: the proper rotation aligning the displacement pair (Δ_j, Δ_k) at t - 1 with
    that at t (a TRIAD frame alignment, closed form, so 16 hypotheses for 10^7 point-frames stay
    cheap). The hypothesis with most inliers (residual ``‖Δ_t - R Δ_{t-1}‖ < ransac_threshold``)
    is refitted on its inliers by Kabsch with the det sign fix. Vectorised over point-frames.

    Parameters
    ----------
    traj : Trajectories
    nbrs : (M, S) int64 ndarray
        ε-neighbours per trajectory, -1 = empty (:func:`filter_neighbors`).
    config : AffinityConfig, optional
    progress : callable, optional
        Called with the number of point-frames done after each chunk.
    executor : Executor, optional
        Where the chunks of point-frames are fitted (default: serially, here); the random
        draws are made here, so the transforms are the same on any executor.
    breaks : (P,) bool ndarray, optional
        :func:`view_breaks`: no transform at a break of i, and a neighbour at a break of its
        own is left out of the fit; kept in the result for :func:`pair_errors`.

    Returns
    -------
    LocalTransforms
    """
    cfg = config or AffinityConfig()
    rng = np.random.default_rng([cfg.seed, 1])
    P = traj.num_point_frames
    rot = np.full((P, 3, 3), np.nan, dtype=np.float32)
    inl = np.full(P, -1, dtype=np.int16)
    S = nbrs.shape[1]
    rows_all = np.setdiff1d(np.arange(P), traj.offsets[:-1], assume_unique=True)
    chunk = max(1, 400_000 // max(S, 1))
    H = cfg.ransac_iterations

    def chunks():
        # The random draws are made here, in chunk order: the same on any executor.
        for c0 in range(0, rows_all.size, chunk):
            r = rows_all[c0 : c0 + chunk]  # (B,) rows of i at t
            yield r, rng.random((r.size, H)), rng.random((r.size, H))

    fits = (executor or SerialExecutor()).map(
        _fit_chunk,
        chunks(),
        label="local rigid transforms",
        total=-(-rows_all.size // chunk),
        context=(traj, nbrs, cfg, breaks),
    )
    for r, ok, R, n2 in fits:
        rot[r[ok]] = R
        inl[r[ok]] = n2
        if progress is not None:
            progress(r.size)
    logger.info(
        "local transforms: %d of %d point-frames fitted",
        int((inl >= 0).sum()),
        rows_all.size,
    )
    return LocalTransforms(rotation=rot, inliers=inl, breaks=breaks)


# -- errors and affinity -----------------------------------------------------------------------
def pair_errors(
    traj: Trajectories,
    transforms: LocalTransforms,
    i: np.ndarray,
    j: np.ndarray,
    mode: Literal["step", "accumulated"] = "step",
) -> np.ndarray:
    """``e_ij``: how badly i's local transforms predict j over the shared lifetime.

    Parameters
    ----------
    traj : Trajectories
    transforms : LocalTransforms
        Of ``traj`` (:func:`fit_local_rigid`).
    i, j : (Q,) int ndarray
        Directed pairs: transforms of ``i`` applied to ``j``.
    mode : {"step", "accumulated"}
        ``"step"``: ``max_t ‖X_t^j - R_t^i X_{t-1}^j - t_t^i‖`` over consecutive shared frames.
        ``"accumulated"``: ``max_t ‖X_t^j - X̂_t^j‖`` with ``X̂`` starting at j's position at
        the first shared frame and propagated by composing i's transforms. Where i has no
        transform at a frame, the prediction restarts from j's observed position there (that
        frame adds no error; the rest of the lifetime still counts). It restarts too at a
        break of i or j (``transforms.breaks``); in ``"step"`` mode such a step is skipped.

    Returns
    -------
    (Q,) float64 ndarray
        Errors in metres; NaN where i has no transform at any frame of the shared lifetime.
    """
    if mode not in ("step", "accumulated"):
        raise ValidationError(f"mode must be 'step' or 'accumulated', got {mode!r}")
    i = np.asarray(i, np.int64)
    j = np.asarray(j, np.int64)
    out = np.full(i.shape[0], np.nan)
    xyz = traj.xyz
    R = transforms.rotation
    brk = transforms.breaks
    for pid, ri, rj in _shared_chunks(traj, i, j):
        if pid.size == 0:
            continue
        first = np.r_[True, pid[1:] != pid[:-1]]  # first shared frame of each pair
        if mode == "step":
            step = ~first  # consecutive (t-1, t) within S
            if brk is not None:
                step &= ~(brk[ri] | brk[rj])
            k = np.flatnonzero(step)
            if k.size == 0:
                continue
            dj0 = (xyz[rj[k] - 1] - xyz[ri[k] - 1]).astype(np.float64)
            dj1 = (xyz[rj[k]] - xyz[ri[k]]).astype(np.float64)
            res = np.linalg.norm(dj1 - (R[ri[k]] @ dj0[:, :, None])[:, :, 0], axis=1)
            p = pid[k]
            starts = np.flatnonzero(np.r_[True, p[1:] != p[:-1]])
            out[p[starts]] = np.fmax.reduceat(res, starts)
        else:
            starts = np.flatnonzero(first)
            lens = np.diff(np.r_[starts, pid.size])
            pred = (xyz[rj[starts]] - xyz[ri[starts]]).astype(np.float64)  # j relative to i
            err = np.full(starts.size, np.nan)
            for s in range(1, int(lens.max(initial=0))):
                live = np.flatnonzero(lens > s)
                k = starts[live] + s
                obs = (xyz[rj[k]] - xyz[ri[k]]).astype(np.float64)
                p = (R[ri[k]] @ pred[live][:, :, None])[:, :, 0]
                gap = np.isnan(p[:, 0])  # no transform of i at this frame: restart from obs
                if brk is not None:  # or the views of i or j changed: the step is no motion
                    gap |= brk[ri[k]] | brk[rj[k]]
                e = np.linalg.norm(obs - p, axis=1)
                e[gap] = np.nan
                p[gap] = obs[gap]
                pred[live] = p
                err[live] = np.fmax(err[live], e)
            out[pid[starts]] = err
    return out


def local_transforms(
    traj: Trajectories,
    config: AffinityConfig,
    rng: np.random.Generator,
    executor: Executor | None = None,
) -> LocalTransforms:
    """Every trajectory's local rigid transforms, fitted on its sampled ε-neighbours.

    :func:`sample_neighbors` draws ``config.rigid_neighbors`` candidates in the ε-ball,
    :func:`filter_neighbors` keeps those within ε over the shared lifetime, and
    :func:`fit_local_rigid` fits the transforms by RANSAC (paper Equation (transform)).

    Parameters
    ----------
    traj : Trajectories
    config : AffinityConfig
        ε, ``rigid_neighbors`` and the RANSAC settings.
    rng : numpy.random.Generator
        Draws the neighbours and the RANSAC samples.
    executor : Executor, optional
        Where the RANSAC chunks run (:func:`fit_local_rigid`).

    Returns
    -------
    LocalTransforms
    """
    nb = filter_neighbors(
        traj, sample_neighbors(traj, config.epsilon, config.rigid_neighbors, rng), config.epsilon
    )
    breaks = view_breaks(traj) if config.view_breaks else None
    return fit_local_rigid(traj, nb, config, executor=executor, breaks=breaks)


#: Pairs per task of :func:`both_pair_errors`.
_PAIR_CHUNK = 100_000


def _both_errors_chunk(
    context: tuple[Trajectories, LocalTransforms, str], pairs: tuple[np.ndarray, np.ndarray]
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`pair_errors` of one chunk of pairs, both ways (a task of :func:`both_pair_errors`)."""
    traj, transforms, mode = context
    i, j = pairs
    return pair_errors(traj, transforms, i, j, mode), pair_errors(traj, transforms, j, i, mode)


def both_pair_errors(
    traj: Trajectories,
    transforms: LocalTransforms,
    i: np.ndarray,
    j: np.ndarray,
    mode: Literal["step", "accumulated"] = "step",
    executor: Executor | None = None,
    progress: Callable[[str, int, int], None] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`pair_errors` of ``(i, j)`` and of ``(j, i)``, by chunks of pairs.

    Each pair's error depends on that pair alone, so the chunks (and the executor that runs
    them) do not change the result.

    Parameters
    ----------
    traj : Trajectories
    transforms : LocalTransforms
    i, j : (Q,) int ndarray
    mode : {"step", "accumulated"}
    executor : Executor, optional
        Default: serially, here.
    progress : callable, optional
        ``progress("errors", done, total)`` per chunk.

    Returns
    -------
    e_fwd, e_bwd : (Q,) float64 ndarray
        Transforms of i applied to j, and of j applied to i.
    """
    i = np.asarray(i, np.int64)
    j = np.asarray(j, np.int64)
    starts = range(0, i.size, _PAIR_CHUNK)
    parts = list(
        (executor or SerialExecutor()).map(
            _both_errors_chunk,
            [(i[s : s + _PAIR_CHUNK], j[s : s + _PAIR_CHUNK]) for s in starts],
            label="errors",
            progress=progress,
            context=(traj, transforms, mode),
        )
    )
    if not parts:
        return np.full(0, np.nan), np.full(0, np.nan)
    return np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])


def symmetric_affinity(
    e_fwd: np.ndarray,
    e_bwd: np.ndarray,
    tau: float,
    symmetrize: Literal["mean", "max", "min"] = "mean",
) -> np.ndarray:
    """``A(i, j) = exp(-(e_ij / τ)^2)`` of both directions, combined (paper Equation (affinity)).

    Parameters
    ----------
    e_fwd, e_bwd : (Q,) float ndarray
        :func:`pair_errors` of ``(i, j)`` and of ``(j, i)``; NaN where untestable.
    tau : float
        τ (m).
    symmetrize : {"mean", "max", "min"}
        How the two directions combine (only available directions count).

    Returns
    -------
    (Q,) float64 ndarray
        In [0, 1]; NaN where neither direction could be tested.
    """
    vals = np.exp(-((np.stack([e_fwd, e_bwd], axis=1) / tau) ** 2))  # (Q, 2), NaN = none
    fin = np.isfinite(vals)
    with np.errstate(invalid="ignore", divide="ignore"):
        if symmetrize == "mean":
            A = np.where(fin, vals, 0.0).sum(axis=1) / fin.sum(axis=1)
        elif symmetrize == "max":
            A = np.fmax(vals[:, 0], vals[:, 1])
        else:
            A = np.fmin(vals[:, 0], vals[:, 1])
    A[~fin.any(axis=1)] = np.nan
    return A


def compute_affinity(
    traj: Trajectories,
    config: AffinityConfig | None = None,
    *,
    progress: Callable[[str, int, int], None] | None = None,
    executor: Executor | None = None,
    transforms: LocalTransforms | None = None,
) -> AffinityGraph:
    """The sparse symmetric affinity graph of a trajectory store (paper Equation (affinity)).

    Parameters
    ----------
    traj : Trajectories
    config : AffinityConfig, optional
    progress : callable, optional
        ``progress(stage, done, total)`` after each step, for progress bars.
    executor : Executor, optional
        Where the local rigid fits and the pair errors run, by chunks of point-frames and of
        pairs (default: serially, here). The graph is the same on any executor.
    transforms : LocalTransforms, optional
        The local rigid transforms to test the pairs with, instead of fitting them
        (:func:`local_transforms`); for studies that supply known motions.

    Returns
    -------
    AffinityGraph
        Upper-triangle edges over the candidate pairs (module docstring) whose weight
        ``A · exp(-(d / distance_scale)^2)`` reaches ``min_affinity``; ``affinity`` and
        ``distance`` hold A and d per edge.
    """
    cfg = config or AffinityConfig()
    rng = np.random.default_rng([cfg.seed, 0])
    M = traj.num_trajectories

    def report(stage: str, done: int, total: int) -> None:
        logger.info("affinity: %s (%d/%d)", stage, done, total)
        if progress is not None:
            progress(stage, done, total)

    report("epsilon-neighbours and local rigid transforms", 0, 5)
    if transforms is None:
        tf = local_transforms(traj, cfg, rng, executor)
    else:
        tf = transforms
        check_array("transforms.rotation", tf.rotation, (traj.num_point_frames, 3, 3), dtype=None)
    report("epsilon_a-neighbours", 2, 5)
    i, j, dist = candidate_pairs(traj, cfg.epsilon_a, cfg.near_neighbors, cfg.max_neighbors, rng)
    report("errors", 3, 5)
    # transforms of i applied to j, and of j applied to i
    e_fwd, e_bwd = both_pair_errors(traj, tf, i, j, cfg.mode, executor)
    del tf
    report("symmetrise", 4, 5)
    A = symmetric_affinity(e_fwd, e_bwd, cfg.tau, cfg.symmetrize)
    untestable = np.isnan(A)
    A[untestable] = cfg.missing_affinity
    w = A if cfg.distance_scale <= 0 else A * np.exp(-((dist / cfg.distance_scale) ** 2))
    ok = w >= cfg.min_affinity
    report("done", 5, 5)
    logger.info(
        "affinity: %d edges over %d trajectories (%.2f per trajectory) from %d candidate pairs "
        "(%d untestable)",
        int(ok.sum()),
        M,
        2 * ok.sum() / max(M, 1),
        i.size,
        int(untestable.sum()),
    )
    return AffinityGraph(
        row=i[ok].astype(np.int64),
        col=j[ok].astype(np.int64),
        weight=w[ok].astype(np.float32),
        num_nodes=M,
        params=asdict(cfg),
        affinity=A[ok].astype(np.float32),
        distance=dist[ok].astype(np.float32),
    )


# -- files -------------------------------------------------------------------------------------
def save_affinity(graph: AffinityGraph, path: str | os.PathLike) -> None:
    """Write ``affinity.npz`` atomically (format: ``data_specs/affinity.md``)."""
    save_npz_atomic(
        path,
        format_version=np.int64(FORMAT_VERSION),
        row=graph.row.astype(np.int64),
        col=graph.col.astype(np.int64),
        weight=graph.weight.astype(np.float32),
        shape=np.array([graph.num_nodes, graph.num_nodes], dtype=np.int64),
        params=np.array(json.dumps(graph.params)),
        **{
            name: np.asarray(value, np.float32)
            for name, value in (("affinity", graph.affinity), ("distance", graph.distance))
            if value is not None
        },
    )


def load_affinity(path: str | os.PathLike) -> AffinityGraph:
    """Read an ``affinity.npz`` written by :func:`save_affinity`.

    Raises
    ------
    FileFormatError
        If the file is missing, unreadable, lacks a field or is inconsistent.
    """
    from .npzfile import load_npz

    path = Path(path)
    data = load_npz(path, ("row", "col", "weight", "shape"), "an affinity graph")
    if int(data.get("format_version", FORMAT_VERSION)) > FORMAT_VERSION:
        raise FileFormatError(path, "format_version is newer than this pointtraj reads")
    try:
        row = check_array("row", data["row"], (None,), dtype=np.int64)
        E = row.shape[0]
        col = check_array("col", data["col"], (E,), dtype=np.int64)
        weight = check_array("weight", data["weight"], (E,), dtype=np.float32, finite=True)
        shape = check_array("shape", data["shape"], (2,), dtype=np.int64)
    except ValidationError as exc:
        raise FileFormatError(path, str(exc)) from None
    M = int(shape[0])
    if E and (row.min() < 0 or col.max() >= M or np.any(row >= col)):
        raise FileFormatError(path, "row/col must satisfy 0 <= row < col < shape[0]")
    extra = {}
    for name in ("affinity", "distance"):
        if name in data:
            try:
                extra[name] = check_array(name, data[name], (E,), dtype=np.float32, finite=True)
            except ValidationError as exc:
                raise FileFormatError(path, str(exc)) from None
    params = json.loads(str(data["params"])) if "params" in data else {}
    return AffinityGraph(row=row, col=col, weight=weight, num_nodes=M, params=params, **extra)
