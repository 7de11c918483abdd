"""Benchmark the synthetic capture renderer on the paper's 69-camera rig.

Renders ``frames`` frames of the ``dribble`` scene with the ``paper69`` preset (69 cameras,
1280x1024) into a temporary capture folder with :func:`pointtraj.synth.render_capture`, and prints
seconds per frame split into scene building, ray casting, shading (texture, normals, noise),
ground truth (visibility rays) and writing (JPEG frames, label and depth PNGs, GT npz), plus the
process's peak resident memory (``ru_maxrss``). The first frame also bakes the solid textures
(reported separately as ``setup``).

Usage::

    .venv/bin/python benchmarks/bench_synth.py                 # paper69, 2 frames
    .venv/bin/python benchmarks/bench_synth.py --frames 3 --preset ring12 --keep /tmp/cap
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import tempfile
import time
from pathlib import Path

from pointtraj.synth import make_rig, make_scene, render_capture


def _peak_rss_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # kB on Linux


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="paper69")
    ap.add_argument("--scene", default="dribble")
    ap.add_argument("--frames", type=int, default=2)
    ap.add_argument("--points-per-part", type=int, default=1000)
    ap.add_argument("--keep", type=Path, default=None, help="Write the capture here and keep it.")
    args = ap.parse_args()

    rig = make_rig(args.preset)
    t0 = time.perf_counter()
    scene = make_scene(args.scene, seed=0)
    for g in scene.geometries:  # bake textures outside the timed frames
        _ = g.texture
    setup = time.perf_counter() - t0
    rss_setup = _peak_rss_mib()

    tmp = None
    out = args.keep
    if out is None:
        tmp = tempfile.mkdtemp(prefix="bench_synth_")
        out = Path(tmp) / "capture"
    cpu0 = time.process_time()
    try:
        # render_capture rebuilds the scene from the registry; the bake above measured its cost,
        # and the per-frame timings below exclude it (first frame) only approximately.
        summary = render_capture(
            out,
            preset=args.preset,
            scene=args.scene,
            frames=args.frames,
            points_per_part=args.points_per_part,
        )
        cpu = time.process_time() - cpu0
        size = sum(f.stat().st_size for f in Path(out).rglob("*") if f.is_file())
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)

    n = summary.rendered
    t = summary.timings
    w, h = rig[0].size
    rows = [
        ("build scene", t.build / n),
        ("ray casting", t.cast / n),
        ("shading", t.shade / n),
        ("ground truth", t.extra.get("ground_truth", 0.0) / n),
        ("writing", t.extra.get("write", 0.0) / n),
        ("total (wall)", summary.seconds_per_frame),
    ]
    print(
        f"{args.preset}: {len(rig)} cameras x {w}x{h}, scene {args.scene}, {n} frames, "
        f"{summary.gt_points} GT points"
    )
    print(f"setup (scene + texture bake): {setup:.2f} s, peak RSS after setup {rss_setup:.0f} MiB")
    print(f"{'step':<16}{'s/frame':>10}")
    for name, sec in rows:
        print(f"{name:<16}{sec:>10.2f}")
    print(f"CPU time (all threads): {cpu / n:.2f} s/frame; load average {os.getloadavg()[0]:.1f}")
    print(f"peak RSS: {_peak_rss_mib():.0f} MiB; capture size: {size / 2**20:.0f} MiB")
    rays = len(rig) * w * h
    print(f"ray-cast rate: {rays / (t.cast / n) / 1e6:.1f} Mrays/s")


if __name__ == "__main__":
    main()
