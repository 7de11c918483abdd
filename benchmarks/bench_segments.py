"""Benchmark: time and memory of the segment stage's algorithm at up to 10^6 trajectories.

Builds exact rigid parts (14 groups of trajectories, each part moving rigidly, every trajectory
alive for a random run of frames) as a :class:`~pointtraj.trajectories.Trajectories` store, then
times :func:`pointtraj.segments.compute_segments` and measures the peak of the memory numpy
allocates during the call (``tracemalloc``), beside the store's own size.

Usage (the figures of ``docs/segments.md``)::

    python benchmarks/bench_segments.py --trajectories 100000 1000000 --frames 30
"""

from __future__ import annotations

import argparse
import time
import tracemalloc

import numpy as np


def make_store(M: int, T: int, rng: np.random.Generator):
    """M trajectories on 14 rigid parts over T frames, each alive for a random run."""
    from pointtraj.geometry import rotation_from_rodrigues
    from pointtraj.labelset import BODY_PARTS
    from pointtraj.trajectories import Trajectories

    K = len(BODY_PARTS)
    label = rng.integers(0, K, M)
    local = rng.normal(scale=0.08, size=(M, 3))
    first = rng.integers(0, T - 1, M)
    length = rng.integers(2, T + 1, M)
    length = np.minimum(length, T - first)
    offsets = np.concatenate([[0], np.cumsum(length)])
    P = int(offsets[-1])
    track = np.repeat(np.arange(M), length)
    frame = first[track] + np.arange(P) - offsets[track]
    axes = rng.normal(size=(K, 3))
    R = np.stack(
        [[rotation_from_rodrigues(axes[k] * 0.03 * t) for t in range(T)] for k in range(K)]
    )  # (K, T, 3, 3)
    t_k = rng.normal(size=(K, 1, 3)) + np.linspace(0, 0.3, T)[None, :, None]  # (K, T, 3)
    xyz = np.empty((P, 3), np.float32)
    for k in range(K):  # one part at a time: no (P, 3, 3) temporary
        rows = np.flatnonzero(label[track] == k)
        f = frame[rows]
        xyz[rows] = np.einsum("pij,pj->pi", R[k, f], local[track[rows]]) + t_k[k, f]
    store = Trajectories(
        first_frame=first,
        offsets=offsets,
        xyz=xyz,
        visibility=np.zeros((P, 1), np.uint8),
        reprojection_error=np.zeros(P, np.float32),
        color=np.zeros((P, 3), np.uint8),
        camera_names=["c0"],
        num_frames=T,
    )
    return store, label


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--trajectories", type=int, nargs="+", default=[100_000, 1_000_000])
    ap.add_argument("--frames", type=int, default=30)
    args = ap.parse_args()
    from pointtraj.labelset import LabelSet
    from pointtraj.segments import compute_segments

    labels = LabelSet.default()
    for M in args.trajectories:
        store, label = make_store(M, args.frames, np.random.default_rng(0))
        _ = store.row_track, store.row_frame, store._frame_index  # the store's own indexes
        size = sum(a.nbytes for a in (store.xyz, store.visibility, store.offsets))
        tracemalloc.start()
        t0, c0 = time.perf_counter(), time.process_time()
        seg = compute_segments(store, label, labels)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        print(
            f"M={M:>9,d} P={store.num_point_frames:>11,d} T={args.frames}: "
            f"{wall:6.1f} s wall, {cpu:6.1f} s CPU, peak {peak / 2**20:7.1f} MiB allocated "
            f"(store {size / 2**20:.0f} MiB), {int((seg.inliers > 0).sum())} part-frames posed, "
            f"max rotation error check: residual max {np.nanmax(seg.residual) * 1000:.3f} mm"
        )


if __name__ == "__main__":
    main()
