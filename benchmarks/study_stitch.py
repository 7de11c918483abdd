"""Study: are stitched trajectories the same surface point? Stitching audited against the truth.

Stitching (:mod:`pointtraj.reconstruct.stitch`) joins a trajectory that ends to one that starts
near its prediction a few frames later. On a synthetic capture the truth says whether the two
are the same point of the surface: the end of the first is carried to the start frame of the
second by the true motion of the part it lies on (the nearest triangle of the posed scene, and
that part's rigid motion), and the join's error is the distance from there to the second's start.
The same distance between consecutive frames of one trajectory is the tracker's own continuity:
a join is as good as tracking when its error is within that.

The store is assembled from a finished reconstruction's frame records (``WORK/state``), before
stitching, and stitched and trimmed as the reconstruction does, under each variant:

- ``stitch-trim``: stitching, then one-view tails trimmed (the order of ``reconstruct_capture``
  before this study);
- ``trim-stitch``: one-view tails trimmed first, so that a trajectory ends at its last
  triangulated frame, then stitching with ``max_gap`` raised by ``[reconstruct.survive] frames``
  (the frames a trimmed tail can leave between the two).

For each it prints the joins, their true error (median, 90th percentile, share within the
tracker's own 90th percentile), the trajectories and their median length, on the actors (points
within 3 cm of a figure or the ball) and over all.

Usage::

    .venv/bin/pointtraj synth --rig captures/pose2sim --up +z --at=-1.046,-0.021,0.9 --fps 60 \\
        --frames 40 --out TWIN
    .venv/bin/pointtraj reconstruct TWIN --out WORK --config pipelines/pose2sim_demo.toml
    .venv/bin/python benchmarks/study_stitch.py TWIN WORK --config pipelines/pose2sim_demo.toml
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import numpy as np


def _scene_frames(capture: Path):
    """(canonical, world) functions of the capture's true scene: a point's part and its
    coordinates in that part's frame at a frame, and back to the world at another frame."""
    import open3d as o3d

    from pointtraj.evaluate.groundtruth import SceneSurface

    surf = SceneSurface(capture)

    def poses(t: int) -> np.ndarray:
        return surf.scene.poses(t / surf.fps)

    def canonical(t: int, xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        P = poses(t)
        rs, _ = surf._renderer.build_raycasting_scene(P)
        q = o3d.core.Tensor(np.ascontiguousarray(xyz, np.float32))
        res = rs.compute_closest_points(q)
        g = res["geometry_ids"].numpy().astype(np.int64)
        p = res["points"].numpy().astype(np.float64)
        local = np.einsum("nji,nj->ni", P[g, :3, :3], p - P[g, :3, 3])
        return g, local, np.linalg.norm(p - xyz, axis=1)

    def world(t: int, g: np.ndarray, local: np.ndarray) -> np.ndarray:
        P = poses(t)
        return np.einsum("nij,nj->ni", P[g, :3, :3], local) + P[g, :3, 3]

    return canonical, world, surf.scene.labelled


def _carried_error(canonical, world, a_frame, a_xyz, b_frame, b_xyz):
    """True error of continuing a point at ``a_xyz`` (frame per row) as ``b_xyz``; the part of
    each a, and its distance to the surface."""
    err = np.full(len(a_xyz), np.nan)
    part = np.full(len(a_xyz), -1)
    off = np.full(len(a_xyz), np.nan)
    for t in np.unique(a_frame):
        rows = np.flatnonzero(a_frame == t)
        g, local, d = canonical(int(t), a_xyz[rows])
        part[rows], off[rows] = g, d
        for tb in np.unique(b_frame[rows]):
            sel = rows[b_frame[rows] == tb]
            k = np.searchsorted(rows, sel)
            err[sel] = np.linalg.norm(world(int(tb), g[k], local[k]) - b_xyz[sel], axis=1)
    return err, part, off


def _joins(before, stitched, new_id):
    """(a, b) trajectory indices of ``before`` joined consecutively in ``stitched``."""
    order = np.lexsort((before.first_frame, new_id))
    same = new_id[order][1:] == new_id[order][:-1]
    return np.stack([order[:-1][same], order[1:][same]], axis=1)


def main() -> None:
    from pointtraj import stages
    from pointtraj.atomic import write_text_atomic
    from pointtraj.reconstruct.config import ReconstructConfig
    from pointtraj.reconstruct.framestore import FrameStore
    from pointtraj.reconstruct.stitch import stitch_trajectories
    from pointtraj.reconstruct.survive import trim_one_view_tails
    from pointtraj.session import Capture

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("capture", type=Path, help="a synthetic capture (gt/synth.toml)")
    ap.add_argument("work", type=Path, help="its finished reconstruction")
    ap.add_argument("--config", type=Path, default=None, help="TOML with [reconstruct]")
    ap.add_argument("--radius", type=float, nargs="*", default=[], help="more radius_m to try")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()

    cap = Capture.open(args.capture)
    cfg = stages.load_reconstruct_config(args.config) if args.config else ReconstructConfig()
    cfg = cfg.for_rig(cap.rig)
    store = FrameStore(args.work, len(cap.rig))
    n = len(list((args.work / "state").glob("0*.npz")))
    frames = range(n)
    raw = store.assemble(frames, list(cap.rig.names), float(cap.fps), int(cap.num_frames))
    canonical, world, labelled = _scene_frames(args.capture)

    # the tracker's own continuity: consecutive rows of a trajectory
    rows = np.flatnonzero(np.diff(raw.row_track) == 0)
    rng = np.random.default_rng(0)
    rows = rng.choice(rows, min(20000, rows.size), replace=False)
    base, part, off = _carried_error(
        canonical, world, raw.row_frame[rows], raw.xyz[rows], raw.row_frame[rows + 1],
        raw.xyz[rows + 1].astype(np.float64),
    )  # fmt: skip
    actor = labelled[part] & (off < 0.03)
    p90 = float(np.nanpercentile(base[actor], 90))
    out = {
        "trajectories_before": raw.num_trajectories,
        "tracking_error_on_actors_mm": {
            "rows": int(actor.sum()),
            "median": round(1e3 * float(np.nanmedian(base[actor])), 2),
            "p90": round(1e3 * p90, 2),
        },
        "variants": {},
    }
    print(json.dumps(out["tracking_error_on_actors_mm"]))

    variants = {"stitch-trim": (cfg.stitch, False), "trim-stitch": (cfg.stitch, True)}
    for r in args.radius:
        s = dataclasses.replace(cfg.stitch, radius_m=r)
        variants[f"trim-stitch r={r}"] = (s, True)
    survive = cfg.survive.frames
    for name, (scfg, trim_first) in variants.items():
        if trim_first:
            trimmed, _ = trim_one_view_tails(raw, cfg.visibility_threshold, cfg.min_views)
            scfg = dataclasses.replace(scfg, max_gap=scfg.max_gap + survive)
            final, new_id = stitch_trajectories(trimmed, scfg)
            before = trimmed
        else:
            stitched, new_id = stitch_trajectories(raw, scfg)
            final, _ = trim_one_view_tails(stitched, cfg.visibility_threshold, cfg.min_views)
            before = raw
        pairs = _joins(before, final, new_id)
        a_end = before.offsets[1:][pairs[:, 0]] - 1
        b_start = before.offsets[:-1][pairs[:, 1]]
        err, jpart, joff = _carried_error(
            canonical, world, before.row_frame[a_end], before.xyz[a_end].astype(np.float64),
            before.row_frame[b_start], before.xyz[b_start].astype(np.float64),
        )  # fmt: skip
        on = labelled[jpart] & (joff < 0.03)
        # trajectories on the actors: most of their rows within 3 cm of a figure or the ball
        lengths = final.lengths
        res = {
            "joins": int(len(pairs)),
            "joins_on_actors": int(on.sum()),
            "join_error_on_actors_mm": {
                "median": round(1e3 * float(np.nanmedian(err[on])), 2) if on.any() else None,
                "p90": round(1e3 * float(np.nanpercentile(err[on], 90)), 2) if on.any() else None,
                "within_tracking_p90": round(float(np.mean(err[on] <= p90)), 3)
                if on.any()
                else None,
            },
            "trajectories": int(final.num_trajectories),
            "median_length": float(np.median(lengths)),
        }
        # actor trajectories: their first row on an actor
        first = final.offsets[:-1]
        g = np.full(final.num_trajectories, -1)
        d = np.full(final.num_trajectories, np.nan)
        for t in np.unique(final.first_frame):
            sel = np.flatnonzero(final.first_frame == t)
            gg, _, dd = canonical(int(t), final.xyz[first[sel]].astype(np.float64))
            g[sel], d[sel] = gg, dd
        on_tr = labelled[g] & (d < 0.03)
        res["actor_trajectories"] = int(on_tr.sum())
        res["actor_median_length"] = float(np.median(lengths[on_tr])) if on_tr.any() else None
        out["variants"][name] = res
        print(name, json.dumps(res))
    if args.json:
        write_text_atomic(args.json, json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
