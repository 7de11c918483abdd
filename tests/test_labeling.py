"""Tests of alpha-expansion on general graphs (pointtraj.labeling)."""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np
import pytest

from pointtraj.errors import ValidationError
from pointtraj.labeling import (
    LabelingConfig,
    alpha_expansion,
    argmax_labels,
    data_costs,
    expand_alpha,
    label_trajectories,
    labeling_energy,
    weigh_by_support,
)


def random_graph(rng: np.random.Generator, M: int, K: int, p: float = 0.5):
    """A random graph with random data costs and affinities."""
    pairs = np.array([(i, j) for i in range(M) for j in range(i + 1, M)])
    keep = rng.random(len(pairs)) < p
    row, col = pairs[keep, 0], pairs[keep, 1]
    weight = rng.random(row.size)
    D = rng.random((M, K)) * 2.0
    return D, row, col, weight


def brute_force(D, row, col, weight, lam):
    M, K = D.shape
    best, arg = np.inf, None
    for lab in itertools.product(range(K), repeat=M):
        e = labeling_energy(np.array(lab), D, row, col, weight, lam)
        if e < best:
            best, arg = e, np.array(lab)
    return best, arg


def best_expansion_energy(labels, alpha, D, row, col, weight, lam):
    """The minimum energy over every α-expansion of ``labels`` (brute force over subsets)."""
    cand = np.flatnonzero(labels != alpha)
    best = labeling_energy(labels, D, row, col, weight, lam)
    for bits in itertools.product([False, True], repeat=cand.size):
        lab = labels.copy()
        lab[cand[np.array(bits, dtype=bool)]] = alpha
        best = min(best, labeling_energy(lab, D, row, col, weight, lam))
    return best


@pytest.mark.parametrize("seed", range(6))
def test_single_move_is_the_optimal_expansion(seed):
    rng = np.random.default_rng(seed)
    D, row, col, weight = random_graph(rng, 6, 3)
    labels = rng.integers(0, 3, 6)
    for alpha in range(3):
        new = expand_alpha(labels, alpha, np.ones(6, bool), D, row, col, 1.5 * weight)
        assert np.all((new == labels) | (new == alpha))
        e_move = labeling_energy(new, D, row, col, weight, 1.5)
        assert e_move == pytest.approx(
            best_expansion_energy(labels, alpha, D, row, col, weight, 1.5), abs=1e-9
        )


@pytest.mark.parametrize("seed", range(12))
def test_pruned_trajectories_never_take_alpha_in_an_optimal_move(seed):
    """_prune_fixed is exact: the move on the pruned set is as good as on the whole set."""
    from pointtraj.labeling import _Adjacency, _prune_fixed

    rng = np.random.default_rng(300 + seed)
    M, K = 9, 3
    D, row, col, weight = random_graph(rng, M, K, p=0.4)
    D = D * rng.choice([0.3, 3.0], size=(M, 1))  # some strongly held labels, some weak
    labels = rng.integers(0, K, M)
    lam_w = 1.2 * weight
    adj = _Adjacency(M, row, col)
    pruned_any = False
    for alpha in range(K):
        everyone = labels != alpha
        free = _prune_fixed(everyone, alpha, labels, D, lam_w, adj)
        assert np.all(free <= everyone)
        pruned_any |= bool((everyone & ~free).any())
        best = best_expansion_energy(labels, alpha, D, row, col, weight, 1.2)
        # brute force over the moves of the pruned set reaches the same optimum
        cand = np.flatnonzero(free)
        restricted = labeling_energy(labels, D, row, col, weight, 1.2)
        for bits in itertools.product([False, True], repeat=cand.size):
            lab = labels.copy()
            lab[cand[np.array(bits, dtype=bool)]] = alpha
            restricted = min(restricted, labeling_energy(lab, D, row, col, weight, 1.2))
        assert restricted == pytest.approx(best, abs=1e-9)
        new = expand_alpha(labels, alpha, free, D, row, col, lam_w)
        assert labeling_energy(new, D, row, col, weight, 1.2) == pytest.approx(best, abs=1e-9)
    if seed == 0:
        assert pruned_any  # the test exercises the pruning


