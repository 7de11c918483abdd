"""People as instances: a person id per trajectory, from the affinity graph and 2D person masks.

The labelling stage gives each trajectory a class (a body part); this module gives the
trajectories on people a person identity that holds across views and over time:

1. **Rigid groups.** Among the trajectories labelled with a person class (``kind = "body"`` in
   labels.toml), the affinity graph's edges of weight ``>= min_weight`` join trajectories that
   move together. Two people are not one rigid group, so the graph keeps them apart (on a
   real two-person capture it had no edge between them).
2. **Splits by the masks.** Where the recogniser gives 2D person masks
   (:attr:`~pointtraj.semantics.semantic_map.SemanticMap.person_votes`: per point-frame and
   camera, the image's person id under the projection), an edge is cut when its two
   trajectories fall in the same person's mask in fewer than ``split_agreement`` of the
   images they share: a chance edge between two people who touch.
3. **Connected components** of what is left (``scipy.sparse.csgraph.connected_components``).
4. **Merges by the masks.** Per component and image, the person that most of its
   trajectories fall in is its vote. Components of at least ``min_trajectories`` trajectories
   (anchors) that vote for the same person in at least ``merge_agreement`` of the images they
   share (at least ``min_shared``) are one person: a body that the graph left in pieces.
   Merges go strongest first and never join two groups that a pair of their anchors
   contradicts (agreeing in fewer than ``split_agreement`` of ``min_shared`` or more shared
   images). Then each smaller component (a short trajectory with no rigid partner: a point
   seen for a frame or two) joins the group whose anchors it agrees with best, if that is at
   least ``merge_agreement`` of one or more shared images: its point lies in the very mask
   that the person's anchors fill in that image.
5. **Ids.** Groups of at least ``min_trajectories`` trajectories are people, numbered 0, 1, ...
   by decreasing size (ties: the smallest trajectory index first), so the ids are stable for a
   given labelling. Smaller groups, other classes and unlabelled trajectories get -1.

Without person votes, steps 2 and 4 do nothing and a person is a connected rigid group.
Everything is vectorised over edges and components (sparse products), except the greedy merge
loop of step 4, which runs over pairs of anchors (a few per person).

``min_weight`` (0.5) matters: the graph also holds weak edges between trajectories whose
rigidity could not be tested (too short a shared lifetime), and on the two-figure synthetic
scene those joined the two people (``docs/labeling.md``, "Instances", has the sweep).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .errors import ValidationError, check_array

__all__ = [
    "InstanceConfig",
    "assign_instances",
    "person_classes",
    "instance_accuracy",
    "match_instances",
]

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class InstanceConfig:
    """Parameters of :func:`assign_instances` (table ``[label]``, prefix ``instance_``).

    Attributes
    ----------
    enabled : bool
        Assign instances at all (the labelling stage's ``[label.instances]`` table).
    min_weight : float
        Affinity edges at least this heavy join trajectories into rigid groups.
    min_shared : int
        Images two trajectories (or components) must share before their person masks count.
    split_agreement : float
        An edge (or a merge) is refused when the pair falls in the same person's mask in fewer
        than this share of their shared images.
    merge_agreement : float
        Two components merge when they fall in the same person's mask in at least this share
        of their shared images.
    min_trajectories : int
        Smallest group that is a person; smaller groups get -1.
    """

    enabled: bool = True
    min_weight: float = 0.5
    min_shared: int = 3
    split_agreement: float = 0.5
    merge_agreement: float = 0.8
    min_trajectories: int = 10

    def __post_init__(self) -> None:
        for name in ("min_weight", "split_agreement", "merge_agreement"):
            v = getattr(self, name)
            if not 0.0 <= v <= 1.0:
                raise ValidationError(f"instance {name}: must be in [0, 1], got {v}")
        if self.min_shared < 1 or self.min_trajectories < 1:
            raise ValidationError(
                f"instance min_shared and min_trajectories must be >= 1, got {self.min_shared} "
                f"and {self.min_trajectories}"
            )


def person_classes(class_names: Sequence[str], kinds: Sequence[str] | None = None) -> np.ndarray:
    """The classes that are parts of a person.

    Parameters
    ----------
    class_names : sequence of K str
    kinds : sequence of K str, optional
        labels.toml's kinds; without them, the classes named like the body parts
        (:data:`pointtraj.labelset.BODY_PARTS`) or ``person``.

    Returns
    -------
    (P,) int64 ndarray
        Class indices of kind ``"body"``.

    Examples
    --------
    >>> person_classes(["head", "ball", "torso"]).tolist()
    [0, 2]
    """
    from .labelset import BODY_PARTS

    if kinds is not None:
        if len(kinds) != len(class_names):
            raise ValidationError(f"kinds: expected {len(class_names)} values, got {len(kinds)}")
        return np.array([i for i, k in enumerate(kinds) if k == "body"], np.int64)
    body = {*BODY_PARTS, "person"}
    return np.array([i for i, n in enumerate(class_names) if n in body], np.int64)


def _vote_matrices(votes: np.ndarray, M: int):
    """Per-trajectory incidence of (image, person) keys and of images, as CSR (M, .) arrays."""
    from scipy import sparse

    track = votes[:, 0].astype(np.int64)
    image = votes[:, 1].astype(np.int64)
    key = image * (int(votes[:, 2].max()) + 1) + votes[:, 2]
    _, kcol = np.unique(key, return_inverse=True)
    _, icol = np.unique(image, return_inverse=True)
    ones = np.ones(len(votes), np.float32)
    B = sparse.csr_array((ones, (track, kcol)), shape=(M, int(kcol.max()) + 1))
    U = sparse.csr_array((ones, (track, icol)), shape=(M, int(icol.max()) + 1))
    B.sum_duplicates()
    U.sum_duplicates()
    B.data[:] = 1.0  # a trajectory is one point: one person per image, counted once
    U.data[:] = 1.0
    return B, U, key, image


def _pair_counts(B, U, a: np.ndarray, b: np.ndarray, chunk: int = 65536):
    """For pairs (a, b) of rows: images where both fall in the same key, and images shared."""
    same = np.zeros(len(a), np.float64)
    both = np.zeros(len(a), np.float64)
    for s in range(0, len(a), chunk):
        sl = slice(s, s + chunk)
        same[sl] = B[a[sl]].multiply(B[b[sl]]).sum(axis=1)
        both[sl] = U[a[sl]].multiply(U[b[sl]]).sum(axis=1)
    return same, both


def assign_instances(
    labels: np.ndarray,
    person_classes: np.ndarray,
    row: np.ndarray,
    col: np.ndarray,
    weight: np.ndarray,
    person_votes: np.ndarray | None = None,
    config: InstanceConfig | None = None,
) -> np.ndarray:
    """A person id per trajectory (see the module docstring for the steps).

    Parameters
    ----------
    labels : (M,) int ndarray
        Class per trajectory (-1: unlabelled).
    person_classes : (P,) int ndarray
        The classes that are parts of a person (labels.toml's ``kind = "body"``).
    row, col : (E,) int ndarray
        Affinity edges (each once).
    weight : (E,) float ndarray
        Their weights.
    person_votes : (V, 3) int ndarray, optional
        Rows (trajectory, image, person id in that image) of the semantic map
        (:attr:`~pointtraj.semantics.semantic_map.SemanticMap.person_votes`).
    config : InstanceConfig, optional

    Returns
    -------
    (M,) int64 ndarray
        Person id (0 the largest), -1 for trajectories on no person.

    Raises
    ------
    ValidationError
        On inconsistent shapes or indices out of range.

    Examples
    --------
    >>> labels = np.array([0, 0, 0, 0, 1])
    >>> assign_instances(labels, np.array([0]), np.array([0, 2]), np.array([1, 3]),
    ...                  np.ones(2), config=InstanceConfig(min_trajectories=2)).tolist()
    [0, 0, 1, 1, -1]
    """
    from scipy import sparse
    from scipy.sparse.csgraph import connected_components

    cfg = config or InstanceConfig()
    labels = check_array("labels", labels, (None,), dtype=np.int64)
    M = labels.shape[0]
    row = check_array("row", row, (None,), dtype=np.int64)
    E = row.shape[0]
    col = check_array("col", col, (E,), dtype=np.int64)
    weight = check_array("weight", weight, (E,), dtype=np.float64)
    if E and (min(row.min(), col.min()) < 0 or max(row.max(), col.max()) >= M):
        raise ValidationError(f"row, col: edge endpoints must lie in [0, {M})")
    votes = np.zeros((0, 3), np.int64) if person_votes is None else np.asarray(person_votes)
    if votes.ndim != 2 or votes.shape[1] != 3:
        raise ValidationError(f"person_votes: expected shape (V, 3), got {votes.shape}")
    if len(votes) and (votes[:, 0].min() < 0 or votes[:, 0].max() >= M):
        raise ValidationError(f"person_votes: trajectory indices must lie in [0, {M})")
    votes = votes[votes[:, 2] >= 0].astype(np.int64)

    on_person = np.isin(labels, np.asarray(person_classes, np.int64))  # (M,)
    keep = on_person[row] & on_person[col] & (weight >= cfg.min_weight)  # (E,)
    a, b = row[keep], col[keep]
    have_votes = len(votes) > 0
    if have_votes:
        B, U, key, image = _vote_matrices(votes, M)
        same, both = _pair_counts(B, U, a, b)
        cut = (both > 0) & (same < cfg.split_agreement * both)
        logger.info(
            "instances: %d of %d rigid-group edges cut by the person masks", cut.sum(), len(a)
        )
        a, b = a[~cut], b[~cut]
    graph = sparse.coo_array((np.ones(len(a)), (a, b)), shape=(M, M)).tocsr()
    _, comp = connected_components(graph, directed=False)  # (M,)
    comp = np.where(on_person, comp, -1)
    # renumber the person components 0..G-1
    used, comp_p = np.unique(comp[on_person], return_inverse=True)
    group = np.full(M, -1, np.int64)
    group[on_person] = comp_p
    G = len(used)
    if have_votes and G > 1:
        group = _merge_by_masks(group, G, votes, cfg)
    return _number_by_size(group, cfg.min_trajectories)


def _merge_by_masks(group: np.ndarray, G: int, votes: np.ndarray, cfg: InstanceConfig):
    """Merge components that the person masks put on one person (step 4).

    Components of at least ``min_trajectories`` trajectories (anchors) merge among themselves,
    strongest agreement first, never joining two groups that a pair of their anchors
    contradicts; then each smaller component joins the anchor group its masks agree with best.
    """
    from scipy import sparse

    g = group[votes[:, 0]]
    ok = g >= 0
    g, image, pid = g[ok], votes[ok, 1], votes[ok, 2]
    if not len(g):
        return group
    # per (component, image): the person most of its trajectories fall in
    P = int(pid.max()) + 1
    _, icol = np.unique(image, return_inverse=True)
    n_img = int(icol.max()) + 1
    cells, counts = np.unique((g * n_img + icol) * P + pid, return_counts=True)
    ci = cells // P  # (component, image) of each cell
    order = np.lexsort((-counts, ci))  # per (component, image), the largest count first
    first = np.ones(len(order), bool)
    first[1:] = ci[order][1:] != ci[order][:-1]
    dom = cells[order][first]  # (component * n_img + image) * P + person, dominant
    dg, dimg = dom // P // n_img, (dom // P) % n_img
    ones = np.ones(len(dom), np.float32)
    D = sparse.csr_array((ones, (dg, dom % (n_img * P))), shape=(G, n_img * P))
    Ui = sparse.csr_array((ones, (dg, dimg)), shape=(G, n_img))
    size = np.bincount(group[group >= 0], minlength=G)
    anchors = np.flatnonzero(size >= cfg.min_trajectories)
    if not len(anchors):
        return group
    # 1. anchors among themselves: (A, A) dense counts
    same = (D[anchors] @ D[anchors].T).toarray()
    shared = (Ui[anchors] @ Ui[anchors].T).toarray()
    with np.errstate(invalid="ignore", divide="ignore"):
        agree = np.where(shared >= cfg.min_shared, same / shared, np.nan)
    pa, pb = np.triu_indices(len(anchors), k=1)
    conflict = agree[pa, pb] < cfg.split_agreement  # NaN compares False
    merge = agree[pa, pb] >= cfg.merge_agreement
    parent = np.arange(len(anchors))

    def find(x: int) -> int:
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    enemies: dict[int, set[int]] = {}
    for x, y in zip(pa[conflict].tolist(), pb[conflict].tolist()):
        enemies.setdefault(x, set()).add(y)
        enemies.setdefault(y, set()).add(x)
    strongest = np.argsort(-same[pa[merge], pb[merge]], kind="stable")
    merged = 0
    for x, y in zip(pa[merge][strongest].tolist(), pb[merge][strongest].tolist()):
        rx, ry = find(x), find(y)
        if rx == ry:
            continue
        ex, ey = enemies.get(rx, set()), enemies.get(ry, set())
        if any(find(e) == ry for e in ex) or any(find(e) == rx for e in ey):
            continue
        parent[ry] = rx
        enemies[rx] = ex | ey
        merged += 1
    root = np.array([find(x) for x in range(len(anchors))], np.int64)  # (A,)
    new = np.full(G, -1, np.int64)
    new[anchors] = anchors[root]
    # 2. smaller components join the anchor group their masks agree with best
    small = np.flatnonzero(size < cfg.min_trajectories)
    if len(small):
        _, gcol = np.unique(root, return_inverse=True)
        to_group = sparse.csr_array(
            (np.ones(len(anchors)), (np.arange(len(anchors)), gcol)),
            shape=(len(anchors), int(gcol.max()) + 1),
        )  # (A, groups)
        same_g = (D[small] @ D[anchors].T @ to_group).toarray()  # (S, groups)
        shared_g = (Ui[small] @ Ui[anchors].T @ to_group).toarray()
        with np.errstate(invalid="ignore", divide="ignore"):
            # one shared image is evidence enough for a piece: its point lies in the mask
            # that the person's anchor trajectories fill in that very image
            agree_g = np.where(shared_g >= 1, same_g / shared_g, -1.0)
        best = agree_g.argmax(axis=1)  # (S,)
        join = agree_g[np.arange(len(small)), best] >= cfg.merge_agreement
        group_root = np.zeros(int(gcol.max()) + 1, np.int64)
        group_root[gcol] = anchors[root]
        new[small[join]] = group_root[best[join]]
        # those that join nothing stay their own (small) group
        new[small[~join]] = small[~join]
        logger.info(
            "instances: %d of %d smaller components joined a person by the masks",
            int(join.sum()),
            len(small),
        )
    logger.info("instances: %d merges of %d larger components by the masks", merged, len(anchors))
    return np.where(group >= 0, new[np.maximum(group, 0)], -1)


def _number_by_size(group: np.ndarray, min_size: int) -> np.ndarray:
    """Groups of at least ``min_size`` members numbered 0.. by decreasing size; others -1."""
    out = np.full(group.shape, -1, np.int64)
    member = group >= 0
    if not member.any():
        return out
    ids, first, inv, size = np.unique(
        group[member], return_index=True, return_inverse=True, return_counts=True
    )
    first_index = np.flatnonzero(member)[first]
    order = np.lexsort((first_index, -size))  # largest first, then earliest trajectory
    rank = np.empty(len(ids), np.int64)
    rank[order] = np.arange(len(ids))
    rank[size < min_size] = -1
    big = size >= min_size
    # renumber the kept ones densely in rank order
    kept = np.sort(rank[big])
    dense = np.full(len(ids), -1, np.int64)
    dense[big] = np.searchsorted(kept, rank[big])
    out[member] = dense[inv]
    return out


def match_instances(pred: np.ndarray, true: np.ndarray) -> dict[int, int]:
    """The best one-to-one matching of predicted to true ids (most shared trajectories).

    Parameters
    ----------
    pred, true : (N,) int ndarray
        Predicted and true ids (negative: none).

    Returns
    -------
    dict of int to int
        Predicted id -> true id (Hungarian assignment on the contingency table).
    """
    from scipy.optimize import linear_sum_assignment

    pred = np.asarray(pred, np.int64)
    true = np.asarray(true, np.int64)
    ok = (pred >= 0) & (true >= 0)
    if not ok.any():
        return {}
    p_ids, p_inv = np.unique(pred[ok], return_inverse=True)
    t_ids, t_inv = np.unique(true[ok], return_inverse=True)
    table = np.zeros((len(p_ids), len(t_ids)), np.int64)
    np.add.at(table, (p_inv, t_inv), 1)
    r, c = linear_sum_assignment(-table)
    return {int(p_ids[i]): int(t_ids[j]) for i, j in zip(r, c)}


def instance_accuracy(pred: np.ndarray, true: np.ndarray) -> float:
    """Share of trajectories with a true person whose predicted id matches it.

    Predicted ids are matched to true ids one-to-one (:func:`match_instances`); a trajectory
    with a true person (``true >= 0``) counts as right when its predicted id is matched to its
    true id (-1 or an unmatched id is wrong).

    Parameters
    ----------
    pred, true : (N,) int ndarray

    Returns
    -------
    float
        NaN when no trajectory has a true person.

    Examples
    --------
    >>> instance_accuracy(np.array([1, 1, 0, 0, -1]), np.array([0, 0, 1, 1, 1]))
    0.8
    """
    pred = np.asarray(pred, np.int64)
    true = np.asarray(true, np.int64)
    if pred.shape != true.shape:
        raise ValidationError(f"pred, true: shapes differ ({pred.shape} and {true.shape})")
    has = true >= 0
    if not has.any():
        return float("nan")
    match = match_instances(pred, true)
    lut = np.array([match.get(int(p), -2) for p in range(int(max(pred.max(), 0)) + 1)])
    mapped = np.where(pred >= 0, lut[np.maximum(pred, 0)], -2)
    return float((mapped[has] == true[has]).mean())
