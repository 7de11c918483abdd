"""Benchmark: memory of the reconstruction's bookkeeping over many frames, at paper69's scale.

A long reconstruction at paper69's scale (50-100k points a frame, 69 cameras) takes minutes a
frame; its bookkeeping does not depend on how the records were made. This drives the same
bookkeeping with records made up frame by frame (``--points`` live trajectories seen by
``--cameras`` cameras, about 22 % of the views observed as on paper69, ``--turnover`` of them
ending each frame and replaced by new ones), in one of two modes, each in its own process:

- ``files`` (this version): each record written to ``state/<t>.npz``
  (:class:`~pointtraj.reconstruct.framestore.FrameStore`) and dropped, the store assembled from
  the files (:meth:`FrameStore.assemble`);
- ``list`` (as earlier versions): every record kept in a list, the store assembled by
  :func:`~pointtraj.reconstruct.stage.assemble_trajectories` (today the same two-pass assembly
  as from the files; earlier versions concatenated and sorted, which peaked at 1407 MiB).

It prints the peak resident memory (``ru_maxrss``) after each tenth frame and after the
assembly, and the growth of the peak between two frames (default 50 and 100).

Usage (the figures of ``docs/reconstruction.md``)::

    .venv/bin/python benchmarks/bench_store_assembly.py --mode files --work /tmp/bsa
    .venv/bin/python benchmarks/bench_store_assembly.py --mode list --work /tmp/bsa
"""

from __future__ import annotations

import argparse
import resource
import shutil
import time
from pathlib import Path

import numpy as np


def peak_mib() -> float:
    """The process's peak resident memory so far, MiB."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--mode", choices=["files", "list"], required=True)
    ap.add_argument("--work", type=Path, required=True)
    ap.add_argument("--frames", type=int, default=100)
    ap.add_argument("--points", type=int, default=50_000)
    ap.add_argument("--cameras", type=int, default=69)
    ap.add_argument("--turnover", type=float, default=0.1)
    ap.add_argument("--at", type=int, nargs=2, default=[50, 100])
    args = ap.parse_args()

    from pointtraj.reconstruct.framestore import FrameStore
    from pointtraj.reconstruct.stage import assemble_trajectories
    from pointtraj.reconstruct.track import FrameRecord

    shutil.rmtree(args.work, ignore_errors=True)
    rng = np.random.default_rng(0)
    N, C = args.points, args.cameras
    ids = np.arange(N, dtype=np.int64)
    next_id = N
    store = FrameStore(args.work, C)
    records: list[FrameRecord] = []
    peaks = {}
    cpu0 = time.process_time()
    base = peak_mib()
    for t in range(args.frames):
        if t:
            ends = rng.random(N) < args.turnover  # (N,) trajectories that end
            ids = ids.copy()
            ids[ends] = next_id + np.arange(int(ends.sum()))
            next_id += int(ends.sum())
        vis = np.where(rng.random((N, C)) < 0.22, rng.integers(13, 256, (N, C)), 0)
        rec = FrameRecord(
            t,
            ids,
            rng.normal(size=(N, 3)).astype(np.float32),
            vis.astype(np.uint8),
            rng.random(N).astype(np.float32),
            rng.integers(0, 256, (N, 3)).astype(np.uint8),
            0,
        )
        if args.mode == "files":
            store.write_record(rec)
        else:
            records.append(rec)
        del rec, vis
        peaks[t + 1] = peak_mib()
        if (t + 1) % 10 == 0:
            print(f"after {t + 1:4d} frames: peak {peaks[t + 1]:7.0f} MiB", flush=True)
    names = [f"cam{c:02d}" for c in range(C)]
    if args.mode == "files":
        traj = store.assemble(range(args.frames), names, 30.0, args.frames)
    else:
        traj = assemble_trajectories(records, names, 30.0, args.frames)
    final = peak_mib()
    a, b = args.at
    print(
        f"\nmode {args.mode}: {args.frames} frames of {N} points and {C} cameras, "
        f"{traj.num_trajectories} trajectories, {traj.num_point_frames} point-frames; store "
        f"{sum(x.nbytes for x in (traj.xyz, traj.visibility, traj.color, traj.reprojection_error)) / 2**20:.0f} MiB"
    )
    print(
        f"peak after {a} frames {peaks[a]:.0f} MiB, after {b} frames {peaks[b]:.0f} MiB "
        f"({100 * (peaks[b] - peaks[a]) / peaks[a]:+.1f} %); after the assembly {final:.0f} MiB "
        f"(at the start {base:.0f} MiB); {time.process_time() - cpu0:.0f} CPU-s"
    )


if __name__ == "__main__":
    main()
