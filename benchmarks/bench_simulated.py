"""Benchmark: CPU time of the simulated recogniser per image, and its outputs against a record.

Runs :meth:`pointtraj.semantics.recognizers.simulated.SimulatedRecognizer.recognize_people` on
a fixed set of a synthetic capture's images (cameras and frames spread evenly), once per noise
model (``correlated``, the default, and ``independent``), in one process, and reports the CPU
seconds an image of each. ``--save`` writes the outputs; ``--compare`` checks them against
such a file: how many arrays differ, and by how much. ``PYTHONPATH`` picks the version, so two
checkouts compare side by side (``docs/scaling.md``, "The simulated recogniser's cost")::

    PYTHONPATH=/path/to/before python benchmarks/bench_simulated.py CAPTURE --save /tmp/a.npz
    PYTHONPATH=. python benchmarks/bench_simulated.py CAPTURE --compare /tmp/a.npz

Run the two at the same time, or one after the other on a quiet machine, as timings are noisy.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np


def run(capture_dir: Path, images: int) -> tuple[dict[str, np.ndarray], dict[str, float]]:
    """Outputs by key (model/camera/frame/L or p) and CPU seconds an image by model."""
    from pointtraj.labelset import LabelSet
    from pointtraj.semantics.recognizers import make_recognizer
    from pointtraj.semantics.recognizers.base import ImageContext
    from pointtraj.session import Capture

    capture = Capture.open(capture_dir)
    labels = LabelSet.load(capture_dir / "labels.toml")
    names, frames = capture.camera_names, list(range(len(capture)))
    picks = [
        (names[i * len(names) // images], frames[(i * 7) % len(frames)]) for i in range(images)
    ]
    outputs, cpu = {}, {}
    for model in ("correlated", "independent"):
        rec = make_recognizer("simulated", labels, model=model)
        rec.recognize(None, ImageContext(names[0], frames[0], str(capture_dir)))  # warm caches
        t0 = time.process_time()
        for cam, frame in picks:
            conf, people = rec.recognize_people(None, ImageContext(cam, frame, str(capture_dir)))
            outputs[f"{model}/{cam}/{frame}/L"] = conf
            if people is not None:
                outputs[f"{model}/{cam}/{frame}/p"] = people
        cpu[model] = (time.process_time() - t0) / len(picks)
    return outputs, cpu


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("capture", type=Path, help="a synthetic capture folder (with gt/)")
    ap.add_argument("--images", type=int, default=40, help="images timed per model")
    ap.add_argument("--save", type=Path, help="write the outputs to this .npz")
    ap.add_argument("--compare", type=Path, help="compare the outputs with this .npz")
    args = ap.parse_args()
    outputs, cpu = run(args.capture, args.images)
    for model, s in cpu.items():
        shape = next(v.shape for k, v in outputs.items() if k.startswith(model))
        print(f"{model}: {s:.4f} CPU-s an image ({args.images} images, output {shape})")
    if args.save:
        np.savez(args.save, **outputs)
    if args.compare:
        ref = np.load(args.compare)
        if sorted(ref.files) != sorted(outputs):
            print(f"outputs: not the same images as {args.compare}")
            return
        diff = [k for k in ref.files if not np.array_equal(ref[k], outputs[k])]
        worst = max((float(np.abs(ref[k] - outputs[k]).max()) for k in diff), default=0.0)
        cells = sum(int((ref[k] != outputs[k]).sum()) for k in diff)
        print(
            f"outputs: {len(diff)} of {len(ref.files)} arrays differ from {args.compare}, "
            f"in {cells} values, by at most {worst:.3g}"
        )


if __name__ == "__main__":
    main()
