"""Benchmark: memory of a long reconstruction, frame by frame, and of the final assembly.

Runs :func:`pointtraj.reconstruct.stage.reconstruct_capture` on a capture into a fresh work
folder and records, after each frame (its ``on_frame`` callback), the process's resident memory
(psutil) and its peak so far (``ru_maxrss``), and the CPU time; then the peak after the store
is assembled, stitched and saved. It reports the peak at two frames (default 50 and 100) and
its growth between them: the reconstruction keeps no per-frame record in memory, so the peak
should follow the live points only, not the frames done.

The same script runs on a checkout of an earlier version (``PYTHONPATH=...``) for comparison.

Usage (the figures of ``docs/reconstruction.md``: paper69's geometry at a quarter of its
resolution, 100 frames)::

    .venv/bin/pointtraj synth --preset paper69q --scene dribble --frames 100 \\
        --points-per-part 100 --out /tmp/cap69q
    .venv/bin/python benchmarks/bench_reconstruct_memory.py /tmp/cap69q \\
        --config pipelines/paper69.toml --frames 100 --work /tmp/w69q --csv /tmp/w69q.csv
"""

from __future__ import annotations

import argparse
import logging
import resource
import shutil
import time
from pathlib import Path

MB = 1 << 20


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("capture", type=Path)
    ap.add_argument("--config", type=Path, default=None, help="a TOML with [reconstruct]")
    ap.add_argument("--frames", type=int, default=100)
    ap.add_argument("--work", type=Path, required=True)
    ap.add_argument("--at", type=int, nargs=2, default=[50, 100], help="frames to compare")
    ap.add_argument("--csv", type=Path, default=None, help="per-frame figures")
    ap.add_argument(
        "--glibc-malloc",
        action="store_true",
        help="leave glibc's malloc as it is (the command line keeps large arrays on its heap)",
    )
    args = ap.parse_args()
    if not args.glibc_malloc:
        from pointtraj.executor import keep_arrays_on_heap

        keep_arrays_on_heap()
    logging.basicConfig(level=logging.WARNING)

    import psutil

    from pointtraj.reconstruct.stage import reconstruct_capture
    from pointtraj.session import Capture
    from pointtraj.stages import load_reconstruct_config

    proc = psutil.Process()
    cap = Capture.open(args.capture)
    cfg = load_reconstruct_config(args.config)
    shutil.rmtree(args.work, ignore_errors=True)
    rows: list[tuple[int, int, float, float, float]] = []
    cpu0 = time.process_time()

    def on_frame(rec) -> None:
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # KiB -> MiB
        rss = proc.memory_info().rss / MB
        rows.append((rec.frame, len(rec), rss, peak, time.process_time() - cpu0))
        t, n, r, p, c = rows[-1]
        print(
            f"frame {t:4d}: {n:7d} points, RSS {r:7.0f} MiB, peak {p:7.0f} MiB, {c:7.0f} CPU-s",
            flush=True,
        )

    traj = reconstruct_capture(cap, args.work, range(args.frames), cfg, on_frame=on_frame)
    final_peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    if args.csv:
        args.csv.write_text(
            "frame,points,rss_mib,peak_mib,cpu_s\n"
            + "".join(f"{t},{n},{r:.1f},{p:.1f},{c:.1f}\n" for t, n, r, p, c in rows)
        )
    by_frame = {t: (r, p) for t, _, r, p, _ in rows}
    a, b = args.at
    a, b = min(a, len(rows)) - 1, min(b, len(rows)) - 1  # "frame 50": after 50 frames
    pa, pb = by_frame[rows[a][0]][1], by_frame[rows[b][0]][1]
    print(
        f"\n{len(cap.rig)} cameras, {args.frames} frames, {traj.num_trajectories} trajectories, "
        f"{traj.num_point_frames} point-frames ({traj.visibility.nbytes / MB:.0f} MiB of "
        "visibility in the store)"
    )
    print(
        f"peak RSS after {a + 1} frames {pa:.0f} MiB, after {b + 1} frames {pb:.0f} MiB: "
        f"{100 * (pb - pa) / pa:+.1f} %; after the assembly {final_peak:.0f} MiB"
    )


if __name__ == "__main__":
    main()
