"""The guided matcher's vectorised kernel against a plain per-keypoint reference."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from helpers.rigs import plane_rig
from helpers.scenes import plane_images

from pointtraj.reconstruct.matching import (
    Features,
    MatchingConfig,
    _camera_terms,
    _guided_matches,
    detect_features,
    epipolar_distances,
    match_pair,
    match_pairs,
)


def _features(pixels: np.ndarray, descriptors: np.ndarray) -> Features:
    import cv2

    kps = [cv2.KeyPoint(float(x), float(y), 31.0) for x, y in pixels]
    return Features(pixels.astype(np.float32), descriptors, kps, (480, 360))


def _reference(rig, fa, fb, cfg) -> dict[int, tuple[int, int]]:
    """Per keypoint of a, by a loop: the nearest b keypoint by Hamming distance among those
    within ``epipolar_px`` of its epipolar line, kept by the ratio test (and, with
    ``cross_check``, when that b keypoint's nearest a keypoint in the band is this one)."""
    bits = np.unpackbits(fa.descriptors[:, None, :] ^ fb.descriptors[None, :, :], axis=2)
    ham = bits.sum(axis=2)  # (Na, Nb)
    band = np.zeros(ham.shape, bool)
    for i in range(len(fa)):
        pa = np.repeat(fa.pixels[i : i + 1].astype(np.float64), len(fb), axis=0)
        band[i] = epipolar_distances(rig, 0, 1, pa, fb.pixels.astype(np.float64)) <= 2.5
    out = {}
    for i in range(len(fa)):
        j = np.flatnonzero(band[i])
        if j.size == 0:
            continue
        d = np.sort(ham[i, j])
        best = int(j[np.argmin(ham[i, j])])
        if j.size > 1 and not d[0] < cfg.ratio * d[1]:
            continue
        if cfg.cross_check:
            back = np.flatnonzero(band[:, best])
            if back[np.argmin(ham[back, best])] != i:
                continue
        out[i] = (best, int(d[0]))
    return out


@pytest.mark.parametrize("cross_check", [False, True])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_guided_kernel_equals_the_per_keypoint_reference(seed, cross_check):
    rng = np.random.default_rng(seed)
    rig = plane_rig(2, dist=[-0.1, 0.02, 0.001, 0.0, 0.0])
    X = rng.uniform(-0.6, 0.6, (300, 3))
    pix = rig.project(X).pixels
    inside = np.all(np.isfinite(pix), axis=(0, 2))
    pa = pix[0][inside]
    pb = pix[1][inside] + rng.normal(0, 1.0, pix[1][inside].shape)  # some leave the band
    # descriptors with distinct distances per keypoint: no ties for the reference to break
    desc_a = rng.integers(0, 256, (len(pa), 32), dtype=np.uint8)
    flips = rng.random(desc_a.shape) < 0.15
    desc_b = desc_a ^ (flips * rng.integers(1, 256, desc_a.shape)).astype(np.uint8)
    # clutter: random keypoints, some of them inside the bands
    extra = np.column_stack([rng.uniform(0, 480, 200), rng.uniform(0, 360, 200)])
    fa = _features(pa, desc_a)
    fb = _features(
        np.vstack([pb, extra]),
        np.vstack([desc_b, rng.integers(0, 256, (200, 32), dtype=np.uint8)]),
    )
    cfg = MatchingConfig(guided=True, gms=False, ratio=0.9, cross_check=cross_check)
    pairs, dist = _guided_matches(rig, 0, 1, fa, fb, cfg, chunk=64)  # several chunks
    ref = _reference(rig, fa, fb, cfg)
    bits = np.unpackbits(fa.descriptors[:, None] ^ fb.descriptors[None], axis=2).sum(axis=2)
    ties = {i for i in ref if np.sum(bits[i] == ref[i][1]) > 1}  # equal nearest: any may win
    got = {int(i): (int(j), int(d)) for (i, j), d in zip(pairs.tolist(), dist.tolist())}
    assert len(ref) > 100
    assert {i: v for i, v in got.items() if i not in ties} == {
        i: v for i, v in ref.items() if i not in ties
    }
    assert dist.dtype == np.int64 and pairs.dtype == np.int64


def test_guided_kernel_rejects_an_equal_second_and_counts_all_256_bits():
    """Two candidates at the same distance fail the ratio test; complementary descriptors are
    256 bits apart (no overflow of the per-word popcounts)."""
    rig = plane_rig(2, dist=[0.0] * 5)
    X = np.array([[0.0, 0.0, 0.0], [0.1, 0.05, 0.0]])
    pix = rig.project(X).pixels
    d = np.zeros((1, 32), np.uint8)
    fa = _features(pix[0][:1], d)
    # two b keypoints on the same epipolar line, both exactly 256 bits away
    fb = _features(pix[1][[0, 0]] + [[0.0, 0.0], [0.0, 0.0]], np.full((2, 32), 255, np.uint8))
    cfg = MatchingConfig(guided=True, gms=False, ratio=1.0)
    pairs, dist = _guided_matches(rig, 0, 1, fa, fb, cfg)
    # equal second: the ratio test (best < ratio * second) rejects it
    assert pairs.shape == (0, 2)
    fb = _features(pix[1][:1], np.full((1, 32), 255, np.uint8))
    pairs, dist = _guided_matches(rig, 0, 1, fa, fb, cfg)
    assert pairs.tolist() == [[0, 0]] and dist.tolist() == [256]


def test_match_pairs_equals_match_pair_per_pair(narrow_rig):
    images = plane_images(narrow_rig, seed=3)
    cfg = MatchingConfig(num_features=1500, guided=True)
    feats = [detect_features(img, cfg) for img in images]
    edges = np.array([[0, 1], [1, 2], [0, 2]])
    together = match_pairs(narrow_rig, feats, edges, cfg)
    assert len(together) == 3 and sum(len(m) for m in together) > 300
    for (a, b), m in zip(edges, together):
        alone = match_pair(narrow_rig, int(a), int(b), feats[a], feats[b], cfg)
        np.testing.assert_array_equal(m, alone)
    # the per-image terms give the kernel the same inputs it computes for itself
    terms = (_camera_terms(narrow_rig, 0, feats[0]), _camera_terms(narrow_rig, 1, feats[1]))
    for cross in (False, True):
        c = dataclasses.replace(cfg, cross_check=cross)
        with_terms = _guided_matches(narrow_rig, 0, 1, feats[0], feats[1], c, terms=terms)
        without = _guided_matches(narrow_rig, 0, 1, feats[0], feats[1], c)
        for x, y in zip(with_terms, without):
            np.testing.assert_array_equal(x, y)
