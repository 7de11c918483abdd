"""Joint trajectory labelling by alpha-expansion on a general graph (the paper's Section 4.3).

Minimises the paper's Equation (cost)

    E(U) = Σ_i D[i, U(i)] + λ Σ_{(i,j) ∈ edges} A(i,j) [U(i) ≠ U(j)]

with Potts pairwise terms weighted by the trajectory affinity. Each α-expansion move is one
binary min-cut built on ``maxflow.Graph[float]`` with vectorised ``add_nodes`` / ``add_edges`` /
``add_grid_tedges`` (Boykov-Veksler-Zabih move, written in the Kolmogorov-Zabih form: a pair with
current labels (a, b), neither α, has move energies E00 = w[a ≠ b], E01 = E10 = w, E11 = 0, which
is submodular because Potts is a metric).

Speed (``method="restricted"``): a move for α only frees the trajectories for which α is
plausible (``L3D[i, α] >= plausible_threshold`` or a neighbour holds α now); the others stay
fixed and enter the cut as unary terms through their edges. Of those, the ones that provably
keep their label in every optimal move are fixed too (:func:`_prune_fixed`: switching to α costs
more than all their edges can give back), which is exact and leaves a few thousand free nodes
per move on a 10^6-trajectory graph. After the first sweep a move is only rebuilt on the
components of its pruned free set that contain a trajectory whose label or neighbourhood
changed since α was last tried (elsewhere the previous optimal move is still optimal), and the
pruning only looks at the neighbourhood of those changes. ``method="full"`` is the plain
whole-graph expansion, for comparison.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from .errors import ValidationError, check_array

__all__ = [
    "LabelingConfig",
    "LabelingResult",
    "data_costs",
    "labeling_energy",
    "expand_alpha",
    "alpha_expansion",
    "plausible_labels",
    "argmax_labels",
    "label_trajectories",
    "weigh_by_support",
]

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class LabelingConfig:
    """Parameters of the labelling stage.

    Attributes
    ----------
    smoothness : float
        λ of the paper's Equation (cost), weight of the affinity (Potts) term. 0.5 was the best
        of 0.3-2 on the demo's reconstructed trajectories (83.8 % against 82.4 % at 0.3) and on
        ring8 ground-truth trajectories (84.0 % against 76.3 %), with the simulated recogniser;
        with ``support_frames = 5`` 0.5 and 1 are both on the plateau (``docs/labeling.md``).
    data_cost : {"neglog", "paper"}
        ``"paper"``: φ = 0 for the argmax label, ``L3D[argmax]`` otherwise. ``"neglog"``:
        ``-log(L3D / ΣL3D + 1e-3)`` shifted to a zero row minimum, which tells the other labels
        apart (the default: see ``benchmarks/study_affinity.py``).
    method : {"restricted", "full"}
        Restricted expansion moves (fast, see the module docstring) or plain whole-graph ones.
    plausible_threshold : float
        α is plausible for a trajectory whose normalised L3D for α is at least this.
    max_sweeps : int
        Upper bound on sweeps over the labels (it stops earlier when no move improves).
    background : float
        L3D of a virtual "none of the classes" label, for every trajectory: a trajectory whose
        L3D stays below it for every class (the walls and the floor of a real capture, where no
        recogniser fires) is left unlabelled (-1) unless its affinity neighbours pull it into
        a class. 0 turns it off and labels every trajectory, as the paper does (its captures
        hold only the labelled people and objects).
    support_frames : float
        Weigh the data cost of a trajectory by its evidence: ``D[i] * max(1, n_i /
        support_frames)``, ``n_i`` the frames its L3D pools (``semantic_map.npz`` ``count``).
        L3D is a temporal average, and ``-log`` of an average says how the classes compare,
        not how often they were seen: without this, 60 frames of a consistent small margin
        weigh what one frame's does, and a few neighbours relabel the trajectory. Shorter
        trajectories keep the paper's cost (never less). 0 turns it off (the paper's cost for
        every trajectory). Default 5: with it the cut gained 1.4 to 4.8 points on the
        reconstructed and ground-truth trajectories of the ring8 demo and a ring12 capture
        (anything from 2 to 5 did, at λ = 0.5 and 1; ``docs/labeling.md``). The weight
        multiplies the margins between the recogniser's classes only: the margin between a
        trajectory's best class and the ``background`` label is a threshold on the
        recogniser's confidence, not evidence that more frames make surer, and stays the
        paper's (:func:`weigh_by_support`).
    """

    smoothness: float = 0.5
    data_cost: Literal["neglog", "paper"] = "neglog"
    method: Literal["restricted", "full"] = "restricted"
    plausible_threshold: float = 0.05
    max_sweeps: int = 10
    background: float = 0.1
    support_frames: float = 5.0

    def __post_init__(self) -> None:
        if not self.smoothness >= 0:
            raise ValidationError("LabelingConfig.smoothness (λ) must be >= 0")
        if self.data_cost not in ("neglog", "paper"):
            raise ValidationError(
                f"LabelingConfig.data_cost must be 'neglog' or 'paper', got {self.data_cost!r}"
            )
        if self.method not in ("restricted", "full"):
            raise ValidationError(
                f"LabelingConfig.method must be 'restricted' or 'full', got {self.method!r}"
            )
        if self.max_sweeps < 1:
            raise ValidationError("LabelingConfig.max_sweeps must be >= 1")
        if not self.support_frames >= 0:
            raise ValidationError(
                f"LabelingConfig.support_frames must be >= 0 (0 = off), got {self.support_frames!r}"
            )
        if not 0 <= self.background < 1:
            raise ValidationError(
                f"LabelingConfig.background must be in [0, 1), got {self.background!r}"
            )


@dataclass
class LabelingResult:
    """Output of :func:`alpha_expansion`.

    Attributes
    ----------
    labels : (M,) int64 ndarray
    energy : list of float
        Energy after initialisation and after each sweep (non-increasing).
    moves : int
        Number of max-flow problems solved.
    seconds : float
        Wall time.
    """

    labels: np.ndarray
    energy: list[float] = field(default_factory=list)
    moves: int = 0
    seconds: float = 0.0


def data_costs(l3d: np.ndarray, kind: Literal["neglog", "paper"] = "neglog") -> np.ndarray:
    """Data costs ``D[i, l]`` from the 3D semantic map.

    Parameters
    ----------
    l3d : (M, K) float ndarray
        L3D per trajectory (non-negative; rows need not sum to 1; NaN rows count as uniform).
    kind : {"neglog", "paper"}
        See :class:`LabelingConfig`.

    Returns
    -------
    (M, K) float64 ndarray
        Non-negative costs, 0 at each row's argmax.

    Examples
    --------
    >>> data_costs(np.array([[0.7, 0.2, 0.1]]), "paper")
    array([[0. , 0.7, 0.7]])
    """
    l3d = check_array("l3d", l3d, (None, None), dtype=np.float64)
    if np.any(l3d < 0):
        raise ValidationError("l3d: must be non-negative")
    l3d = np.where(np.isfinite(l3d), l3d, 0.0)
    M, K = l3d.shape
    top = l3d.argmax(axis=1)
    if kind == "paper":
        D = np.repeat(l3d[np.arange(M), top][:, None], K, axis=1)
        D[np.arange(M), top] = 0.0
        return D
    if kind == "neglog":
        s = l3d.sum(axis=1, keepdims=True)
        p = np.where(s > 0, l3d / np.where(s > 0, s, 1.0), 1.0 / K)
        D = -np.log(p + 1e-3)
        return D - D.min(axis=1, keepdims=True)
    raise ValidationError(f"kind must be 'neglog' or 'paper', got {kind!r}")


def _check_graph(
    D: np.ndarray, row: np.ndarray, col: np.ndarray, weight: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    D = check_array("data_cost", D, (None, None), dtype=np.float64, finite=True)
    row = check_array("row", row, (None,), dtype=np.int64)
    col = check_array("col", col, (row.shape[0],), dtype=np.int64)
    weight = check_array("weight", weight, (row.shape[0],), dtype=np.float64, finite=True)
    M = D.shape[0]
    if row.size and (min(row.min(), col.min()) < 0 or max(row.max(), col.max()) >= M):
        raise ValidationError(f"row/col: edge endpoints must lie in [0, {M})")
    if np.any(weight < 0):
        raise ValidationError("weight: affinities must be non-negative")
    return D, row, col, weight


def labeling_energy(
    labels: np.ndarray,
    D: np.ndarray,
    row: np.ndarray,
    col: np.ndarray,
    weight: np.ndarray,
    smoothness: float = 0.5,
) -> float:
    """``Σ_i D[i, U(i)] + λ Σ_e w_e [U(row_e) ≠ U(col_e)]`` (paper Equation (cost)).

    Parameters
    ----------
    labels : (M,) int ndarray
    D : (M, K) float ndarray
    row, col : (E,) int ndarray
        Each undirected edge once.
    weight : (E,) float ndarray
    smoothness : float
        λ.
    """
    labels = np.asarray(labels)
    unary = D[np.arange(D.shape[0]), labels].sum()
    return float(unary + smoothness * weight[labels[row] != labels[col]].sum())


def expand_alpha(
    labels: np.ndarray,
    alpha: int,
    free: np.ndarray,
    D: np.ndarray,
    row: np.ndarray,
    col: np.ndarray,
    lam_w: np.ndarray,
    edges: np.ndarray | None = None,
) -> np.ndarray:
    """One α-expansion move restricted to the ``free`` trajectories (one min-cut).

    Parameters
    ----------
    labels : (M,) int64 ndarray
        Current labelling (not modified).
    alpha : int
    free : (M,) bool ndarray
        Trajectories allowed to switch to α (those already α are ignored).
    D : (M, K) float64 ndarray
    row, col : (E,) int64 ndarray
    lam_w : (E,) float64 ndarray
        λ A(i, j) per edge.
    edges : (E',) int ndarray, optional
        Indices of the edges with an end in ``free`` (or any superset); default all.

    Returns
    -------
    (M,) int64 ndarray
        The labelling after the optimal move (equal to ``labels`` where nothing improves).
    """
    import maxflow

    free = free & (labels != alpha)
    nodes = np.flatnonzero(free)
    n = nodes.size
    out = labels.copy()
    if n == 0:
        return out
    if edges is not None:
        row, col, lam_w = row[edges], col[edges], lam_w[edges]
    loc = np.full(labels.shape[0], -1, dtype=np.int64)
    loc[nodes] = np.arange(n)
    u1 = D[nodes, alpha].copy()  # cost if the node takes α (sink side)
    u0 = D[nodes, labels[nodes]].copy()  # cost if it keeps its label (source side)
    fr, fc = free[row], free[col]
    lr, lc = labels[row], labels[col]
    # both free: E00 = w[lr != lc], E01 = E10 = w, E11 = 0 (Kolmogorov-Zabih decomposition:
    # E = E00 + (E10 - E00) x_r + (E11 - E10) x_c + (E01 + E10 - E00 - E11) (1 - x_r) x_c)
    both = fr & fc
    w = lam_w[both]
    e00 = np.where(lr[both] == lc[both], 0.0, w)
    a, b = loc[row[both]], loc[col[both]]
    u1 += np.bincount(a, w - e00, minlength=n)
    u1 -= np.bincount(b, w, minlength=n)
    pair_cap = 2.0 * w - e00
    # one end free, the other fixed with label m: E(x) = x w[α != m] + (1 - x) w[l != m]
    for f_side, fl, ol, f_free, o_free in ((row, lr, lc, fr, fc), (col, lc, lr, fc, fr)):
        one = f_free & ~o_free
        if not np.any(one):
            continue
        w1 = lam_w[one]
        k = loc[f_side[one]]
        olo = ol[one]
        u1 += np.bincount(k, np.where(olo != alpha, w1, 0.0), minlength=n)
        u0 += np.bincount(k, np.where(olo != fl[one], w1, 0.0), minlength=n)
    m = np.minimum(u0, u1)
    g = maxflow.Graph[float](n, int(a.size))
    g.add_nodes(n)
    if a.size:  # int32 node ids: PyMaxflow converts int64 per element, 40 % slower
        g.add_edges(a.astype(np.int32), b.astype(np.int32), pair_cap, np.zeros_like(pair_cap))
    g.add_grid_tedges(np.arange(n), u1 - m, u0 - m)
    g.maxflow()
    to_alpha = g.get_grid_segments(np.arange(n))  # True = sink side = α
    out[nodes[to_alpha]] = alpha
    return out


class _Adjacency:
    """Node -> (neighbour, edge id) lists in CSR form, built once per graph."""

    def __init__(self, M: int, row: np.ndarray, col: np.ndarray) -> None:
        from scipy.sparse import coo_matrix

        # scipy's COO -> CSR conversion is a counting sort, 10x faster than an argsort here
        eid = np.arange(row.size, dtype=np.int64)
        csr = coo_matrix(
            (np.concatenate([eid, eid]), (np.concatenate([row, col]), np.concatenate([col, row]))),
            shape=(M, M),
        ).tocsr()  # edges are unique and never loops, so no entries are summed
        self.indptr = csr.indptr.astype(np.int64)
        self.nbr = csr.indices.astype(np.int64)
        self.eid = csr.data
        self.num_edges = int(row.size)

    def slots(self, nodes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Positions of ``nodes``' adjacency entries, concatenated, and how many each has."""
        start = self.indptr[nodes]
        cnt = self.indptr[nodes + 1] - start
        return np.repeat(start - np.cumsum(cnt) + cnt, cnt) + np.arange(int(cnt.sum())), cnt

    def gather(self, nodes: np.ndarray, data: np.ndarray) -> np.ndarray:
        return data[self.slots(nodes)[0]]

    def neighbours_of(self, mask: np.ndarray) -> np.ndarray:
        """(M,) bool: has an edge to a node in ``mask``."""
        out = np.zeros(mask.shape[0], dtype=bool)
        out[self.gather(np.flatnonzero(mask), self.nbr)] = True
        return out

    def edges_of(self, mask: np.ndarray) -> np.ndarray:
        """Sorted unique ids of the edges with an end in ``mask``."""
        mark = np.zeros(self.num_edges, dtype=bool)
        mark[self.gather(np.flatnonzero(mask), self.eid)] = True
        return np.flatnonzero(mark)


def alpha_expansion(
    D: np.ndarray,
    row: np.ndarray,
    col: np.ndarray,
    weight: np.ndarray,
    config: LabelingConfig | None = None,
    *,
    init: np.ndarray | None = None,
    plausible: np.ndarray | None = None,
    progress: Callable[[int], None] | None = None,
) -> LabelingResult:
    """Minimise the paper's Equation (cost) by α-expansion on a general graph.

    Parameters
    ----------
    D : (M, K) float ndarray
        Data costs (:func:`data_costs`).
    row, col : (E,) int ndarray
        Undirected edges, each once.
    weight : (E,) float ndarray
        Affinities ``A(i, j) >= 0``.
    config : LabelingConfig, optional
        λ is ``config.smoothness``.
    init : (M,) int ndarray, optional
        Initial labels (default: argmin of D, i.e. argmax of L3D).
    plausible : (M, K) bool ndarray, optional
        Labels a trajectory may take in a restricted move besides those its neighbours hold
        (e.g. ``L3D / ΣL3D >= plausible_threshold``, see :func:`plausible_labels`); default all.
    progress : callable, optional
        ``progress(1)`` after each label tried.

    Returns
    -------
    LabelingResult
        The energy trace is non-increasing (a move that would raise it is rejected).

    Raises
    ------
    ValidationError
        On inconsistent shapes, negative weights or out-of-range edges.
    """
    cfg = config or LabelingConfig()
    D, row, col, weight = _check_graph(D, row, col, weight)
    M, K = D.shape
    t0 = time.perf_counter()
    lam_w = cfg.smoothness * weight
    labels = D.argmin(axis=1) if init is None else np.asarray(init, np.int64).copy()
    if labels.shape != (M,) or (M and (labels.min() < 0 or labels.max() >= K)):
        raise ValidationError(f"init: expected ({M},) labels in [0, {K})")
    if plausible is None or cfg.method == "full":
        plausible = np.ones((M, K), dtype=bool)
    else:
        plausible = check_array("plausible", plausible, (M, K), dtype=bool)
    E = float(D[np.arange(M), labels].sum() + lam_w[labels[row] != labels[col]].sum())
    trace = [E]
    logger.info("alpha-expansion: %d nodes, %d edges, %d labels, E0 = %.6g", M, row.size, K, E)
    if M == 0:
        return LabelingResult(labels=labels, energy=trace)
    adj = _Adjacency(M, row, col)
    # bookkeeping of the restricted method: move number at which each node last changed and
    # at which each label was last expanded
    changed_at = np.zeros(M, dtype=np.int64)
    tried_at = np.full(K, -1, dtype=np.int64)
    move = 0
    solved = 0
    for sweep in range(cfg.max_sweeps):
        improved = False
        for alpha in range(K):
            move += 1
            if progress is not None:
                progress(1)
            is_alpha = labels == alpha
            if cfg.method == "full":
                free = ~is_alpha
            else:
                cand = (plausible[:, alpha] | adj.neighbours_of(is_alpha)) & ~is_alpha
                if tried_at[alpha] < 0:
                    # exact: drop the trajectories that cannot take α in an optimal move
                    free = _prune_fixed(cand, alpha, labels, D, lam_w, adj)
                else:
                    # only the trajectories near a change since α was last tried can move:
                    # elsewhere the last (optimal) α-move is still optimal
                    dirty = changed_at > tried_at[alpha]
                    touched = (dirty | adj.neighbours_of(dirty)) & cand
                    free = _free_near(touched, cand, alpha, labels, D, lam_w, adj)
            tried_at[alpha] = move
            if not free.any():
                continue
            tm = time.perf_counter()
            edges = adj.edges_of(free)
            new = expand_alpha(labels, alpha, free, D, row, col, lam_w, edges)
            solved += 1
            diff = np.flatnonzero(new != labels)
            logger.debug(
                "move %d (alpha %d): %d free, %d edges, %d changed, %.3f s",
                move,
                alpha,
                int(free.sum()),
                edges.size,
                diff.size,
                time.perf_counter() - tm,
            )
            if diff.size == 0:
                continue
            # energy change over the changed nodes and their edges only
            ed = adj.edges_of(new != labels)
            r, c, w = row[ed], col[ed], lam_w[ed]
            dE = (D[diff, new[diff]] - D[diff, labels[diff]]).sum() + (
                w[new[r] != new[c]].sum() - w[labels[r] != labels[c]].sum()
            )
            if dE < -1e-12 * max(1.0, abs(E)):
                labels = new
                changed_at[diff] = move
                E += float(dE)
                improved = True
        trace.append(E)
        logger.info("alpha-expansion sweep %d: E = %.6g (%d cuts)", sweep + 1, E, solved)
        if not improved:
            break
    secs = time.perf_counter() - t0
    logger.info("alpha-expansion: %d cuts in %.2f s, E = %.6g", solved, secs, E)
    return LabelingResult(labels=labels, energy=trace, moves=solved, seconds=secs)


def plausible_labels(l3d: np.ndarray, threshold: float) -> np.ndarray:
    """(M, K) bool: labels whose normalised L3D reaches ``threshold`` (argmax always)."""
    l3d = np.where(np.isfinite(l3d), np.asarray(l3d, np.float64), 0.0)
    s = l3d.sum(axis=1, keepdims=True)
    out = l3d >= threshold * np.where(s > 0, s, 1.0)
    out[np.arange(l3d.shape[0]), l3d.argmax(axis=1)] = True
    return out


def _prune_fixed(
    free: np.ndarray,
    alpha: int,
    labels: np.ndarray,
    D: np.ndarray,
    lam_w: np.ndarray,
    adj: _Adjacency,
    others: np.ndarray | None = None,
    tol: float = 1e-9,
) -> np.ndarray:
    """The free trajectories that may take α in an optimal α-move (exact pruning).

    A free node ``i`` with label ``l`` can be fixed to ``l`` when switching it to α costs more
    than any configuration of its neighbours can give back:
    ``D[i, α] - D[i, l] > Σ_j λw_ij s_ij`` with ``s_ij = 1`` for a neighbour that is free or
    holds α, ``-1`` for a fixed neighbour with label ``l`` and ``0`` otherwise. Then in every
    labelling of the others, moving ``i`` back from α lowers the energy, so no optimal move has
    ``i`` at α. Fixing nodes turns more neighbours into fixed ones; the test is repeated until
    nothing more is fixed.

    Parameters
    ----------
    free : (M,) bool ndarray
        Candidate trajectories (not modified).
    alpha : int
    labels : (M,) int64 ndarray
    D : (M, K) float64 ndarray
    lam_w : (E,) float64 ndarray
        λ A(i, j) per edge.
    adj : _Adjacency
    others : (M,) bool ndarray, optional
        Further free trajectories that are not tested but counted as free neighbours (the
        test stays valid: it assumes the most a neighbour can give back).
    tol : float
        Slack on the test (ties stay free).

    Returns
    -------
    (M,) bool ndarray
        The subset of ``free`` that the move still has to decide.
    """
    free = free.copy()
    nodes = np.flatnonzero(free)
    # nodes counted as free neighbours: the candidates and, conservatively, ``others``
    counted = free.copy() if others is None else free | others
    while nodes.size:
        li = labels[nodes]
        gain = D[nodes, alpha] - D[nodes, li]
        idx, cnt = adj.slots(nodes)
        owner = np.repeat(np.arange(nodes.size), cnt)
        nbr = adj.nbr[idx]
        w = lam_w[adj.eid[idx]]
        lj = labels[nbr]
        contrib = np.where(counted[nbr] | (lj == alpha), w, np.where(lj == li[owner], -w, 0.0))
        bound = np.bincount(owner, contrib, minlength=nodes.size)
        fixed = gain > bound + tol * np.maximum(1.0, np.abs(gain))
        if not fixed.any():
            break
        free[nodes[fixed]] = False
        counted[nodes[fixed]] = False
        # only the remaining nodes next to a newly fixed one can change their test
        touched = np.zeros(free.shape[0], dtype=bool)
        touched[nbr[fixed[owner]]] = True
        nodes = np.flatnonzero(touched & free)
    return free


def _free_near(
    touched: np.ndarray,
    cand: np.ndarray,
    alpha: int,
    labels: np.ndarray,
    D: np.ndarray,
    lam_w: np.ndarray,
    adj: _Adjacency,
) -> np.ndarray:
    """The free trajectories of a repeated α-move: pruned components that hold a touched node.

    Prunes (:func:`_prune_fixed`) a region grown around ``touched`` through ``cand``, counting
    the candidates outside it as free, and keeps the components of what survives that contain a
    touched node. A component that reaches the region's border is not known to be complete:
    the region then grows (doubling its rings) until none does. Every other candidate keeps its
    label in an optimal move, so this is exact while costing only the neighbourhood of the
    changes.

    Parameters
    ----------
    touched : (M,) bool ndarray
        Candidates that changed, or have a neighbour that changed, since α was last tried.
    cand : (M,) bool ndarray
        Every candidate of the move.
    alpha, labels, D, lam_w, adj
        As in :func:`_prune_fixed`.

    Returns
    -------
    (M,) bool ndarray
    """
    if not touched.any():
        return touched
    region = touched.copy()
    rings = 2
    while True:
        for _ in range(rings):
            region |= adj.neighbours_of(region) & cand
        outside = cand & ~region
        free = _prune_fixed(region, alpha, labels, D, lam_w, adj, others=outside)
        comps = _components_touching(free, touched & free, adj)
        if not outside.any() or not (adj.neighbours_of(comps) & outside).any():
            return comps
        rings *= 2


def _components_touching(free: np.ndarray, touched: np.ndarray, adj: _Adjacency) -> np.ndarray:
    """Nodes of the connected components of the free subgraph that contain a touched node.

    A breadth-first flood from the touched nodes through free nodes, one vectorised frontier
    expansion per level.
    """
    out = touched.copy()
    frontier = np.flatnonzero(touched)
    while frontier.size:
        cand = adj.gather(frontier, adj.nbr)
        cand = cand[free[cand] & ~out[cand]]
        out[cand] = True
        frontier = np.unique(cand)
    return out


def argmax_labels(l3d: np.ndarray, background: float = 0.0) -> np.ndarray:
    """The class of largest L3D per trajectory, -1 where every class is below ``background``.

    Parameters
    ----------
    l3d : (M, K) float ndarray
        NaN counts as 0.
    background : float
        See :attr:`LabelingConfig.background` (0: never -1).

    Returns
    -------
    (M,) int64 ndarray

    Examples
    --------
    >>> argmax_labels(np.array([[0.2, 0.5], [0.05, 0.0]]), 0.1).tolist()
    [1, -1]
    """
    l3d = np.nan_to_num(np.asarray(l3d, np.float64), nan=0.0)
    top = l3d.argmax(axis=1) if l3d.shape[1] else np.full(l3d.shape[0], -1)
    if background > 0 and l3d.shape[1]:
        top = np.where(l3d.max(axis=1) < background, -1, top)
    return top.astype(np.int64)


def weigh_by_support(D: np.ndarray, w: np.ndarray, K: int) -> np.ndarray:
    """Data costs weighed by each trajectory's evidence, between the recogniser's classes only.

    The K classes' costs are multiplied by ``w``; where a virtual background label follows
    them (column K), its cost rises by ``(w - 1)`` times the row's best class cost, so that its
    margin to the best class is the unweighted one. A trajectory that the recogniser saw
    consistently for many frames then holds its class against neighbours of another class
    (``LabelingConfig.support_frames``), but not against the background more than the
    paper's cost does: on a real capture, points beside a person that a recogniser's masks
    cover in every frame (a bias, not independent evidence) are still pulled to the
    background by their neighbours.

    Parameters
    ----------
    D : (M, K) or (M, K + 1) float ndarray
        Data costs, each row's minimum 0; column K, where present, the background's.
    w : (M,) float ndarray
        Weights, >= 1.
    K : int
        Number of the recogniser's classes.

    Returns
    -------
    (M, K) or (M, K + 1) float ndarray
        The weighed costs (a new array), each row's minimum still 0.
    """
    out = D * w[:, None]
    if K > 0 and D.shape[1] > K:
        out[:, K] = D[:, K] + (w - 1.0) * D[:, :K].min(axis=1, initial=np.inf)
    return out


def label_trajectories(
    l3d: np.ndarray,
    row: np.ndarray,
    col: np.ndarray,
    weight: np.ndarray,
    config: LabelingConfig | None = None,
    *,
    support: np.ndarray | None = None,
    progress: Callable[[int], None] | None = None,
) -> LabelingResult:
    """Label trajectories from their 3D semantic map and affinity graph (paper Section 4.3).

    Data costs from ``config.data_cost``, initialisation at the argmax of L3D, then
    :func:`alpha_expansion` (restricted moves use :func:`plausible_labels`). With
    ``config.background > 0`` a virtual label of constant L3D ``background`` takes part in the
    expansion; the trajectories that end with it are labelled -1.

    Parameters
    ----------
    l3d : (M, K) float ndarray
        L3D per trajectory (rows of zeros for trajectories without semantics).
    row, col : (E,) int ndarray
        Affinity graph edges, each once.
    weight : (E,) float ndarray
        ``A(row, col)``.
    config : LabelingConfig, optional
    support : (M,) ndarray, optional
        Frames pooled into each row of ``l3d`` (``SemanticMap.count``). With
        ``config.support_frames > 0`` row i's data cost is scaled by
        ``max(1, support[i] / support_frames)``; without ``support`` every row keeps the
        paper's cost (as with ``support_frames = 0``; logged).

    Returns
    -------
    LabelingResult
        ``labels`` in [-1, K).

    Raises
    ------
    ValidationError
        If ``support`` is not (M,), finite and non-negative.
    """
    cfg = config or LabelingConfig()
    l3d = check_array("l3d", l3d, (None, None), dtype=np.float64)
    K = l3d.shape[1]
    if cfg.background > 0:
        none = np.full((l3d.shape[0], 1), cfg.background)
        l3d = np.concatenate([np.nan_to_num(l3d, nan=0.0), none], axis=1)  # (M, K + 1)
    D = data_costs(l3d, cfg.data_cost)
    if cfg.support_frames > 0 and support is None:
        logger.info("labelling: no pooled-frame counts given, support_frames is not applied")
    elif cfg.support_frames > 0:
        n = check_array("support", support, (l3d.shape[0],), dtype=np.float64, finite=True)
        if np.any(n < 0):
            raise ValidationError("support: frame counts must be non-negative")
        D = weigh_by_support(D, np.maximum(1.0, n / cfg.support_frames), K)
    init = np.nan_to_num(l3d, nan=0.0).argmax(axis=1)
    res = alpha_expansion(
        D,
        row,
        col,
        weight,
        cfg,
        init=init,
        plausible=plausible_labels(l3d, cfg.plausible_threshold),
        progress=progress,
    )
    res.labels = np.where(res.labels >= K, -1, res.labels).astype(np.int64)
    return res
