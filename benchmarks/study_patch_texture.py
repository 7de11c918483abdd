"""Study: the patch spacing (densification's and view discovery's) chosen from each capture's texture.

For each capture, measures frames of it with :func:`pointtraj.reconstruct.texture.measure_texture_scale`
(the cameras :func:`~pointtraj.reconstruct.texture.texture_cameras` picks) and prints, for each
candidate spacing, the share of the contrast of a patch twice as wide that its patch holds,
the spacing chosen, and the CPU time of the measurement (the images' decoding left out).

Usage (the table of ``docs/real_captures.md``, "Densification's patch from the images'
texture")::

    .venv/bin/python benchmarks/study_patch_texture.py CAPTURE [CAPTURE ...] [--frames 0,50]
"""

from __future__ import annotations

import argparse
import time


def main() -> None:
    from pointtraj.reconstruct.texture import TEXTURE_HELD, texture_cameras, texture_patch_spacing
    from pointtraj.session import Capture

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("captures", nargs="+")
    ap.add_argument("--frames", default="0", help="comma-separated frames (clipped to each)")
    args = ap.parse_args()
    frames = [int(f) for f in args.frames.split(",")]
    print(
        f"the patch holds, of the contrast of one twice as wide (chosen: the smallest >= "
        f"{TEXTURE_HELD:g})"
    )
    for path in args.captures:
        cap = Capture.open(path)
        names = cap.camera_names
        w, h = cap.image_size(names[0])
        for frame in sorted({min(f, cap.num_frames - 1) for f in frames}):
            images = [cap.read(names[c], frame) for c in texture_cameras(len(names))]
            t0 = time.process_time()
            spacing, scale = texture_patch_spacing(images)
            cpu = time.process_time() - t0
            held = "  ".join(f"{s:g} px {v:.2f}" for s, v in zip(scale.spacings, scale.held))
            print(
                f"{path}  {len(names)} cameras {w}x{h}  frame {frame}:  {held}  -> {spacing:g} px"
                f"  ({scale.cameras} cameras measured, {cpu:.2f} CPU-s)"
            )


if __name__ == "__main__":
    main()