@pytest.mark.parametrize("method", ["restricted", "full"])
@pytest.mark.parametrize("seed", range(8))
def test_result_is_local_minimum_within_bound(seed, method):
    rng = np.random.default_rng(100 + seed)
    D, row, col, weight = random_graph(rng, 6, 3)
    lam = 1.0
    res = alpha_expansion(D, row, col, weight, LabelingConfig(smoothness=lam, method=method))
    E = labeling_energy(res.labels, D, row, col, weight, lam)
    assert E == pytest.approx(res.energy[-1])
    assert np.all(np.diff(res.energy) <= 1e-12)
    # no α-expansion improves the result
    for alpha in range(3):
        assert best_expansion_energy(res.labels, alpha, D, row, col, weight, lam) >= E - 1e-9
    # Boykov-Veksler-Zabih: within 2 max(w)/min(w) = 2 of the optimum for Potts
    opt, _ = brute_force(D, row, col, weight, lam)
    assert opt - 1e-9 <= E <= 2.0 * opt + 1e-9


@pytest.mark.parametrize("seed", range(6))
def test_two_labels_is_exact(seed):
    rng = np.random.default_rng(200 + seed)
    D, row, col, weight = random_graph(rng, 8, 2, p=0.6)
    res = alpha_expansion(D, row, col, 2.0 * weight, LabelingConfig(smoothness=1.0, method="full"))
    opt, _ = brute_force(D, row, col, 2.0 * weight, 1.0)
    assert res.energy[-1] == pytest.approx(opt, abs=1e-9)


