"""Benchmark: CPU seconds and live points per frame of the reconstruction stage.

Runs :func:`pointtraj.reconstruct.stage.reconstruct_capture` over frames ``0:N`` of a capture
into a fresh work folder and prints, per frame, the process CPU time (``time.process_time``,
which a shared machine's load inflates far less than wall time), the live points and the new
ones; then the total, the mean per frame and the peak resident memory. The work folder can then
be audited with ``study_views.py`` and ``study_reconstruct.py`` (which reuses its states).

Usage (the figures of ``docs/reconstruction.md``, "Bounded density and the back-off")::

    .venv/bin/pointtraj synth --preset paper69 --scene dribble --frames 3 --out /tmp/p69
    .venv/bin/python benchmarks/bench_reconstruct_cpu.py /tmp/p69 /tmp/p69_work \\
        --config pipelines/paper69.toml --frames 3
"""

from __future__ import annotations

import argparse
import resource
import shutil
import time
from pathlib import Path


def main() -> None:
    from pointtraj import stages
    from pointtraj.reconstruct.stage import reconstruct_capture
    from pointtraj.session import Capture

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("capture", type=Path)
    ap.add_argument("work", type=Path, help="emptied first")
    ap.add_argument("--config", type=Path, default=None, help="TOML with [reconstruct]")
    ap.add_argument("--frames", type=int, default=3, help="frames 0 .. N-1")
    ap.add_argument(
        "--glibc-malloc",
        action="store_true",
        help="leave glibc's malloc as it is (the command line keeps large arrays on its heap)",
    )
    args = ap.parse_args()
    if not args.glibc_malloc:
        from pointtraj.executor import keep_arrays_on_heap

        keep_arrays_on_heap()

    capture = Capture.open(args.capture)
    cfg = stages.load_reconstruct_config(args.config) if args.config else None
    shutil.rmtree(args.work, ignore_errors=True)
    args.work.mkdir(parents=True)
    last = [time.process_time()]
    cpu: list[float] = []

    def on_frame(rec) -> None:
        now = time.process_time()
        cpu.append(now - last[0])
        last[0] = now
        print(f"frame {rec.frame}: cpu {cpu[-1]:.1f} s, live {len(rec)}, new {rec.num_new}")

    reconstruct_capture(capture, args.work, range(args.frames), cfg, on_frame=on_frame)
    peak_gb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6
    print(f"total cpu {sum(cpu):.1f} s, mean {sum(cpu) / len(cpu):.1f} s a frame")
    print(f"peak resident memory {peak_gb:.2f} GB")


if __name__ == "__main__":
    main()
