"""Reconstruction wall time, serial against a local Dask cluster, with the outputs compared.

Usage (from the repository root)::

    .venv/bin/pointtraj synth --preset paper69 --scene dribble --frames 6 \\
        --points-per-part 1000 --out /tmp/paper69_6
    .venv/bin/python benchmarks/bench_reconstruct_executor.py /tmp/paper69_6 \\
        --config pipelines/paper69.toml --frames 0:6 --chunk-frames 3 --chunk-overlap 1 \\
        --workers 2 --out /tmp/bench_reconstruct_executor

The frame range is tracked in temporal chunks (``chunk_frames``, ``chunk_overlap`` of
``[reconstruct]``; the defaults here cut frames 0-5 into two chunks, 0-2 and 3-5, the second
warmed up on frame 2, the first carrying its trajectories on over 3-5 without new points: two
tasks of about 4 frames' tracking each), once serially in this process and once on a local cluster of
``--workers`` worker processes (started before the clock, its start-up reported apart). Both
runs write a fresh work folder under ``--out``; the script prints the wall and CPU times of
each, the speed-up, and whether ``trajectories.npz`` and every cloud are byte-identical (the
chunk plan depends only on the configuration, so they must be). Exit status 1 when they
differ.

CPU time is this process's (the serial run does all its work here) plus, for the cluster, the
CPU seconds of the worker processes over the run; the kernel's share (system) is printed apart.
On a machine shared with other jobs the wall times are inflated; compare the two lines of one
run. On a freshly booted virtual machine the first touch of memory that no process has used yet
costs the kernel several seconds a GiB (``docs/scaling.md``), and every new process's heap pays
it: a high system share says so.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import shutil
import sys
import time
from pathlib import Path

import numpy as np
from bench_executor import process_cpu, workers_cpu  # (this script's folder is on sys.path)


def _same(a: Path, b: Path) -> list[str]:
    """Names of the outputs that differ between two work folders."""
    bad = []
    if (a / "trajectories.npz").read_bytes() != (b / "trajectories.npz").read_bytes():
        with np.load(a / "trajectories.npz") as x, np.load(b / "trajectories.npz") as y:
            bad += [f"trajectories.npz:{k}" for k in x.files if not np.array_equal(x[k], y[k])] or [
                "trajectories.npz (bytes)"
            ]
    ca = sorted(p.name for p in (a / "clouds").iterdir())
    cb = sorted(p.name for p in (b / "clouds").iterdir())
    if ca != cb:
        bad.append("clouds/ (different files)")
    bad += [
        f"clouds/{n}"
        for n in sorted(set(ca) & set(cb))
        if (a / "clouds" / n).read_bytes() != (b / "clouds" / n).read_bytes()
    ]
    return bad


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("capture", type=Path)
    ap.add_argument("--config", type=Path, help="TOML with a [reconstruct] table")
    ap.add_argument("--frames", default="0:6")
    ap.add_argument("--chunk-frames", type=int, default=3)
    ap.add_argument("--chunk-overlap", type=int, default=1)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", type=Path, default=Path("/tmp/bench_reconstruct_executor"))
    args = ap.parse_args()
    from pointtraj.executor import keep_arrays_on_heap

    keep_arrays_on_heap()  # in the serial run's process, as the command line and the workers
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    logging.getLogger("distributed").setLevel(logging.ERROR)
    logging.getLogger("pointtraj.reconstruct.stage").setLevel(logging.INFO)  # each chunk's times

    from pointtraj.executor import ExecutorConfig, SerialExecutor, open_executor
    from pointtraj.reconstruct.chunks import plan_chunks
    from pointtraj.session import Capture
    from pointtraj.stages import load_reconstruct_config, reconstruct_work
    from pointtraj.workdir import parse_frames

    cfg = load_reconstruct_config(args.config)
    cfg = dataclasses.replace(cfg, chunk_frames=args.chunk_frames, chunk_overlap=args.chunk_overlap)
    frames = parse_frames(args.frames, Capture.open(args.capture).num_frames)
    chunks = plan_chunks(frames, cfg.chunk_frames, cfg.chunk_overlap)
    print(
        f"capture {args.capture}, frames {frames.start}:{frames.stop}, chunk_frames "
        f"{cfg.chunk_frames}, chunk_overlap {cfg.chunk_overlap}: {len(chunks)} chunks "
        f"({', '.join(f'{c.start}-{c.stop - 1} keeping {c.boundary}-' for c in chunks)})"
    )
    if args.out.exists():
        shutil.rmtree(args.out)
    rows = []

    t0, c0 = time.perf_counter(), process_cpu()
    serial = reconstruct_work(
        args.out / "serial", args.capture, cfg, frames, executor=SerialExecutor()
    )
    rows.append(("serial", time.perf_counter() - t0, process_cpu() - c0, serial))

    t0 = time.perf_counter()
    with open_executor(ExecutorConfig(workers=args.workers)) as ex:
        startup = time.perf_counter() - t0
        logging.getLogger("distributed").setLevel(logging.ERROR)  # its import reset it
        w0 = workers_cpu(ex)
        t0, c0 = time.perf_counter(), process_cpu()
        traj = reconstruct_work(args.out / "cluster", args.capture, cfg, frames, executor=ex)
        wall, cpu = time.perf_counter() - t0, process_cpu() - c0
        cpu += workers_cpu(ex) - w0
    rows.append((f"{args.workers}-worker local cluster", wall, cpu, traj))

    print(
        f"{'run':<26}{'wall s':>9}{'CPU s':>9}{'system':>9}{'trajectories':>14}{'point-frames':>14}"
    )
    for name, wall, (user, system), t in rows:
        print(
            f"{name:<26}{wall:>9.1f}{user + system:>9.1f}{system:>9.1f}{t.num_trajectories:>14}"
            f"{t.num_point_frames:>14}"
        )
    print(f"cluster start-up (not counted): {startup:.1f} s")
    print(f"speed-up (wall): {rows[0][1] / rows[1][1]:.2f}x")
    bad = _same(args.out / "serial", args.out / "cluster")
    print("outputs identical: " + ("yes" if not bad else "NO: " + ", ".join(bad[:10])))
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
