"""Write a copy of a capture as a worse camera would have filmed it: smaller, blurred, noisier.

For checking that a default chosen on one capture holds on images it was not chosen on
(``docs/reconstruction.md``, "Noisier images and real video at a lower resolution"):

- ``--scale``: every image or video frame resized (OpenCV's ``INTER_AREA``) and the rig's
  intrinsics scaled with it (focal lengths and principal point, pixel centres kept; the
  distortion, a function of normalised coordinates, is unchanged). Videos are re-encoded as
  MPEG-4 (``mp4v``).
- ``--blur``: a Gaussian blur of this sigma (px), after resizing.
- ``--noise``: Gaussian noise of this sigma (grey levels), after the blur, from one generator
  seeded by ``--seed`` and drawn camera by camera, frame by frame.
- ``--jpeg``: the quality of the JPEG files written (frame folders of JPEG images only).

Everything else in the capture folder (``capture.toml``, ``labels.toml``, ``gt/`` of a synthetic
capture) is copied as it is, so a synthetic capture's ground truth still applies where the
images were not resized.

Usage::

    .venv/bin/python benchmarks/degrade_capture.py CAPTURE OUT --noise 4 --jpeg 75 --frames 17
    .venv/bin/python benchmarks/degrade_capture.py captures/pose2sim OUT --scale 0.5
"""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path

import numpy as np

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png")
#: Written into OUT, so that a later run replaces only a folder this script wrote.
MARKER = ".degraded-capture"


def scaled_rig(rig, scale: float):
    """The rig as filmed at ``scale`` times the image size (pixel centres kept; each camera by
    :meth:`pointtraj.camera.Camera.resized`, whose size rounding :func:`degrade` follows)."""
    from pointtraj.camera import CameraRig

    return CameraRig([cam.resized(scale) for cam in rig])


def degrade(image: np.ndarray, args, rng: np.random.Generator) -> np.ndarray:
    """One image (H, W, 3) uint8 BGR, resized, blurred and made noisier."""
    import cv2

    h, w = image.shape[:2]
    out = image
    if args.scale != 1.0:
        size = (max(1, round(w * args.scale)), max(1, round(h * args.scale)))  # as Camera.resized
        out = cv2.resize(out, size, interpolation=cv2.INTER_AREA)
    out = out.astype(np.float32)
    if args.blur > 0:
        out = cv2.GaussianBlur(out, (0, 0), args.blur)
    if args.noise > 0:
        out += rng.normal(0.0, args.noise, out.shape).astype(np.float32)
    return np.clip(out + 0.5, 0, 255).astype(np.uint8)


def main() -> None:
    import cv2

    from pointtraj.rigio import load_rig, save_rig

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("capture", type=Path)
    ap.add_argument("out", type=Path, help="a new folder, or one this script wrote (replaced)")
    ap.add_argument("--scale", type=float, default=1.0)
    ap.add_argument("--blur", type=float, default=0.0, help="Gaussian sigma, px")
    ap.add_argument("--noise", type=float, default=0.0, help="Gaussian sigma, grey levels")
    ap.add_argument("--jpeg", type=int, default=95, help="JPEG quality of written images")
    ap.add_argument("--frames", type=int, default=None, help="only frames 0 .. N-1 of folders")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    if not (0 < args.scale <= 1) or args.blur < 0 or args.noise < 0 or not 1 <= args.jpeg <= 100:
        ap.error("--scale in (0, 1], --blur and --noise >= 0, --jpeg in 1-100")
    if args.out.resolve() == args.capture.resolve():
        ap.error("OUT must not be CAPTURE")
    if args.out.exists() and not (args.out / MARKER).is_file():
        if not args.out.is_dir() or any(args.out.iterdir()):
            ap.error(f"{args.out}: exists and was not written by this script; not replaced")
    frames, videos = (args.capture / "frames").resolve(), (args.capture / "videos").resolve()

    def skip(folder: str, names: list[str]) -> set[str]:
        """The images of frames/ and the videos of videos/, written below (not gt/'s maps)."""
        here = Path(folder).resolve()
        if here.parent == frames:
            return {n for n in names if Path(n).suffix.lower() in IMAGE_SUFFIXES}
        if here == videos:
            return {n for n in names if n.endswith(".mp4")}
        return set()

    shutil.rmtree(args.out, ignore_errors=True)
    shutil.copytree(args.capture, args.out, ignore=skip)
    (args.out / MARKER).write_text("written by benchmarks/degrade_capture.py\n")
    rng = np.random.default_rng(args.seed)
    written = 0
    for cam in sorted(p for p in frames.iterdir() if p.is_dir()) if frames.is_dir() else []:
        files = sorted(p for p in cam.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        for f in files[: args.frames]:
            image = cv2.imread(str(f), cv2.IMREAD_COLOR)
            if image is None:
                raise SystemExit(f"{f}: unreadable image")
            params = [cv2.IMWRITE_JPEG_QUALITY, args.jpeg] if f.suffix.lower() != ".png" else []
            target = args.out / "frames" / cam.name / f.name
            cv2.imwrite(str(target), degrade(image, args, rng), params)
            written += 1
    for video in sorted(videos.glob("*.mp4")):
        src = cv2.VideoCapture(str(video))
        fps, sink = src.get(cv2.CAP_PROP_FPS), None
        while True:
            ok, image = src.read()
            if not ok:
                break
            frame = degrade(image, args, rng)
            if sink is None:
                target = str(args.out / "videos" / video.name)
                size = (frame.shape[1], frame.shape[0])
                sink = cv2.VideoWriter(target, cv2.VideoWriter_fourcc(*"mp4v"), fps, size)
            sink.write(frame)
            written += 1
        src.release()
        if sink is None:
            raise SystemExit(f"{video}: no frame could be read")
        sink.release()
    if args.scale != 1.0:
        save_rig(scaled_rig(load_rig(args.capture / "rig.toml"), args.scale), args.out / "rig.toml")
    print(f"{written} images written to {args.out}")


if __name__ == "__main__":
    main()
