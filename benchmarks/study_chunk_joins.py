"""Joins across temporal chunk boundaries, checked against a synthetic capture's ground truth.

Usage (from the repository root)::

    printf '[reconstruct]\\nchunk_frames = 10\\nchunk_overlap = 5\\n' > /tmp/c10.toml
    .venv/bin/pointtraj reconstruct CAPTURE --frames 0:30 --out /tmp/w_c10 --config /tmp/c10.toml
    .venv/bin/pointtraj reconstruct CAPTURE --frames 0:30 --out /tmp/w_one
    .venv/bin/python benchmarks/study_chunk_joins.py CAPTURE /tmp/w_c10 /tmp/w_one

For each boundary of the chunked run (its chunks, tails and parameters are read from its work
folder): how many trajectories were alive at the frame before it, how many joined over the
overlap, how many the tail carried on and how many of those joined later, and whether the
joins are right: across a join, a
trajectory should move as its nearest ground-truth surface point moves, so the step error is
the distance between its position after the join and its position before moved by that ground-
truth point's motion. The same error of the ordinary steps of the unchunked run at the same
frame is the baseline. Then, for both runs: trajectories alive across each boundary, those of
10 frames or more, the median length, trajectories and point-frames.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("capture", type=Path)
    ap.add_argument("chunked", type=Path, help="work folder of the chunked run")
    ap.add_argument("unchunked", type=Path, help="work folder of the one-chunk run")
    args = ap.parse_args()

    from scipy.spatial import cKDTree

    from pointtraj.config import from_mapping
    from pointtraj.reconstruct.chunks import Bridge, join_boundary, join_tail, plan_chunks
    from pointtraj.reconstruct.config import ReconstructConfig
    from pointtraj.session import Capture
    from pointtraj.synth.groundtruth import load_ground_truth
    from pointtraj.trajectories import Trajectories
    from pointtraj.workdir import WorkFolder

    doc = WorkFolder(args.chunked).read_toml()
    cfg = from_mapping(ReconstructConfig, doc["reconstruct"])
    frames = range(*doc["reconstruct_run"]["frames"])
    chunks = plan_chunks(frames, cfg.chunk_frames, cfg.chunk_overlap)
    gt = load_ground_truth(args.capture)
    rig = Capture.open(args.capture).rig
    stores = [
        Trajectories.load(args.chunked / "chunks" / c.name / "trajectories.npz") for c in chunks
    ]
    one = Trajectories.load(args.unchunked / "trajectories.npz")
    tol = (cfg.chunk_join_m, 2 * cfg.ransac_threshold_px, cfg.visibility_threshold)

    def step_error(x0: np.ndarray, x1: np.ndarray, t: int) -> np.ndarray:
        """(n,) mm: x1 (at t) against x0 (at t - 1) moved as its nearest GT point moved."""
        g0, g1 = gt.xyz[:, t - 1], gt.xyz[:, t]
        ok = np.flatnonzero(np.isfinite(g0).all(1) & np.isfinite(g1).all(1))
        _, j = cKDTree(g0[ok]).query(x0)
        return 1000 * np.linalg.norm(x1 - (x0 + g1[ok[j]] - g0[ok[j]]), axis=1)

    def at(store: Trajectories, m: np.ndarray, t: np.ndarray | int) -> np.ndarray:
        return store.xyz[store.offsets[m] + (t - store.first_frame[m])].astype(np.float64)

    def stats(v: np.ndarray) -> str:
        if not len(v):
            return "none"
        return f"median {np.median(v):.1f} mm, p90 {np.percentile(v, 90):.1f} mm (n={len(v)})"

    print(f"chunks: {', '.join(c.name for c in chunks)}; chunk_join_m {cfg.chunk_join_m}")
    for k in range(1, len(chunks)):
        b = chunks[k].boundary
        before, after = stores[k - 1], stores[k]
        pairs, count = join_boundary(before, after, b, b - chunks[k].start, rig, *tol)
        joined = step_error(at(before, pairs[:, 0], b - 1), at(after, pairs[:, 1], b), b)
        tail_file = args.chunked / "chunks" / chunks[k - 1].name / "tail.npz"
        later = np.zeros(0)
        carried = 0
        if tail_file.is_file():
            br = join_tail(Bridge.load(tail_file), after, pairs[:, 0], pairs[:, 1], rig, *tol)
            carried = int(np.unique(np.concatenate([br.ids, br.joins[:, 0]])).size)
            x0 = []
            for a, _, t in br.joins:
                row = np.flatnonzero((br.ids == a) & (br.frame == t - 1))
                x0.append(br.xyz[row[0]] if row.size else at(before, np.array([a]), t - 1)[0])
            later = np.array(
                [
                    step_error(np.array([x], float), at(after, np.array([bb]), t), t)[0]
                    for x, (_, bb, t) in zip(x0, br.joins)
                ]
            )
        alive = np.flatnonzero((one.first_frame <= b - 1) & (one.last_frame >= b))
        ordinary = step_error(at(one, alive, b - 1), at(one, alive, b), b)
        print(
            f"boundary {b}: {count.ending} alive at {b - 1}; {len(pairs)} joined over the "
            f"overlap, step error {stats(joined)}; {carried} carried on past it, "
            f"{len(later)} joined later, step error {stats(later)}; unchunked steps "
            f"{b - 1}->{b}: {stats(ordinary)}"
        )
    for name, work in (("chunked", args.chunked), ("one chunk", args.unchunked)):
        t = Trajectories.load(work / "trajectories.npz")
        cross = [
            int(((t.first_frame < c.boundary) & (t.last_frame >= c.boundary)).sum())
            for c in chunks[1:]
        ]
        print(
            f"{name}: alive across the boundaries {cross}; {int((t.lengths >= 10).sum())} of "
            f"{t.num_trajectories} trajectories last 10+ frames; median length "
            f"{np.median(t.lengths):g}; {t.num_point_frames} point-frames"
        )


if __name__ == "__main__":
    main()
