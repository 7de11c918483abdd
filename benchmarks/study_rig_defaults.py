"""Study: the settings the reconstruction derives from a rig, on every kind of rig.

For each rig (the synthetic presets, a rig file given on the command line, and the narrow-field
preset's layout at room size), prints the cameras' common view (the capture volume,
:func:`pointtraj.reconstruct.connectivity.common_view`), the camera pairs kept by the defaults
(the relative cut-off in the common view) and by the earlier rule (a cube of half the median
camera distance around the point nearest the optical axes, with a fixed shared-view cut-off of
0.05), and the matching and densification settings chosen
(:func:`pointtraj.reconstruct.config.rig_choices`). No images are read: it takes a few seconds.

Usage (the table of ``docs/reconstruction.md``, "Rig-derived defaults")::

    .venv/bin/pointtraj examples fetch caliscope-board --out /tmp/board   # optional
    .venv/bin/python benchmarks/study_rig_defaults.py [/tmp/board/rig.toml ...]
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np


def wide_volume_rule_pairs(rig) -> int:
    """Pairs within 90 degrees whose shared view of the earlier cube is at least 0.05."""
    from pointtraj.reconstruct.connectivity import build_connectivity

    d = rig.R[:, 2]
    proj = np.eye(3) - d[:, :, None] * d[:, None, :]
    center = np.linalg.solve(proj.sum(axis=0), np.einsum("cij,cj->i", proj, rig.C))
    half = 0.5 * float(np.median(np.linalg.norm(rig.C - center, axis=1)))
    g = build_connectivity(rig, min_overlap=0.0, volume=np.stack([center - half, center + half]))
    return int(np.sum(g.overlap >= 0.05))


def room_sized(rig, scale: float, fov_deg: float):
    """The same layout ``scale`` times larger, every camera with a ``fov_deg`` field of view."""
    from pointtraj.camera import Camera, CameraRig

    return CameraRig(
        [
            Camera.look_at(
                c.name,
                scale * c.C,
                [0.0, 0.0, 0.0],
                tuple(c.size),
                c.width / 2 / math.tan(math.radians(fov_deg / 2)),
            )
            for c in rig
        ]
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("rigs", nargs="*", type=Path, help="rig files (any format rig convert reads)")
    args = ap.parse_args()

    from pointtraj.reconstruct.config import ReconstructConfig, rig_choices
    from pointtraj.reconstruct.connectivity import build_connectivity, common_view
    from pointtraj.rigio import load_rig
    from pointtraj.synth.presets import make_rig

    rigs = {n: make_rig(n) for n in ("tiny4", "lab4", "ring8", "ring12", "paper69", "narrow7")}
    rigs["narrow7 at room size (80 deg FOV)"] = room_sized(rigs["narrow7"], 2.4 / 0.118, 80.0)
    for path in args.rigs:
        rigs[str(path)] = load_rig(path)
    cfg = ReconstructConfig()
    print(
        "| rig | cameras | common view (capture volume) | pairs within 90 deg | kept: defaults "
        "| kept: earlier rule | matching, densification |"
    )
    print("|---|---|---|---|---|---|---|")
    for name, rig in rigs.items():
        view = common_view(rig)
        g = build_connectivity(rig, cfg.max_angle_deg, cfg.min_pair_overlap)
        angles = np.degrees(np.arccos(np.clip(rig.R[:, 2] @ rig.R[:, 2].T, -1, 1)))
        i, j = np.triu_indices(len(rig), 1)
        within = int(np.sum(angles[i, j] <= cfg.max_angle_deg + 1e-9))
        c = rig_choices(rig)
        summary = view.summary().split(": ", 1)[1]
        print(
            f"| {name} | {len(rig)} | >= {view.min_cameras} cameras: {summary} | {within} "
            f"| {g.num_edges} | {wide_volume_rule_pairs(rig)} | guided "
            f"{'on' if c.guided else 'off'}, GMS {c.gms_threshold:g}, densify "
            f"{f'on at NCC {c.densify_ncc:g} from {c.densify_seeds}' if c.densify else 'off'}, "
            f"new two-view points confirmed facing their cameras "
            f"{'on' if cfg.for_rig(rig, log=False).views.confirm_incidence_deg else 'off'} "
            f"({c.megapixels:.2f} MP, nearest partner {c.nearest_deg:.1f} deg) |"
        )


if __name__ == "__main__":
    main()
