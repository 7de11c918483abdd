"""Draw body-part overlays on Pose2Sim demo frames (the PNGs beside this file).

Usage (the Pose2Sim demo videos come from its PyPI wheel, BSD-3-Clause)::

    python -m pip download --no-deps pose2sim==0.10.49 -d /tmp/p2s
    unzip -q /tmp/p2s/pose2sim-0.10.49-py3-none-any.whl 'Pose2Sim/Demo_SinglePerson/videos/*' -d /tmp/p2s
    pointtraj models fetch body-parts
    python docs/images/make_overlays.py /tmp/p2s/Pose2Sim/Demo_SinglePerson/videos docs/images \
        cam01:10 cam02:10 cam03:10 cam04:10 cam02:50

Each overlay blends the colour of the most confident part (alpha = 0.7 x confidence) on the
full-resolution frame, marks the wrists and ankles with MediaPipe's left/right (the person's
own), draws the pose region of interest, and states the recogniser's median CPU time per image
(wall and CPU time are also printed).
"""

from __future__ import annotations

import sys
import time

import cv2
import numpy as np

from pointtraj.semantics.recognizers.bodyparts import BODY_PARTS, BodyPartRecognizer

COLORS = np.array(
    [
        [255, 215, 0], [150, 150, 150], [255, 0, 0], [0, 90, 255], [255, 130, 130],
        [120, 200, 255], [150, 0, 0], [0, 0, 150], [0, 200, 0], [200, 0, 200],
        [150, 255, 150], [255, 150, 255], [0, 100, 0], [100, 0, 100],
    ],
    dtype=np.uint8,
)  # fmt: skip


def read_frame(videos: str, cam: str, frame: int) -> np.ndarray:
    cap = cv2.VideoCapture(f"{videos}/{cam}.mp4")
    cap.set(cv2.CAP_PROP_POS_FRAMES, frame)
    ok, bgr = cap.read()
    if not ok:
        raise SystemExit(f"cannot read frame {frame} of {videos}/{cam}.mp4")
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def overlay(
    rec: BodyPartRecognizer, image: np.ndarray, label: str
) -> tuple[np.ndarray, float, float]:
    names = list(BODY_PARTS)
    rec.recognize(image)  # warm-up
    wall, cpu = [], []
    for _ in range(7):
        t, c = time.perf_counter(), time.process_time()
        maps = rec.recognize(image)
        wall.append(time.perf_counter() - t)
        cpu.append(time.process_time() - c)
    ms, cpu_ms = 1e3 * float(np.median(wall)), 1e3 * float(np.median(cpu))
    H, W = image.shape[:2]
    full = cv2.resize(maps, (W, H), interpolation=cv2.INTER_LINEAR)
    alpha = (0.7 * full.max(axis=2))[..., None]
    vis = (image * (1 - alpha) + COLORS[full.argmax(axis=2)] * alpha).astype(np.uint8)
    for pose in rec.estimate_poses(image):
        centre, up, (side, _) = pose.roi
        right = np.array([-up[1], up[0]])
        corners = [
            centre + side / 2 * (sx * right + sy * up)
            for sx, sy in ((-1, 1), (1, 1), (1, -1), (-1, -1))
        ]
        cv2.polylines(vis, [np.round(corners).astype(np.int32)], True, (255, 255, 255), 3)
        for i, text in ((15, "L wrist"), (16, "R wrist"), (27, "L ankle"), (28, "R ankle")):
            x, y = np.round(pose.landmarks[i]).astype(int)
            cv2.circle(vis, (x, y), 7, (255, 255, 255), -1)
            cv2.putText(vis, text, (x + 10, y), cv2.FONT_HERSHEY_SIMPLEX, 1.1, (255, 255, 255), 3)
    cv2.rectangle(vis, (0, 0), (330, 30 + 36 * len(names)), (0, 0, 0), -1)
    for i, name in enumerate(names):
        y = 12 + 36 * i
        cv2.rectangle(vis, (10, y), (42, y + 28), tuple(int(v) for v in COLORS[i]), -1)
        cv2.putText(vis, name, (52, y + 24), cv2.FONT_HERSHEY_SIMPLEX, 0.95, (255, 255, 255), 2)
    text = f"{label}: body-parts {cpu_ms:.0f} ms CPU"
    cv2.putText(vis, text, (10, H - 24), cv2.FONT_HERSHEY_SIMPLEX, 1.3, (255, 255, 255), 3)
    small = cv2.resize(vis, (W * 2 // 5, H * 2 // 5), interpolation=cv2.INTER_AREA)
    return small, ms, cpu_ms


def main(argv: list[str]) -> None:
    videos, out_dir, *specs = argv
    rec = BodyPartRecognizer(list(BODY_PARTS))
    for spec in specs:
        cam, frame = spec.split(":")
        image = read_frame(videos, cam, int(frame))
        png, ms, cpu_ms = overlay(rec, image, f"{cam} frame {int(frame)}")
        path = f"{out_dir}/bodyparts_{cam}_f{int(frame):03d}.png"
        cv2.imwrite(path, cv2.cvtColor(png, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_PNG_COMPRESSION, 9])
        h, w = image.shape[:2]
        sys.stdout.write(f"{path}: {w}x{h}, {ms:.1f} ms wall, {cpu_ms:.1f} ms CPU (median of 7)\n")


if __name__ == "__main__":
    main(sys.argv[1:])
