"""Draw segment frames and joint centres over a capture's camera images (the PNGs beside this).

Usage (the demo's figure in ``docs/segments.md``)::

    pointtraj demo --out /tmp/segments/demo
    pointtraj segments /tmp/segments/demo/work
    python docs/images/make_segments_overlay.py /tmp/segments/demo/work \
        docs/images/segments_demo.png cam01:30 cam03:30

Each panel is one camera's image at one frame with the labelled points alive there (class
colours, small), every segment's frame at its centroid (x red, y green, z blue, 8 cm) and the
joint centres (yellow), cropped around the labelled points and shown at twice the size; the
panels are placed side by side.
"""

from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np

from pointtraj.labelfile import load_labels
from pointtraj.labelset import LabelSet
from pointtraj.render import class_palette, draw_caption, draw_scene, draw_segments, write_png
from pointtraj.segments import load_segments
from pointtraj.session import Capture
from pointtraj.trajectories import Trajectories
from pointtraj.workdir import WorkFolder


def main() -> None:
    work, out, views = Path(sys.argv[1]), Path(sys.argv[2]), sys.argv[3:]
    wf = WorkFolder(work)
    capture = Capture.open(wf.capture_path())
    traj = Trajectories.load(wf.trajectories)
    labels = load_labels(wf.labels)
    seg = load_segments(wf.segments)
    palette = class_palette(labels.class_names, LabelSet.load(capture.labels_path))
    panels = []
    for view in views:
        cam, frame = view.split(":")
        t = int(frame)
        rows = traj.frame_rows(t)
        lab = labels.labels[traj.row_track[rows]]
        keep = lab >= 0
        camera = capture.rig[capture.camera_names.index(cam)]
        image = capture.read(cam, t)
        image = (0.6 * image + 0.4 * 255).astype(np.uint8)  # lighter, so the marks stand out
        image = draw_scene(image, camera, traj.xyz[rows][keep], palette[lab[keep]], radius=1)
        image = draw_segments(image, camera, seg, t)
        pix, _, inside = camera.project(traj.xyz[rows][keep])
        lo = np.floor(pix[inside].min(axis=0)).astype(int) - 30
        hi = np.ceil(pix[inside].max(axis=0)).astype(int) + 30
        crop = image[max(lo[1], 0) : hi[1], max(lo[0], 0) : hi[0]]
        crop = cv2.resize(crop, None, fx=2, fy=2, interpolation=cv2.INTER_NEAREST)
        panels.append(draw_caption(crop, f"{cam}, frame {t}"))
    height = max(p.shape[0] for p in panels)
    panels = [
        np.pad(p, ((0, height - p.shape[0]), (0, 0), (0, 0)), constant_values=255) for p in panels
    ]
    write_png(out, np.concatenate(panels, axis=1))
    sys.stdout.write(f"wrote {out}\n")


if __name__ == "__main__":
    main()
