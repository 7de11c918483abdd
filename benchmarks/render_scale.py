"""Renders of one labelled scene at human scale and scaled by 0.01 (a 1.2 cm subject seen from
2-3 cm), with the Open3D engine: the orbit view and a rig camera's view of each.

Run from the repository root::

    python benchmarks/render_scale.py OUT_FOLDER [--png docs/images/render_scale.png]

It prints, per scale and view, the pixels drawn (not background) and the red and blue
(labelled) pixels, and writes the four images side by side with ``--png``.
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import numpy as np

from pointtraj.camera import Camera, CameraRig
from pointtraj.labelset import LabelSet
from pointtraj.render import RenderConfig, read_png, render_work, write_png
from pointtraj.session import Capture
from pointtraj.trajectories import Trajectories

RED, BLUE = (220, 30, 30), (30, 60, 220)
SIZE = (320, 256)
T = 8


def make_work(root: Path, scale: float, rng: np.random.Generator) -> Path:
    """Two labelled clusters of 300 trajectories each (a 1.2 m scene when ``scale`` is 1)
    seen by two cameras 2-3 m away, all mapped by ``X -> scale X``."""
    cams = [
        Camera.look_at("cam0", [2.0, 0.0, 1.3], [0, 0, 1.0], SIZE, 240.0),
        Camera.look_at("cam1", [0.3, 2.5, 1.5], [0, 0, 1.0], SIZE, 240.0),
    ]
    rig = CameraRig([Camera(c.name, c.K, c.R, scale * c.C, c.size) for c in cams])
    cap = Capture.create(root / "cap", rig, fps=10.0, image_format="png")
    for c in range(len(rig)):
        for t in range(T):
            cap.write_frame(c, t, np.zeros((SIZE[1], SIZE[0], 3), np.uint8))
    LabelSet(["red_thing", "blue_thing"], [RED, BLUE]).save(root / "cap" / "labels.toml")
    lab = np.repeat([0, 1], 300)
    base = rng.normal(size=(600, 3)) * [0.08, 0.08, 0.25]
    base[:, 1] += np.where(lab == 0, -0.3, 0.3)
    base[:, 2] += 1.0
    xyz = base[:, None, :] + np.array([0, 0, 0.02])[None, None] * np.arange(T)[None, :, None]
    work = root / "work"
    work.mkdir(parents=True)
    Trajectories.from_dense(
        scale * xyz, np.ones((600, T, 2)), camera_names=rig.names, fps=10.0
    ).save(work / "trajectories.npz")
    (work / "work.toml").write_text(f'capture = "{(root / "cap").as_posix()}"\n')
    np.savez(
        work / "labels.npz",
        labels=lab.astype(np.int64),
        class_names=np.array(["red_thing", "blue_thing"]),
    )
    return work


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path)
    parser.add_argument("--png", type=Path)
    args = parser.parse_args()
    cfg = RenderConfig(
        engine="open3d", views=("orbit", "cam0"), size=SIZE, frames=(5, 6), tail=4,
        overlays=False, video=False, caption=False,
    )  # fmt: skip
    tiles = []
    for scale in (1.0, 0.01):
        work = make_work(args.out / f"scale{scale:g}", scale, np.random.default_rng(0))
        render_work(work, dataclasses.replace(cfg))
        for view in cfg.views:
            img = read_png(work / "renders" / "views" / view / "000005.png")
            drawn = int(np.any(img != 255, axis=2).sum())
            red = int(np.all(img == RED, axis=2).sum())
            blue = int(np.all(img == BLUE, axis=2).sum())
            print(f"scale {scale:g} {view:5s}: {drawn} pixels drawn, {red} red, {blue} blue")
            tiles.append(img)
    if args.png is not None:
        row = [np.concatenate([t, np.full((SIZE[1], 4, 3), 128, np.uint8)], axis=1) for t in tiles]
        write_png(args.png, np.concatenate(row, axis=1)[:, :-4])
        print(f"wrote {args.png}")


if __name__ == "__main__":
    main()
