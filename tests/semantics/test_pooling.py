"""Tests of pointtraj.semantics.pooling: view pooling (visibility-weighted medoid) and baselines."""

from __future__ import annotations

import numpy as np
import pytest

from pointtraj.errors import ValidationError
from pointtraj.semantics.pooling import POOLINGS, pool_views, view_pooling_costs


def brute_force_costs(L, V, eps):
    """O(C^2 K) medoid costs sum_j V_j ||L_c - L_j||^2 over cameras with V > eps."""
    C, N, K = L.shape
    costs = np.full((C, N), np.inf)
    for n in range(N):
        valid = [c for c in range(C) if V[n, c] > eps]
        for c in valid:
            costs[c, n] = sum(V[n, j] * np.sum((L[c, n] - L[j, n]) ** 2) for j in valid)
    return costs


def random_case(seed, C=9, N=300, K=5):
    rng = np.random.default_rng(seed)
    L = rng.random((C, N, K)).astype(np.float32)
    V = rng.random((N, C)).astype(np.float32)
    V[rng.random((N, C)) < 0.3] = 0.0
    V[:5] = 0.05  # no camera above eps_e
    return L, V


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_view_pooling_matches_brute_force_medoid(seed):
    L, V = random_case(seed)
    eps = 0.1
    ref = brute_force_costs(L.astype(np.float64), V.astype(np.float64), eps)
    costs = view_pooling_costs(L, V, eps)
    finite = np.isfinite(ref)
    np.testing.assert_array_equal(np.isfinite(costs), finite)
    np.testing.assert_allclose(costs[finite], ref[finite], rtol=1e-4, atol=1e-4)
    pooled = pool_views(L, V, eps)
    best = np.argmin(ref, axis=0)
    has = finite.any(axis=0)
    # The chosen vector is a candidate whose brute-force cost is the minimum (ties allowed).
    for n in np.flatnonzero(has):
        chosen = [c for c in range(L.shape[0]) if np.array_equal(L[c, n], pooled[n])]
        assert chosen and min(ref[c, n] for c in chosen) <= ref[best[n], n] + 1e-4
    assert np.isnan(pooled[~has]).all() and (~has).sum() >= 5


def test_layouts_agree_and_ambiguity_is_resolved():
    L, V = random_case(3)
    a = pool_views(L, V, 0.1)
    b = pool_views(L.transpose(1, 0, 2), V, 0.1)
    np.testing.assert_array_equal(a, b)
    square = np.random.default_rng(0).random((4, 4, 3)).astype(np.float32)
    Vs = np.ones((4, 4))
    np.testing.assert_array_equal(
        pool_views(square, Vs, 0.1, camera_axis=1), pool_views(square.transpose(1, 0, 2), Vs, 0.1)
    )


def test_view_pooling_ignores_outlier_views_that_average_cannot():
    """A few confident wrong views: the medoid returns a majority view, the mean is biased."""
    rng = np.random.default_rng(4)
    C, N, K = 20, 200, 4
    truth = np.zeros((N, K), np.float32)
    truth[:, 0] = 0.9
    L = np.repeat(truth[None], C, axis=0) + rng.uniform(0, 0.05, (C, N, K)).astype(np.float32)
    L[:6, :, 0] = 0.0
    L[:6, :, 1] = 1.0  # six views confuse class 0 with class 1
    V = np.ones((N, C), np.float32)
    view = pool_views(L, V, 0.1)
    avg = pool_views(L, V, 0.1, method="average")
    assert (view.argmax(1) == 0).all() and view[:, 1].max() < 0.1
    assert avg[:, 1].min() > 0.25  # the mean carries the confusion


def test_average_uses_in_image_cameras_unweighted():
    L = np.array([[[1.0, 0.0]], [[0.0, 1.0]], [[0.5, 0.5]]], np.float32)  # (3, 1, 2)
    V = np.array([[1.0, 0.0, 0.0]])
    in_image = np.array([[True], [True], [False]])
    np.testing.assert_allclose(pool_views(L, V, 0.1, "average", in_image=in_image), [[0.5, 0.5]])
    np.testing.assert_allclose(pool_views(L, V, 0.1, "average"), [[1.0, 0.0]])  # V > 0 fallback
    none = pool_views(L, V, 0.1, "average", in_image=np.zeros((3, 1), bool))
    assert np.isnan(none).all()


