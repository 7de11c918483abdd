"""Benchmark: brute-force Hamming matching, OpenCV's BFMatcher against ``hamming_nearest``.

Detects the rig-derived ORB features of one frame of a capture in every camera, then matches
every camera pair within ``max_angle_deg`` both ways (OpenCV on its default threads and on
one, then :func:`pointtraj.reconstruct.matching.hamming_nearest`), alternating the matchers
over ``--repeats`` rounds so that a noisy machine weighs on each alike. Prints the CPU seconds
of each round and checks that every pair gets the same matches and distances from both.

Usage (the figures of ``docs/reconstruction.md``, "Brute-force matching in numpy")::

    .venv/bin/pointtraj synth --preset ring8 --scene dribble --frames 60 --out pointtraj-demo/capture
    .venv/bin/python benchmarks/bench_hamming.py pointtraj-demo/capture --frame 0 --repeats 4
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np


def main() -> None:
    import cv2

    from pointtraj.reconstruct.config import ReconstructConfig
    from pointtraj.reconstruct.matching import detect_features, hamming_nearest
    from pointtraj.reconstruct.track import config_edges
    from pointtraj.session import Capture

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("capture", type=Path)
    ap.add_argument("--frame", type=int, default=0)
    ap.add_argument("--repeats", type=int, default=4)
    args = ap.parse_args()

    cap = Capture.open(args.capture)
    cfg = ReconstructConfig().for_rig(cap.rig)
    feats = [detect_features(cap.read(n, args.frame), cfg.matching) for n in cap.rig.names]
    edges = np.asarray(config_edges(cap.rig, cfg)).reshape(-1, 2).tolist()
    sizes = [len(f) for f in feats]
    print(f"{len(edges)} pairs; features per image {min(sizes)}-{max(sizes)}")

    def opencv(a: np.ndarray, b: np.ndarray) -> tuple[list, list]:
        m = cv2.BFMatcher(cv2.NORM_HAMMING).match(a, b)
        return [[x.queryIdx, x.trainIdx] for x in m], [x.distance for x in m]

    def numpy_(a: np.ndarray, b: np.ndarray) -> tuple[list, list]:
        pairs, dist = hamming_nearest(a, b)
        return pairs.tolist(), dist.tolist()

    threads = cv2.getNumThreads()
    matchers = {
        f"OpenCV BFMatcher, {threads} threads": (opencv, threads),
        "OpenCV BFMatcher, 1 thread": (opencv, 1),
        "hamming_nearest (numpy)": (numpy_, 1),
    }
    cpu: dict[str, list[float]] = {name: [] for name in matchers}
    answers: dict[str, list] = {}
    for _ in range(args.repeats):
        for name, (fn, n) in matchers.items():
            cv2.setNumThreads(n)
            c0 = time.process_time()
            got = [fn(feats[a].descriptors, feats[b].descriptors) for a, b in edges]
            cpu[name].append(time.process_time() - c0)
            answers.setdefault(name, got)
    cv2.setNumThreads(threads)
    ref = answers[next(iter(matchers))]
    same = all(got == ref for got in answers.values())
    print("| matcher | CPU-s a round (all pairs) | per pair, median (ms) |")
    print("|---|---|---:|")
    for name, c in cpu.items():
        rounds = " / ".join(f"{v:.2f}" for v in c)
        print(f"| {name} | {rounds} | {1000 * np.median(c) / len(edges):.0f} |")
    print(f"same matches and distances from every matcher on all {len(edges)} pairs: {same}")
    if not same:
        raise SystemExit(1)


if __name__ == "__main__":
    main()
