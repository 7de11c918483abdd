"""Benchmark: memory and time of ``pointtraj export rerun`` at 10^6 trajectories.

A made-up store of ``--trajectories`` trajectories over ``--frames`` frames (each alive on a
random run of at least half the frames, so that about three quarters of them are live in a
frame), with labels over ``--classes`` classes, two people, and semantic-map confidences,
is written as a Rerun recording by :func:`pointtraj.export.rerun.write_recording` with the
default options (tails of 10 frames, confidences on; no cameras: a made-up store has no
images). It prints:

- the resident memory after building the store and its frame-major index (the inputs);
- the resident memory after each frame of the export (``/proc/self/statm``), first, middle and
  last, and the peak (``ru_maxrss``): the export holds one frame, so these do not grow with the
  frames;
- the export's wall and CPU time, and the recording's size.

Usage (the figures of ``docs/user_guide.md``, "Exporting")::

    PYTHONPATH=. .venv/bin/python benchmarks/bench_export_memory.py --out /tmp/bench_rerun.rrd
    PYTHONPATH=. .venv/bin/python benchmarks/bench_export_memory.py --frames 10 --out /tmp/b.rrd
"""

from __future__ import annotations

import argparse
import os
import resource
import time
from pathlib import Path

import numpy as np


def rss_mib() -> float:
    """The process's resident memory now, MiB."""
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def peak_mib() -> float:
    """The process's peak resident memory so far, MiB."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def cpu_seconds() -> float:
    """The process's user and system CPU time so far, its threads included, seconds."""
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def made_up_store(M: int, T: int, C: int, rng: np.random.Generator):
    """M trajectories over T frames, built directly in the store's layout (no dense copy)."""
    from pointtraj.trajectories import Trajectories

    half = max(1, T // 2)
    first = rng.integers(0, T - half + 1, M)  # (M,)
    lengths = rng.integers(half, T - first + 1)  # (M,) at least half the frames
    offsets = np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64)
    P = int(offsets[-1])
    row_track = np.repeat(np.arange(M), lengths)  # (P,)
    local = np.arange(P) - offsets[row_track]  # (P,) frames since the first
    base = rng.normal(size=(M, 3)).astype(np.float32)
    step = rng.normal(scale=0.005, size=(M, 3)).astype(np.float32)
    xyz = base[row_track] + step[row_track] * local[:, None].astype(np.float32)  # (P, 3)
    del row_track, local
    return Trajectories(
        first_frame=first.astype(np.int64),
        offsets=offsets,
        xyz=xyz,
        visibility=np.zeros((P, C), np.uint8),
        reprojection_error=np.zeros(P, np.float32),
        color=np.full((P, 3), 200, np.uint8),
        camera_names=[f"cam{c}" for c in range(C)],
        fps=30.0,
        num_frames=T,
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, required=True, help="The .rrd (removed unless --keep).")
    ap.add_argument("--trajectories", type=int, default=1_000_000)
    ap.add_argument("--frames", type=int, default=20)
    ap.add_argument("--cameras", type=int, default=4)
    ap.add_argument("--classes", type=int, default=15)
    ap.add_argument("--tail", type=int, default=10)
    ap.add_argument("--keep", action="store_true")
    args = ap.parse_args()

    from pointtraj.export.rerun import RerunConfig, write_recording

    rng = np.random.default_rng(0)
    M, K = args.trajectories, args.classes
    t0 = time.perf_counter()
    traj = made_up_store(M, args.frames, args.cameras, rng)
    traj.frame_rows(0)  # the frame-major index
    labels = rng.integers(-1, K, M)
    instance = rng.integers(-1, 2, M)
    conf = rng.random((M, K), dtype=np.float32)
    names = tuple(f"class{k}" for k in range(K))
    inputs = rss_mib()
    print(
        f"store: {M} trajectories, {traj.num_point_frames} point-frames over "
        f"{traj.num_frames} frames, built in {time.perf_counter() - t0:.1f} s; "
        f"RSS with the index and tables {inputs:.0f} MiB (peak {peak_mib():.0f})"
    )
    per_frame: list[float] = []
    cpu0 = cpu_seconds()

    def progress(label: str, done: int, total: int) -> None:
        per_frame.append(rss_mib())

    result = write_recording(
        args.out,
        traj,
        labels=labels,
        class_names=names,
        instance=instance,
        confidences=conf,
        config=RerunConfig(tail=args.tail),
        progress=progress,
    )
    cpu = cpu_seconds() - cpu0
    T = len(per_frame)
    size = args.out.stat().st_size / 2**20
    print(
        f"export: {len(result.frames)} frames, {result.points} point-frames "
        f"({result.points / len(result.frames):.0f} a frame), {result.strips} line strips, "
        f"in {result.seconds:.1f} s wall, {cpu:.1f} CPU-s (threads included); "
        f"recording {size:.0f} MiB"
    )
    print(
        f"RSS after frame 1: {per_frame[0]:.0f} MiB, after frame {T // 2}: "
        f"{per_frame[T // 2 - 1]:.0f} MiB, after frame {T}: {per_frame[-1]:.0f} MiB; "
        f"peak {peak_mib():.0f} MiB (inputs {inputs:.0f} MiB: the export adds "
        f"{peak_mib() - inputs:.0f} MiB)"
    )
    print("RSS after each frame, MiB:", " ".join(f"{r:.0f}" for r in per_frame))
    if not args.keep:
        args.out.unlink()


if __name__ == "__main__":
    main()
