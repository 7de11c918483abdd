"""The semantics stage serially and on a local Dask cluster, side by side, on paper69-like data.

A synthetic capture with the paper's 69-camera rig (1280x1024, ``pipelines/paper69.toml``'s
``[semantics]``: the simulated recogniser, view and average pooling) and its ground-truth
trajectories; ``semantics_work`` runs once serially (in this process) and once on a
``LocalCluster`` of ``--workers`` worker processes, one after the other in the same run. Reports
wall and CPU seconds of each (the cluster's CPU is this process's plus its workers'; the
kernel's share, system, apart: on a freshly booted virtual machine each new process's first
touch of memory costs it several seconds a GiB, ``docs/scaling.md``), the wall ratio, the
cluster's start-up apart, a second cluster run on the same (warm) workers, and checks that both
semantic maps are identical, array by array. The load average is printed: other work on the
machine inflates wall times.

Usage::

    .venv/bin/python benchmarks/bench_executor.py [--out /tmp/bench_executor] [--frames 6]
        [--points-per-part 300] [--workers 2] [--capture EXISTING_PAPER69_CAPTURE]

The capture is rendered into ``OUT/capture`` on the first run (a few minutes) and reused after.
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import time
from pathlib import Path

import numpy as np

from pointtraj.executor import ExecutorConfig, open_executor
from pointtraj.pipeline import load_pipeline
from pointtraj.stages import SynthConfig, ground_truth_work, semantics_work, synthesize

ROOT = Path(__file__).resolve().parents[1]


def process_cpu() -> np.ndarray:
    """(user, system) CPU seconds of the calling process (run on each worker too; also
    ``bench_reconstruct_executor.py``'s)."""
    r = resource.getrusage(resource.RUSAGE_SELF)
    return np.array([r.ru_utime, r.ru_stime])


def workers_cpu(executor) -> np.ndarray:
    """(user, system) CPU seconds of the workers so far, summed."""
    return np.sum(list(executor.client.run(process_cpu).values()), axis=0)


def _same_npz(a: Path, b: Path) -> list[str]:
    """The arrays that differ between two npz files (NaN equals NaN)."""
    with np.load(a) as za, np.load(b) as zb:
        if sorted(za.files) != sorted(zb.files):
            return ["(different arrays)"]
        return [
            k
            for k in za.files
            if not np.array_equal(za[k], zb[k], equal_nan=za[k].dtype.kind in "fc")
        ]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=Path("/tmp/bench_executor"))
    ap.add_argument("--capture", type=Path, help="An existing paper69 synthetic capture.")
    ap.add_argument("--frames", type=int, default=6)
    ap.add_argument("--points-per-part", type=int, default=300)
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args()
    from pointtraj.executor import keep_arrays_on_heap

    keep_arrays_on_heap()  # in the serial run's process, as the command line and the workers

    capture = args.capture
    if capture is None:
        capture = args.out / "capture"
        t0 = time.perf_counter()
        synth = SynthConfig(
            preset="paper69",
            scene="dribble",
            frames=args.frames,
            points_per_part=args.points_per_part,
        )
        summary = synthesize(capture, synth)
        if summary.rendered:
            print(f"rendered {summary.rendered} frames in {time.perf_counter() - t0:.0f} s")
    semantics = load_pipeline(ROOT / "pipelines" / "paper69.toml").semantics
    works = {}
    for name in ("serial", "cluster"):
        works[name] = args.out / f"work-{name}"
        shutil.rmtree(works[name], ignore_errors=True)
        ground_truth_work(works[name], capture)
    traj = np.load(works["serial"] / "trajectories.npz")
    print(
        f"capture {capture}: 69 cameras, {int(traj['num_frames'])} frames, "
        f"{len(traj['first_frame'])} trajectories, {len(traj['xyz'])} point-frames"
    )
    print(f"load average before: {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores")

    t0, c0 = time.perf_counter(), process_cpu()
    semantics_work(works["serial"], semantics, capture)
    serial_wall, serial_cpu = time.perf_counter() - t0, process_cpu() - c0

    t0 = time.perf_counter()
    with open_executor(ExecutorConfig(workers=args.workers, dashboard=False)) as ex:
        startup = time.perf_counter() - t0
        runs = []
        for _ in range(2):  # cold (each worker imports and makes its recogniser), then warm
            w0 = workers_cpu(ex)
            t0, c0 = time.perf_counter(), process_cpu()
            semantics_work(works["cluster"], semantics, capture, executor=ex)
            wall = time.perf_counter() - t0
            here = process_cpu() - c0
            runs.append((wall, here + workers_cpu(ex) - w0, here))
    (cluster_wall, cluster_cpu, cold_here), (warm_wall, warm_cpu, warm_here) = runs
    print(f"load average after:  {os.getloadavg()[0]:.2f}")

    differ = _same_npz(works["serial"] / "semantic_map.npz", works["cluster"] / "semantic_map.npz")
    print()
    print(f"{'semantics':22s} {'wall s':>8s} {'CPU s':>8s} {'system':>8s} {'of it here':>10s}")
    for name, wall, cpu, here in [
        ("serial", serial_wall, serial_cpu, serial_cpu),
        (f"{args.workers}-worker local cluster", cluster_wall, cluster_cpu, cold_here),
        ("  again (warm workers)", warm_wall, warm_cpu, warm_here),
    ]:
        print(f"{name:22s} {wall:8.1f} {cpu.sum():8.1f} {cpu[1]:8.1f} {here.sum():10.1f}")
    print(f"{'(cluster start-up)':22s} {startup:8.1f}")
    print()
    print(f"wall ratio serial / cluster: {serial_wall / cluster_wall:.2f}x")
    print(f"with the start-up:           {serial_wall / (cluster_wall + startup):.2f}x")
    print(f"warm workers:                {serial_wall / warm_wall:.2f}x")
    print("outputs: " + ("identical" if not differ else f"DIFFER in {', '.join(differ)}"))


if __name__ == "__main__":
    main()
