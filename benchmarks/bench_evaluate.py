"""Benchmark: the report's costliest parts on a work folder, serially or on a local cluster.

Times (wall and CPU seconds of this process) the 3D error of every point-frame against the
ground-truth depth maps (:func:`pointtraj.evaluate.groundtruth.surface_errors`), the sample
collection of predictive validity (the recogniser on every camera of the sampled frames,
:func:`pointtraj.evaluate.validity.collect_camera_samples`) and its pooling over camera subsets
(:func:`pointtraj.evaluate.validity.predictive_validity`), with the settings of
``pointtraj evaluate``. With ``--workers 2`` the per-frame parts run on a two-worker local
Dask cluster (their CPU is then the workers', not counted here); the figures must be the same.

To compare two checkouts, run this script from each with ``PYTHONPATH=<checkout>``, side by
side (a script's own folder, not the current one, is first on ``sys.path``).

Usage (the figures of ``docs/scaling.md``, "The report at paper scale")::

    .venv/bin/python benchmarks/bench_evaluate.py WORK --frames 0:3 --workers 1
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np


def _timed(label: str, fn):
    w, c = time.perf_counter(), time.process_time()
    out = fn()
    print(f"{label}: {time.perf_counter() - w:.1f} s wall, {time.process_time() - c:.1f} CPU-s")
    return out


def main() -> None:
    from pointtraj.evaluate.groundtruth import surface_errors
    from pointtraj.evaluate.study import (
        EvaluateConfig,
        recorded_semantics_config,
        validity_samples,
    )
    from pointtraj.evaluate.validity import camera_counts, predictive_validity
    from pointtraj.executor import ExecutorConfig, open_executor
    from pointtraj.scale import scale_lengths, work_scene_scale
    from pointtraj.semantics.semantic_map import SemanticMap
    from pointtraj.session import Capture
    from pointtraj.trajectories import Trajectories
    from pointtraj.workdir import WorkFolder

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("work", type=Path)
    ap.add_argument("--frames", default=None, help="A:B, frames of the 3D error (default all)")
    ap.add_argument("--workers", type=int, default=1)
    args = ap.parse_args()

    wf = WorkFolder(args.work)
    cap = Capture.open(wf.require_capture(None))
    traj = Trajectories.load(wf.trajectories)
    rig = cap.rig.subset(traj.camera_names)
    frames = range(traj.num_frames)
    if args.frames:
        a, b = (int(x) for x in args.frames.split(":"))
        frames = range(a, b)
    cfg = EvaluateConfig()
    with open_executor(ExecutorConfig(workers=args.workers, dashboard=False)) as ex:
        err = _timed(
            f"3D error, {len(frames)} frames",
            lambda: surface_errors(cap.path, rig, traj, frames, executor=ex),
        )
        print(f"  {len(err)} point-frames, median {1e3 * np.nanmedian(err):.4f} mm")
        smap = SemanticMap.load(wf.semantic_map)
        scfg = scale_lengths(
            recorded_semantics_config(smap), work_scene_scale(wf), "[semantics]"
        )  # as evaluate_work makes it
        samples = _timed(
            "predictive validity: samples",
            lambda: validity_samples(cap, traj, rig, scfg, cfg, executor=ex),
        )
    print(f"  {samples.L.shape[0]} point-frames x {samples.L.shape[1]} cameras")
    res = _timed(
        "predictive validity: pooling",
        lambda: predictive_validity(
            samples,
            scfg.eps_e,
            poolings=cfg.validity_poolings,
            counts=camera_counts(len(rig)),
            draws=cfg.validity_draws,
            seed=cfg.seed,
        ),
    )
    top = camera_counts(len(rig))[-1]
    print("  " + ", ".join(f"{p} {d[top]:.4f}" for p, d in res.items()) + f" ({top} cameras)")


if __name__ == "__main__":
    main()