def test_energy_never_increases_and_restricted_matches_full_on_chain():
    """A noisy 1D chain of three segments: both methods reach the same low energy."""
    rng = np.random.default_rng(3)
    M, K = 3000, 3
    truth = np.repeat(np.arange(K), M // K)
    l3d = rng.dirichlet(np.ones(K) * 0.5, size=M)
    l3d[np.arange(M), truth] += 0.4
    row = np.arange(M - 1)
    col = row + 1
    weight = np.ones(M - 1)
    D = data_costs(l3d)
    plaus = l3d / l3d.sum(1, keepdims=True) >= 0.05
    res_r = alpha_expansion(D, row, col, weight, LabelingConfig(smoothness=2.0), plausible=plaus)
    res_f = alpha_expansion(D, row, col, weight, LabelingConfig(smoothness=2.0, method="full"))
    for res in (res_r, res_f):
        assert np.all(np.diff(res.energy) <= 1e-9)
        assert res.energy[-1] < res.energy[0]
    assert res_r.energy[-1] <= res_f.energy[-1] * 1.001
    assert (res_f.labels == truth).mean() > (D.argmin(1) == truth).mean()


def test_data_costs_kinds():
    l3d = np.array([[0.6, 0.3, 0.1], [0.0, 0.0, 0.0]])
    paper = data_costs(l3d, "paper")
    np.testing.assert_allclose(paper[0], [0.0, 0.6, 0.6])
    neg = data_costs(l3d, "neglog")
    assert neg.shape == (2, 3) and neg[0, 0] == 0.0 and neg[0, 1] < neg[0, 2]
    np.testing.assert_allclose(neg[1], 0.0)  # empty L3D: uniform
    with pytest.raises(ValidationError, match="kind"):
        data_costs(l3d, "hinge")
    with pytest.raises(ValidationError, match="l3d"):
        data_costs(-l3d, "paper")


def test_bad_input():
    D = np.zeros((3, 2))
    with pytest.raises(ValidationError, match="row/col"):
        alpha_expansion(D, np.array([0]), np.array([5]), np.array([1.0]))
    with pytest.raises(ValidationError, match="weight"):
        alpha_expansion(D, np.array([0]), np.array([1]), np.array([-1.0]))
    with pytest.raises(ValidationError, match="col"):
        alpha_expansion(D, np.array([0, 1]), np.array([1]), np.array([1.0]))
    with pytest.raises(ValidationError, match="smoothness"):
        LabelingConfig(smoothness=-1.0)
    with pytest.raises(ValidationError, match="method"):
        LabelingConfig(method="gco")


def test_empty_graph_returns_argmin():
    D = np.array([[1.0, 0.0], [0.0, 1.0]])
    res = alpha_expansion(D, np.zeros(0, int), np.zeros(0, int), np.zeros(0))
    np.testing.assert_array_equal(res.labels, [1, 0])
    assert res.energy[-1] == 0.0


def _rotation(axis, angle: float) -> np.ndarray:
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def attached_parts_scene(rng: np.random.Generator, T: int = 8):
    """A forearm (300 points) with a hand (80) rigidly attached at its end, and a third part
    (300) moving differently; labels 0, 1, 2. A noisy L3D: 10 % of trajectories have a wrong
    dominant class."""
    from pointtraj.trajectories import Trajectories

    arm = rng.uniform([-0.25, -0.03, -0.03], [0.0, 0.03, 0.03], (300, 3))
    hand = rng.uniform([0.005, -0.03, -0.015], [0.085, 0.03, 0.015], (80, 3))
    other = rng.uniform([-0.45, -0.1, -0.1], [-0.30, 0.1, 0.1], (300, 3))
    label = np.repeat([0, 1, 2], [300, 80, 300])
    X = np.empty((label.size, T, 3))
    for t in range(T):
        X[:380, t] = np.concatenate([arm, hand]) @ _rotation([0, 0, 1], 0.05 * t).T
        X[:380, t, 0] += 0.01 * t
        X[380:, t] = other @ _rotation([0, 1, 0], -0.03 * t).T
    M = label.size
    l3d = np.full((M, 3), 0.05)
    l3d[np.arange(M), label] = 0.6
    wrong = rng.random(M) < 0.1
    alt = (label + rng.integers(1, 3, M)) % 3
    l3d[wrong, alt[wrong]] = 0.7
    return Trajectories.from_dense(X.astype(np.float32)), label, l3d


def test_cut_keeps_rigidly_attached_small_part():
    """Regression: the graph cut relabelled a whole part rigidly attached to a bigger one.

    Bug: with the former defaults (τ = 2 cm, per-step errors, ε_a-neighbours drawn uniformly in
    the 30 cm ball, no spatial kernel, λ = 1) a hand rigidly attached to its forearm gets
    A ≈ 1 to most of its ε_a-neighbours, which are forearm points; the Potts term then outweighs
    the hand's data evidence and the cut labels the whole hand "forearm" (hands 50 % -> 10 % on
    the 8-camera demo). The defaults (near neighbours, spatial kernel, τ = 2 mm, λ = 0.4) keep
    the hand and fix most of the noisy labels.
    """
    from pointtraj.affinity import AffinityConfig, compute_affinity
    from pointtraj.labeling import label_trajectories

    traj, label, l3d = attached_parts_scene(np.random.default_rng(0))
    hand = label == 1
    argmax = l3d.argmax(axis=1)
    g = compute_affinity(traj, AffinityConfig())
    res = label_trajectories(l3d, g.row, g.col, g.weight, LabelingConfig())
    assert np.all(np.diff(res.energy) <= 1e-9)
    assert (res.labels[hand] == 1).mean() >= 0.95
    assert (res.labels == label).mean() >= 0.98 > (argmax == label).mean()
    # the former defaults reproduce the bug: A ≈ 1 across the joint, the hand disappears
    former = AffinityConfig(
        tau=0.02,
        mode="step",
        near_neighbors=0,
        distance_scale=0.0,
        missing_affinity=0.0,
        min_affinity=1e-4,
    )
    g_old = compute_affinity(traj, former)
    across = np.isin(label[g_old.row], [0, 1]) & (label[g_old.row] != label[g_old.col])
    across &= np.isin(label[g_old.col], [0, 1])
    assert across.sum() > 50 and g_old.affinity[across].mean() > 0.95
    old = label_trajectories(l3d, g_old.row, g_old.col, g_old.weight, LabelingConfig(smoothness=1))
    assert (old.labels[hand] == 1).mean() < 0.2


def test_background_leaves_trajectories_without_semantics_unlabelled():
    """Regression: on a real capture every wall and floor trajectory (L3D all zero) was
    labelled ``head``, class 0, the argmax of a zero row."""
    l3d = np.array([[0.8, 0.1], [0.0, 0.0], [0.02, 0.05], [0.0, 0.05], [0.1, 0.7]])
    row, col, weight = np.array([0, 3]), np.array([1, 4]), np.array([0.0, 100.0])
    res = label_trajectories(l3d, row, col, weight, LabelingConfig(background=0.1))
    # 1 and 2 have nothing above 0.1; 3 (weak evidence) is pulled into its neighbour's class
    # by the affinity.
    np.testing.assert_array_equal(res.labels, [0, -1, -1, 1, 1])
    np.testing.assert_array_equal(argmax_labels(l3d, 0.1), [0, -1, -1, -1, 1])
    off = label_trajectories(l3d, row, col, weight, LabelingConfig(background=0.0))
    assert off.labels.min() == 0  # the paper's: every trajectory gets a class
    np.testing.assert_array_equal(argmax_labels(l3d), [0, 0, 1, 1, 1])
    nan = label_trajectories(np.full((2, 3), np.nan), [], [], [], LabelingConfig())
    np.testing.assert_array_equal(nan.labels, [-1, -1])
    with pytest.raises(ValidationError, match="background must be in"):
        LabelingConfig(background=1.0)


def test_support_frames_weighs_data_cost_by_pooled_frames():
    """A long, consistently recognised trajectory keeps its label against a few short
    neighbours; with the paper's cost (the same for every trajectory) they relabel it.

    Trajectory 0 pooled 60 frames with a small margin for class 0; trajectories 1-3 pooled
    2 frames each with the same margin for class 1, all strongly connected to 0.
    """
    l3d = np.array([[0.4, 0.3]] + [[0.3, 0.4]] * 3)
    row, col, weight = np.array([0, 0, 0]), np.array([1, 2, 3]), np.full(3, 1.0)
    count = np.array([60, 2, 2, 2])
    paper = label_trajectories(l3d, row, col, weight, LabelingConfig(background=0.0))
    np.testing.assert_array_equal(paper.labels, [1, 1, 1, 1])  # the short ones win
    cfg = LabelingConfig(background=0.0, support_frames=10.0)
    res = label_trajectories(l3d, row, col, weight, cfg, support=count)
    np.testing.assert_array_equal(res.labels, [0, 0, 0, 0])  # 60 frames of evidence win
    # the energy is the one of the scaled costs, and non-increasing
    D = data_costs(l3d) * np.maximum(1.0, count / 10.0)[:, None]
    assert res.energy[-1] == pytest.approx(labeling_energy(res.labels, D, row, col, weight, 0.5))
    assert np.all(np.diff(res.energy) <= 1e-12)
    # fewer frames than support_frames keep the paper's cost, never less: the same energies
    zero = label_trajectories(l3d, row, col, weight, cfg, support=np.array([60, 0, 0, 0]))
    np.testing.assert_allclose(zero.energy, res.energy)
    # a short trajectory alone keeps the paper's cost: 0 against 3 short neighbours loses
    short = label_trajectories(l3d, row, col, weight, cfg, support=np.full(4, 2))
    np.testing.assert_array_equal(short.labels, paper.labels)
    # without the counts every trajectory keeps the paper's cost
    np.testing.assert_allclose(label_trajectories(l3d, row, col, weight, cfg).energy, paper.energy)
    with pytest.raises(ValidationError, match="support"):
        label_trajectories(l3d, row, col, weight, cfg, support=np.array([1, -1, 2, 2]))
    with pytest.raises(ValidationError, match=r"support: expected"):
        label_trajectories(l3d, row, col, weight, cfg, support=np.ones(3))
    with pytest.raises(ValidationError, match="support_frames"):
        LabelingConfig(support_frames=-1.0)


def test_support_frames_leaves_the_background_margin_unweighed():
    """The evidence weight holds a class against other classes, not against the background.

    Trajectory 0 pooled 60 frames with class 0 just above the background level (a recogniser's
    mask that spills past a person, the same in every frame); its three neighbours have no
    class above it. As with the paper's cost they pull it to the background. Between two
    classes (above the background) the weight still holds it.
    """
    row, col, weight = np.array([0, 0, 0]), np.array([1, 2, 3]), np.full(3, 1.0)
    count = np.array([60, 2, 2, 2])
    cfg = LabelingConfig(background=0.1, support_frames=10.0)
    spill = np.array([[0.15, 0.05]] + [[0.02, 0.02]] * 3)
    paper = label_trajectories(spill, row, col, weight, dataclasses.replace(cfg, support_frames=0))
    np.testing.assert_array_equal(paper.labels, [-1, -1, -1, -1])
    res = label_trajectories(spill, row, col, weight, cfg, support=count)
    np.testing.assert_array_equal(res.labels, paper.labels)
    # the costs: the classes' weighed by max(1, n / 10), the background's margin to the best
    # class as it was
    D = data_costs(np.column_stack([spill, np.full(4, 0.1)]))
    W = weigh_by_support(D, np.maximum(1.0, count / 10.0), 2)
    np.testing.assert_allclose(W[:, :2], D[:, :2] * np.array([6.0, 1, 1, 1])[:, None])
    np.testing.assert_allclose(W[:, 2] - W[:, :2].min(axis=1), D[:, 2] - D[:, :2].min(axis=1))
    assert np.all(W.min(axis=1) == 0)
    assert res.energy[-1] == pytest.approx(
        labeling_energy(res.labels + 3 * (res.labels < 0), W, row, col, weight, 0.5)
    )
    # two classes, both above the background: 60 frames of evidence hold class 0
    classes = np.array([[0.4, 0.3]] + [[0.3, 0.4]] * 3)
    held = label_trajectories(classes, row, col, weight, cfg, support=count)
    np.testing.assert_array_equal(held.labels, [0, 0, 0, 0])
    np.testing.assert_array_equal(
        label_trajectories(
            classes, row, col, weight, dataclasses.replace(cfg, support_frames=0)
        ).labels,
        [1, 1, 1, 1],
    )
