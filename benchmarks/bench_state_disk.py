"""Benchmark: the disk a reconstructed frame costs in the work folder (state and clouds).

Reconstructs the first frames of a capture into a fresh work folder (or measures one already
made with ``--reuse``) and reports, per frame: the record file ``state/<t>.npz`` (what the store
is assembled from), the size the same frame took in the format of earlier versions (record and
the full live state, stored: measured by writing it aside), the one ``state/live.npz`` (after
the last frame), and the frame's cloud written in each ``cloud_visibility`` form, with the CPU
time of each write.

Usage (the figures of ``docs/reconstruction.md``)::

    .venv/bin/pointtraj synth --preset paper69 --scene dribble --frames 3 --out /tmp/p69/cap
    .venv/bin/python benchmarks/bench_state_disk.py /tmp/p69/cap --config pipelines/paper69.toml \\
        --frames 3 --work /tmp/p69/w_disk
"""

from __future__ import annotations

import argparse
import logging
import tempfile
import time
from pathlib import Path

import numpy as np

MB = 1e6


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("capture", type=Path)
    ap.add_argument("--config", type=Path, default=None, help="a TOML with [reconstruct]")
    ap.add_argument("--frames", type=int, default=3)
    ap.add_argument("--work", type=Path, required=True)
    ap.add_argument("--reuse", action="store_true", help="measure --work as it is")
    args = ap.parse_args()
    logging.basicConfig(level=logging.WARNING)

    from pointtraj.atomic import save_npz_atomic
    from pointtraj.reconstruct.framestore import FrameStore
    from pointtraj.reconstruct.stage import reconstruct_capture, write_frame_cloud
    from pointtraj.session import Capture
    from pointtraj.stages import load_reconstruct_config

    cap = Capture.open(args.capture)
    C = len(cap.rig)
    frames = range(args.frames)
    old_format: dict[int, float] = {}
    write_cpu: dict[int, float] = {}
    if not args.reuse:
        import shutil

        shutil.rmtree(args.work, ignore_errors=True)
        store = FrameStore(args.work, C)
        save_frame = store.save_frame

        def timed_save(record, state):  # the new files, timed; the old format written aside
            t0 = time.process_time()
            save_frame(record, state)
            write_cpu[record.frame] = time.process_time() - t0
            with tempfile.TemporaryDirectory() as tmp:
                path = Path(tmp) / "v1.npz"
                save_npz_atomic(
                    path,
                    rec_ids=record.ids,
                    rec_xyz=record.xyz,
                    rec_visibility=record.visibility,
                    rec_error=record.error,
                    rec_color=record.color,
                    live_ids=state.ids,
                    live_xyz=state.xyz,
                    live_visibility=state.visibility,
                    live_pixels=state.pixels,
                    live_lone=state.lone,
                )
                old_format[record.frame] = path.stat().st_size / MB
            print(
                f"frame {record.frame}: {len(record)} points, new files written in "
                f"{write_cpu[record.frame]:.2f} CPU-s; the format of earlier versions "
                f"{old_format[record.frame]:.1f} MB",
                flush=True,
            )

        FrameStore.save_frame = lambda self, r, s: timed_save(r, s)  # type: ignore[method-assign]
        cfg = load_reconstruct_config(args.config)
        t0 = time.process_time()
        reconstruct_capture(cap, args.work, frames, cfg)
        print(f"reconstructed {len(frames)} frames in {time.process_time() - t0:.0f} CPU-s")
    store = FrameStore(args.work, C)
    live = store.live_path.stat().st_size / MB
    print(f"{C} cameras; state/live.npz (after frame {frames[-1]}): {live:.1f} MB\n")
    forms = ("full", "uint8", "sparse")
    head = f"{'frame':>5} {'points':>8} {'record MB':>10} {'v1 state MB':>12} {'write CPU-s':>12}"
    print(head + "".join(f" {'cloud ' + f:>14}" for f in forms))
    totals = np.zeros(3 + len(forms))
    with tempfile.TemporaryDirectory() as tmp:
        for t in frames:
            rec = store.read_record(t)
            size = store.record_path(t).stat().st_size / MB
            clouds = []
            for form in forms:
                path = Path(tmp) / f"{form}.ply"
                c0 = time.process_time()
                write_frame_cloud(path, rec, form)
                clouds.append((path.stat().st_size / MB, time.process_time() - c0))
            row = [size, old_format.get(t, np.nan), write_cpu.get(t, np.nan)]
            totals += np.array(row + [c[0] for c in clouds])
            print(
                f"{t:>5} {len(rec):>8} {size:>10.2f} {row[1]:>12.1f} {row[2]:>12.2f}"
                + "".join(f" {c[0]:>7.2f} ({c[1]:.2f}s)" for c in clouds)
            )
    n = len(frames)
    print(
        f"{'mean':>5} {'':>8} {totals[0] / n:>10.2f} {totals[1] / n:>12.1f} {totals[2] / n:>12.2f}"
        + "".join(f" {x / n:>14.2f}" for x in totals[3:])
    )
    print(
        f"\nstate per frame: {totals[0] / n:.2f} MB of records, plus one live state of "
        f"{live:.1f} MB for the whole run (earlier versions: {totals[1] / n:.1f} MB a frame)"
    )


if __name__ == "__main__":
    main()
