"""Throughput of sampling + view pooling, the per-point-frame work of the semantic map.

Synthetic arrays at realistic sizes: N points in one frame seen by C cameras, K classes, and
coarse (1/8) confidence maps of 1280x1024 images. Reports point-frame-cameras per second for
bilinear sampling, for view pooling, for both, and for a whole ``build_semantic_map`` frame
(projection, sampling, view and average pooling, accumulation), and extrapolates to the paper's scale
(10^6 trajectories x 30 frames x 69 cameras x 20 classes), excluding recogniser inference.

Usage::

    .venv/bin/python benchmarks/bench_pooling.py [--points 20000] [--cameras 69] [--classes 20]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from pointtraj.camera import Camera, CameraRig
from pointtraj.semantics.pooling import pool_views
from pointtraj.semantics.recognizers.base import Recognizer
from pointtraj.semantics.sampling import sample_confidences
from pointtraj.semantics.semantic_map import SemanticsConfig, build_semantic_map
from pointtraj.trajectories import Trajectories


def best_of(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


class ArrayRecognizer(Recognizer):
    """Returns a fixed map per camera: recognition cost excluded."""

    name = "arrays"
    needs_image = False

    def __init__(self, names: list[str], maps: list[np.ndarray], K: int) -> None:
        self.maps = dict(zip(names, maps))
        self.class_names = tuple(f"class{k}" for k in range(K))

    def recognize(self, image, context=None):
        return self.maps[context.camera]


class MemoryCapture:
    def __init__(self, rig: CameraRig) -> None:
        self.rig = rig
        self.path = None

    def read(self, camera, frame):
        raise AssertionError("images are not needed")


def end_to_end(
    N: int, C: int, K: int, maps: list[np.ndarray], frames: int, visibility: str
) -> float:
    """Seconds per frame of build_semantic_map (projection, sampling, view + average pooling,
    accumulation; with ``visibility="geometric"`` also the z-buffer occlusion test) on N points
    seen by a paper69-like rig, recognition excluded."""
    rng = np.random.default_rng(1)
    cams = [
        Camera.look_at(
            f"cam{i:02d}",
            [1.6 * np.cos(a), 1.6 * np.sin(a), 1.0 if i % 2 else 2.2],
            [0.0, 0.0, 1.0],
            (1280, 1024),
            600.0,
        )
        for i, a in enumerate(np.linspace(0, 2 * np.pi, C, endpoint=False))
    ]
    rig = CameraRig(cams)
    r = 0.4 * np.sqrt(rng.random(N))
    a = rng.uniform(0, 2 * np.pi, N)
    base = np.stack([r * np.cos(a), r * np.sin(a), rng.uniform(0.2, 1.8, N)], axis=1)
    xyz = base[:, None, :] + np.linspace(0, 0.05, frames)[None, :, None]  # (N, T, 3)
    vis = np.where(rng.random((N, frames, C)) < 0.4, rng.random((N, frames, C)), 0.0)
    traj = Trajectories.from_dense(xyz, vis, camera_names=rig.names)
    rec = ArrayRecognizer(rig.names, maps, K)
    t0 = time.perf_counter()
    cfg = SemanticsConfig(sample_budget_mb=0, visibility=visibility)
    build_semantic_map(MemoryCapture(rig), traj, rec, config=cfg)
    return (time.perf_counter() - t0) / frames


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=20000)
    parser.add_argument("--cameras", type=int, default=69)
    parser.add_argument("--classes", type=int, default=20)
    parser.add_argument("--chunk", type=int, default=4096, help="points pooled at once")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--frames", type=int, default=3, help="frames of the end-to-end run")
    args = parser.parse_args()
    N, C, K = args.points, args.cameras, args.classes
    W, H = 1280, 1024
    rng = np.random.default_rng(0)
    maps = [rng.random((H // 8, W // 8, K), dtype=np.float32) for _ in range(C)]
    pixels = rng.uniform([-50, -50], [W + 50, H + 50], size=(C, N, 2)).astype(np.float32)
    V = np.where(rng.random((N, C)) < 0.4, rng.random((N, C)), 0).astype(np.float32)
    in_image = np.ones((C, N), bool)

    def sample():
        L = np.zeros((C, N, K), np.float32)
        for c in range(C):
            L[c] = sample_confidences(maps[c], pixels[c], (W, H))
        return L

    L = sample()

    def pool(method):
        for s in range(0, N, args.chunk):
            sl = slice(s, s + args.chunk)
            pool_views(L[:, sl], V[sl], 0.1, method, in_image=in_image[:, sl], camera_axis=0)

    t_e2e_obs = end_to_end(N, C, K, maps, args.frames, "observed")
    t_e2e = end_to_end(N, C, K, maps, args.frames, "geometric")
    t_sample = best_of(sample, args.repeat)
    t_view = best_of(lambda: pool("view"), args.repeat)
    t_avg = best_of(lambda: pool("average"), args.repeat)
    pfc = N * C
    total = 1e6 * 30 * 69
    scale = K / 20  # throughput measured at K classes; the target has 20
    print(f"N={N} points x C={C} cameras x K={K} classes per frame")
    for name, t in (
        ("sampling", t_sample),
        ("view pooling", t_view),
        ("average pooling", t_avg),
        ("sampling + view pooling", t_sample + t_view),
        ("build_semantic_map, observed V", t_e2e_obs),
        ("build_semantic_map, geometric V", t_e2e),
    ):
        rate = pfc / t
        print(
            f"{name:>32}: {t * 1e3:8.1f} ms/frame  {rate / 1e6:7.1f} M point-frame-cameras/s  "
            f"-> {total / rate / 60 / scale:6.1f} min for 1e6 traj x 30 frames x 69 cams"
        )


if __name__ == "__main__":
    main()