def test_baselines():
    L = np.array([[[0.8, 0.2]], [[0.6, 0.4]], [[0.0, 1.0]]], np.float32)
    V = np.array([[1.0, 0.5, 0.05]])
    np.testing.assert_allclose(pool_views(L, V, 0.1, "max"), [[0.8, 0.4]])
    np.testing.assert_allclose(
        pool_views(L, V, 0.1, "weighted"), [[(0.8 + 0.3) / 1.5, (0.2 + 0.2) / 1.5]], rtol=1e-6
    )
    prod = pool_views(L, V, 0.1, "product")
    expected = np.array([(0.8 + 1e-3) * (0.6 + 1e-3), (0.2 + 1e-3) * (0.4 + 1e-3)])
    np.testing.assert_allclose(prod[0], expected / expected.sum(), rtol=1e-5)
    for method in POOLINGS:
        out = pool_views(L, np.zeros((1, 3)), 0.1, method)
        assert out.shape == (1, 2) and np.isnan(out).all(), method


def test_nan_samples_are_not_used():
    L = np.array([[[np.nan, 0.0]], [[0.3, 0.7]], [[0.2, 0.8]]], np.float32)
    V = np.ones((1, 3))
    for method in POOLINGS:
        out = pool_views(L, V, 0.1, method)
        assert np.isfinite(out).all(), method
        assert out[0, 1] > out[0, 0], method


def test_errors():
    L, V = random_case(0, C=3, N=4, K=2)
    with pytest.raises(ValidationError, match="method: must be one of"):
        pool_views(L, V, 0.1, "median")
    with pytest.raises(ValidationError, match="does not match V"):
        pool_views(L[:, :3], V, 0.1)
    with pytest.raises(ValidationError, match="in_image"):
        pool_views(L, V, 0.1, "average", in_image=np.ones((2, 2), bool))
    with pytest.raises(ValidationError, match="camera_axis"):
        pool_views(L, V, 0.1, camera_axis=2)


@pytest.mark.parametrize("seed", [0, 1])
def test_view_soft_is_the_kernel_weighted_mean_around_the_medoid(seed):
    from pointtraj.semantics.pooling import VIEW_SOFT_WIDTH

    L, V = random_case(seed)
    eps = 0.1
    medoid = pool_views(L, V, eps, "view")
    soft = pool_views(L, V, eps, "view_soft")
    for n in range(0, L.shape[1], 7):
        use = [c for c in range(L.shape[0]) if V[n, c] > eps]
        if not use:
            assert np.isnan(soft[n]).all()
            continue
        w = np.array(
            [
                V[n, c] * np.exp(-np.sum((L[c, n] - medoid[n]) ** 2) / VIEW_SOFT_WIDTH**2)
                for c in use
            ]
        )
        want = (w[:, None] * L[use, n]).sum(axis=0) / w.sum()
        np.testing.assert_allclose(soft[n], want, rtol=1e-5, atol=1e-6)


def test_view_soft_keeps_the_medoid_robustness():
    """Six views agree on class 0 with view-specific noise, three confidently say class 1: the
    soft pool stays on class 0 and is less noisy than the single medoid view."""
    rng = np.random.default_rng(0)
    C, N, K = 9, 200, 3
    L = np.zeros((C, N, K), np.float32)
    L[:6, :, 0] = rng.uniform(0.6, 1.0, (6, N))
    L[:6, :, 1:] = rng.uniform(0.0, 0.2, (6, N, 2))
    L[6:, :, 1] = 0.95
    V = np.ones((N, C), np.float32)
    soft = pool_views(L, V, 0.1, "view_soft")
    medoid = pool_views(L, V, 0.1, "view")
    assert (soft.argmax(axis=1) == 0).all() and (medoid.argmax(axis=1) == 0).all()
    assert soft[:, 1].max() < 0.3  # the outlying views hardly count
    assert soft[:, 0].std() < medoid[:, 0].std()


def test_average_visible_is_the_unweighted_mean_of_the_visible_cameras():
    L, V = random_case(4)
    eps = 0.1
    out = pool_views(L, V, eps, "average_visible")
    for n in range(L.shape[1]):
        use = V[n] > eps
        if use.any():
            np.testing.assert_allclose(out[n], L[use, n].mean(axis=0), rtol=1e-5)
        else:
            assert np.isnan(out[n]).all()
    # With visibility 0 or 1 it is the visibility-weighted mean; the paper's average (every
    # camera in whose image the point falls) also takes the cameras with V = 0.
    V01 = (V > eps).astype(np.float32)
    np.testing.assert_allclose(
        pool_views(L, V01, eps, "weighted"), pool_views(L, V01, eps, "average_visible")
    )
    every = np.ones(L.shape[:2], bool)
    some = V01.sum(axis=1) < L.shape[0]
    assert not np.allclose(
        pool_views(L, V01, eps, "average", in_image=every)[some & (V01.sum(1) > 0)],
        out[some & (V01.sum(1) > 0)],
    )
