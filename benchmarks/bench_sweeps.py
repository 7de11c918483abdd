"""Benchmark: the plane sweeps (densification, view discovery) on recorded tracker calls.

Two steps, as ``bench_kernels.py``. ``record`` reconstructs the first frames of a capture and
records every call of :func:`pointtraj.reconstruct.densify.densify` and
:func:`pointtraj.reconstruct.views.discover_views` made by the tracker: the frame's grey images
and the other inputs, and the outputs (a pickle; about 0.45 GB a frame on paper69). ``time``
replays the calls with the code now importable (``PYTHONPATH`` picks the version), reports the
CPU seconds of each (the prepared images are made before the call, outside the timing) and
whether its outputs equal the recorded ones bit for bit (``np.array_equal``, NaN equal to NaN).

The figures of ``docs/reconstruction.md`` ("Where a paper69 frame goes now")::

    PYTHONPATH=/work/main python benchmarks/bench_sweeps.py record /tmp/p14/cap \\
        pipelines/paper69.toml /tmp/sweeps.pkl --frames 2          # records main's outputs
    PYTHONPATH=/work/main python benchmarks/bench_sweeps.py time /tmp/sweeps.pkl   # before
    PYTHONPATH=. python benchmarks/bench_sweeps.py time /tmp/sweeps.pkl            # after
"""

from __future__ import annotations

import argparse
import pickle
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np


def record(capture_dir: Path, config: Path, out: Path, frames: int) -> None:
    """Reconstruct ``frames`` frames and record the sweeps' calls into ``out``."""
    import pointtraj.reconstruct.densify as densify_module
    import pointtraj.reconstruct.track as track_module
    from pointtraj import stages
    from pointtraj.reconstruct.stage import reconstruct_capture
    from pointtraj.session import Capture

    calls = []
    densify, discover = densify_module.densify, track_module.discover_views

    def copies(args) -> list:
        return [np.copy(a) if isinstance(a, np.ndarray) else a for a in args]

    def densify_rec(rig, images, *args, **kwargs):
        result = densify(rig, images, *args, **kwargs)
        calls.append(("densify", list(images.grey), copies(args), kwargs, np.copy(result)))
        return result

    def discover_rec(rig, images, *args, **kwargs):
        result = discover(rig, images, *args, **kwargs)
        out_ = tuple(np.copy(r) for r in result)
        calls.append(("discover_views", list(images.grey), copies(args), kwargs, out_))
        return result

    densify_module.densify, track_module.discover_views = densify_rec, discover_rec
    capture = Capture.open(capture_dir)
    cfg = stages.load_reconstruct_config(config)
    work = Path(tempfile.mkdtemp(prefix="bench_sweeps_"))
    try:
        reconstruct_capture(capture, work, range(frames), cfg)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    with open(out, "wb") as f:
        pickle.dump({"rig": capture.rig, "calls": calls}, f, protocol=5)
    print(f"recorded {len(calls)} calls into {out}")


def replay(path: Path) -> None:
    """Time the recorded calls with the code now importable and check their outputs."""
    import pointtraj.reconstruct.densify as densify_module
    import pointtraj.reconstruct.views as views_module

    with open(path, "rb") as f:
        rec = pickle.load(f)
    rig = rec["rig"]
    print(f"pointtraj from {densify_module.__file__}")
    totals: dict[str, float] = {}
    for name, grey, args, kwargs, expected in rec["calls"]:
        prepared = densify_module.prepare_images(rig, grey)
        for c in range(len(rig)):
            prepared[c]
        fn = densify_module.densify if name == "densify" else views_module.discover_views
        t0 = time.process_time()
        result = fn(rig, prepared, *args, **kwargs)
        cpu = time.process_time() - t0
        if name == "densify":
            same = np.array_equal(result, expected, equal_nan=True)
        else:
            same = all(np.array_equal(a, b, equal_nan=True) for a, b in zip(result, expected))
        totals[name] = totals.get(name, 0.0) + cpu
        print(f"{name}: {cpu:.2f} CPU-s, outputs {'identical' if same else 'DIFFERENT'}")
    for name, cpu in totals.items():
        print(f"total {name}: {cpu:.1f} CPU-s")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="command", required=True)
    r = sub.add_parser("record", help="reconstruct and record the sweeps' calls")
    r.add_argument("capture", type=Path)
    r.add_argument("config", type=Path, help="TOML with [reconstruct]")
    r.add_argument("out", type=Path, help="pickle to write")
    r.add_argument("--frames", type=int, default=2, help="frames 0 .. N-1")
    t = sub.add_parser("time", help="replay the recorded calls, timed and checked")
    t.add_argument("recording", type=Path)
    args = ap.parse_args()
    if args.command == "record":
        record(args.capture, args.config, args.out, args.frames)
    else:
        replay(args.recording)


if __name__ == "__main__":
    main()
