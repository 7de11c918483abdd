"""Where true views are lost, and which points the occlusion test wrongly hides them behind
(issue #20, "Points that float hide nothing").

Usage (from the repository root)::

    .venv/bin/python benchmarks/study_occluders.py CAPTURE WORK [--frames 0,10,20,29]
        [--radius 0.03] [--depth-tol 0.01]

For each frame, the precision of the observed views of actor points, and of their truly visible
views (the audit of :mod:`pointtraj.evaluate.views`: the camera's depth map sees the point's
nearest ground-truth sample within ``--depth-tol``): the share observed (recall), and the
shares of the rest that
the tracker's occlusion test marks occluded (``ReconstructConfig()`` defaults: 5 cm, 8 px
cells, every point hiding), that face the camera at more than ``max_incidence_deg`` by the
fitted normal, and that were searchable. Then the test's false occlusions by the point in front
in the cell: floating ones (farther than ``--radius`` from the actors' surface and over 5 cm
above the floor, z = 0), with their view counts.

Where ``WORK/state/live.npz`` holds the last frame (view discovery's failure counts), the
occlusion test on that frame with every point hiding, with refuted points
(:func:`pointtraj.reconstruct.views.refuted`) hiding nothing, and with every point hiding in
cells half the size.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np


def cell_front(rig, proj, cell_px: float) -> np.ndarray:
    """(C, N) index of the nearest point in each point's z-buffer cell (-1 outside the image),
    the cells of :func:`~pointtraj.reconstruct.occlusion.occlusion_test`: which point a view
    that the test marks is hidden behind."""
    ok = proj.in_image
    C, N = ok.shape
    front = np.full((C, N), -1)
    for c in range(C):
        gw = int(np.ceil(rig.sizes[c, 0] / cell_px))
        gh = int(np.ceil(rig.sizes[c, 1] / cell_px))
        pix = np.nan_to_num(proj.pixels[c])
        cell = np.clip((pix[:, 1] + 0.5) // cell_px, 0, gh - 1).astype(np.int64) * gw + np.clip(
            (pix[:, 0] + 0.5) // cell_px, 0, gw - 1
        ).astype(np.int64)
        idx = np.flatnonzero(ok[c])
        order = idx[np.lexsort((proj.depth[c, idx], cell[idx]))]
        first = np.ones(len(order), bool)
        first[1:] = cell[order][1:] != cell[order][:-1]
        of_cell = np.full(gw * gh, -1)
        of_cell[cell[order][first]] = order[first]
        front[c] = np.where(ok[c], of_cell[cell], -1)
    return front


def frame_losses(capture: Path, rig, traj, t: int, radius: float, depth_tol: float) -> dict:
    """The loss shares and the false occlusions by occluder of frame ``t``."""
    from scipy.spatial import cKDTree

    from pointtraj.evaluate.views import frame_truth, nearest_sample
    from pointtraj.reconstruct.config import ReconstructConfig
    from pointtraj.reconstruct.occlusion import occlusion_test
    from pointtraj.reconstruct.views import _directions, point_normals
    from pointtraj.trajectories import dequantize_visibility

    cfg = ReconstructConfig()
    rows = traj.frame_rows(t)
    xyz = traj.xyz[rows].astype(np.float64)
    observed = dequantize_visibility(traj.visibility[rows]).T > cfg.visibility_threshold  # (C, N)
    truth = frame_truth(capture, rig, t, depth_tol)
    nearest, actor = nearest_sample(truth, xyz, radius)
    off, _ = cKDTree(truth.xyz).query(xyz)  # metres from the surface, every point
    proj = rig.project(xyz)
    occluded = occlusion_test(
        rig, xyz, cfg.occlusion_depth_m, cell_px=cfg.occlusion_cell_px, projection=proj
    ).T  # (C, N), the tracker's test with every point hiding
    safe = np.maximum(cell_front(rig, proj, cfg.occlusion_cell_px), 0)
    vis = truth.visible[nearest[actor]].T  # (C, A)
    obs, occ = observed[:, actor], occluded[:, actor]
    normals = point_normals(rig, xyz, observed, cfg.views.normal_neighbors)
    cos = np.einsum("cnk,nk->cn", _directions(rig, xyz), normals)[:, actor]
    grazing = cos < np.cos(np.radians(cfg.views.max_incidence_deg))
    true = int(vis.sum())
    false_occ = vis & occ
    by = safe[:, actor][false_occ]  # the point in front, per false occlusion
    floating = (off[by] > radius) & (xyz[by, 2] > 0.05)
    views = observed.sum(axis=0)
    return {
        "frame": t,
        "actor_points": int(actor.sum()),
        "true_views": true,
        "recall": float((vis & obs).sum() / true),
        "precision": float((vis & obs).sum() / max(int(obs.sum()), 1)),
        "observed_views": int(obs.sum()),
        "lost_occluded": float((vis & ~obs & occ).sum() / true),
        "lost_grazing": float((vis & ~obs & ~occ & grazing).sum() / true),
        "lost_searchable": float((vis & ~obs & ~occ & ~grazing).sum() / true),
        "false_occlusions": int(false_occ.sum()),
        "by_floating_points": int(floating.sum()),
        "floating_occluders": int(np.unique(by[floating]).size),
        "floating_off_surface_mm_median": float(1000 * np.median(off[by[floating]]))
        if floating.any()
        else float("nan"),
        "floating_views_hist": np.bincount(np.minimum(views[by[floating]], 10), minlength=11)
        .astype(int)
        .tolist(),
    }


def refuted_figures(capture: Path, work: Path, radius: float, depth_tol: float) -> dict | None:
    """The last frame's occlusion test with every point hiding and with refuted points hiding
    nothing, from ``WORK/state/live.npz`` (None when there is none)."""
    from scipy.spatial import cKDTree

    from pointtraj.evaluate.views import false_occlusion_rate, frame_truth
    from pointtraj.reconstruct.config import ReconstructConfig
    from pointtraj.reconstruct.framestore import FrameStore
    from pointtraj.reconstruct.occlusion import occlusion_test
    from pointtraj.reconstruct.views import refuted
    from pointtraj.session import Capture

    cfg = ReconstructConfig()
    rig = Capture.open(capture).rig
    st = FrameStore(work, len(rig)).read_live()
    if st is None:
        return None
    observed = st.visibility > cfg.visibility_threshold  # (N, C)
    truth = frame_truth(capture, rig, st.frame, depth_tol)
    off, _ = cKDTree(truth.xyz).query(st.xyz)
    gone = refuted(st.misses, observed.sum(axis=1), cfg.views)
    out = {"frame": st.frame, "points": len(st), "refuted": int(gone.sum())}
    floor = st.xyz[:, 2] <= 0.05  # the synthetic floor is z = 0 (it has no samples)
    out["refuted_on_actors"] = int((gone & (off <= radius)).sum())
    out["refuted_floating"] = int((gone & (off > radius) & ~floor).sum())
    out["refuted_near_floor"] = int((gone & (off > radius) & floor).sum())
    cell = cfg.occlusion_cell_px
    for name, hide, cell_px in (
        ("all_hide", None, cell),
        ("refuted_hide_nothing", ~gone, cell),
        ("all_hide_half_cells", None, cell / 2),
    ):
        occ = occlusion_test(rig, st.xyz, cfg.occlusion_depth_m, cell_px=cell_px, occluders=hide)
        a = false_occlusion_rate(
            capture, rig, st.frame, st.xyz, occ, radius, depth_tol, truth=truth
        )
        out[name] = {
            "marked": a.marked,
            "false_rate": a.false_rate,
            "recall": a.recall,
            "truly_visible_marked": a.marked_visible,
        }
    return out


def main() -> None:
    """Parse the command line and print the figures as JSON lines."""
    import json
    import logging

    from pointtraj.session import Capture
    from pointtraj.trajectories import Trajectories

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("capture", type=Path)
    ap.add_argument("work", type=Path)
    ap.add_argument("--frames", default="0,10,20,29", help="comma-separated frames")
    ap.add_argument("--radius", type=float, default=0.03)
    ap.add_argument("--depth-tol", type=float, default=0.01)
    args = ap.parse_args()
    logging.basicConfig(level=logging.WARNING)
    traj = Trajectories.load(args.work / "trajectories.npz")
    rig = Capture.open(args.capture).rig.subset(traj.camera_names)
    for t in (int(f) for f in args.frames.split(",")):
        figures = frame_losses(args.capture, rig, traj, t, args.radius, args.depth_tol)
        print(json.dumps(figures), flush=True)
    last = refuted_figures(args.capture, args.work, args.radius, args.depth_tol)
    print(json.dumps(last if last is not None else {"live_state": "none"}))


if __name__ == "__main__":
    main()
