"""Benchmark: memory and time of densification's prepared images under a memory budget.

:class:`pointtraj.reconstruct.densify.PreparedImages` undistorts and blurs a camera's image on
first use and keeps the prepared images within ``budget_mb``, dropping the least recently used.
This runs :func:`~pointtraj.reconstruct.densify.densify` on one frame of a synthetic capture,
grown from a fraction of the ground-truth surface points (as ``study_densify.py`` part 1), once
per budget, side by side in this process, and reports for each: the new points (they must be
the same for every budget), the images prepared (the camera count when nothing was dropped),
the peak of the images kept, the peak of all memory that numpy allocated during the call
(``tracemalloc``), and the CPU time. It first times one preparation of camera 0's image, as
the rig is and with lens distortion: the undistortion map dominates a re-preparation on real
rigs, whose cameras are distorted (the synthetic ones are not).

Usage (the figures of ``docs/reconstruction.md``)::

    .venv/bin/pointtraj synth --preset paper69 --scene dribble --frames 30 --out /tmp/p69
    .venv/bin/python benchmarks/bench_densify_memory.py /tmp/p69 --frame 5 \\
        --budgets 1024 128 32
"""

from __future__ import annotations

import argparse
import dataclasses
import time
import tracemalloc
from pathlib import Path

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("capture", type=Path, help="synthetic capture (with gt/)")
    ap.add_argument("--frame", type=int, default=5)
    ap.add_argument("--seed-fraction", type=float, default=0.1)
    ap.add_argument("--budgets", type=float, nargs="+", default=[1024.0, 128.0, 32.0])
    args = ap.parse_args()

    from study_densify import ground_truth_seeds

    from pointtraj.camera import CameraRig
    from pointtraj.reconstruct.densify import DensifyConfig, PreparedImages, densify
    from pointtraj.session import Capture

    rig = Capture.open(args.capture).rig
    X, pix, grey = ground_truth_seeds(args.capture, rig, args.frame, args.seed_fraction)
    one_mb = grey[0].size * 4 / 1e6
    print(
        f"{len(rig)} cameras, {len(X)} seeds, frame {args.frame}; one prepared image "
        f"{one_mb:.1f} MB, all of them {one_mb * len(rig):.0f} MB"
    )
    # what one (re-)preparation costs, as this rig is and with lens distortion (real rigs)
    distorted = CameraRig([dataclasses.replace(rig[0], dist=np.array([-0.2, 0.05, 0, 0, 0]))])
    for name, one_rig in (("this rig's camera 0", rig.subset([0])), ("with k1 = -0.2", distorted)):
        prep = PreparedImages(one_rig, grey[:1], 0.0)
        prep._prepare(0)  # warm up
        t0 = time.perf_counter()
        for _ in range(20):
            prep._prepare(0)
        print(f"one preparation, {name}: {(time.perf_counter() - t0) / 20 * 1000:.1f} ms wall")
    print()
    print("| budget MB | new points | images prepared | kept at most MB | numpy peak MB | CPU s |")
    print("|---:|---:|---:|---:|---:|---:|")
    reference = None
    for budget in args.budgets:
        images = _Watched(PreparedImages(rig, grey, budget))
        tracemalloc.start()
        c0 = time.process_time()
        obs = densify(rig, images, X, pix, pix, DensifyConfig(enabled=True))
        cpu = time.process_time() - c0
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        if reference is None:
            reference = obs
        same = obs.shape == reference.shape and np.array_equal(obs, reference, equal_nan=True)
        print(
            f"| {budget:g} | {obs.shape[1]}{'' if same else ' (differs!)'} | "
            f"{images.images.prepared} | {images.kept_max / 1e6:.0f} | {peak / 1e6:.0f} | "
            f"{cpu:.1f} |",
            flush=True,
        )


class _Watched:
    """PreparedImages that records the most bytes it kept at once."""

    def __init__(self, images) -> None:
        self.images = images
        self.kept_max = 0

    def __len__(self) -> int:
        return len(self.images)

    def __getitem__(self, c):
        out = self.images[c]
        self.kept_max = max(self.kept_max, self.images.nbytes)
        return out


if __name__ == "__main__":
    main()
