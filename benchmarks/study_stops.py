"""Study: why trajectories end, by their age.

The tracker counts why trajectories end (``Tracker.stops``, logged at the end of a
reconstruction with ``-v``). This study reconstructs frames ``0:N`` of a capture into a fresh
work folder with the tracker's counting wrapped, so that each ended trajectory is counted by its
reason and its age (frames since its birth): a point that dies one frame after it was born and
one that dies after 30 frames have different causes. For the trajectories that lose their flow
one frame after birth it also counts how many views they still had.

It also splits the views that tracked points lose (``view_losses``): of the (point, camera) views
observed at frame ``t - 1``, the share not observed at ``t`` because

- ``flow``: Lucas-Kanade lost it (no convergence, too little texture for its minimum eigenvalue,
  the forward-backward check, or out of the image);
- ``ransac``: the flow went on but the re-triangulation left it out of its inliers;
- ``visibility``: an inlier whose reprojection error puts ``V(X, c)`` below
  ``visibility_threshold``;
- ``point_ended``: the point ended with it (its other views were lost);
- ``dropped_later``: the point goes on without it (the occlusion test, grazing views).

The reasons are the tracker's: ``one-view`` (carried on one view by ``[reconstruct.survive]``
and not found again), ``flow`` (fewer than ``min_views`` views tracked, and not carried),
``triangulation``, ``occlusion``, ``visibility`` and ``unconfirmed`` (left with two views that
``[reconstruct.views] unconfirmed_fails`` cameras did not confirm).

Usage::

    .venv/bin/python benchmarks/study_stops.py CAPTURE WORK --config pipelines/pose2sim_demo.toml \\
        --frames 25 [densify.enabled=false ...]

Extra ``key=value`` arguments set ``[reconstruct]`` keys (``table.key`` for its tables; values in
TOML syntax).
"""

from __future__ import annotations

import argparse
import collections
import json
import shutil
from pathlib import Path

import numpy as np


def _config(path: Path | None, items: list[str]):
    """The ``[reconstruct]`` tables of ``path`` (:func:`pointtraj.stages.load_reconstruct_config`)
    with ``key=value`` items set (``table.key`` for its tables; values in TOML syntax),
    validated as a pipeline file's."""
    import tomllib

    from pointtraj import stages
    from pointtraj.config import from_mapping, to_mapping
    from pointtraj.reconstruct.config import ReconstructConfig

    table = to_mapping(stages.load_reconstruct_config(path))
    for item in items:
        key, text = item.split("=", 1)
        value = tomllib.loads(f"v = {text}")["v"]
        if "." in key:
            name, key = key.split(".", 1)
            table[name] = {**table.get(name, {}), key: value}
        else:
            table[key] = value
    return from_mapping(ReconstructConfig, table, where="[reconstruct]")


def main() -> None:
    from pointtraj.geometry import finite_rows
    from pointtraj.reconstruct import track, triangulate
    from pointtraj.reconstruct.stage import reconstruct_capture
    from pointtraj.session import Capture

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("capture", type=Path)
    ap.add_argument("work", type=Path, help="emptied first (only a work folder)")
    ap.add_argument("--config", type=Path, default=None, help="TOML with [reconstruct]")
    ap.add_argument("--frames", type=int, default=25, help="frames 0 .. N-1")
    ap.add_argument("overrides", nargs="*", help="[reconstruct] key=value")
    args = ap.parse_intermixed_args()  # key=value after the options too

    birth: dict[int, int] = {}
    ages: dict[str, list[int]] = collections.defaultdict(list)
    young_flows = np.zeros(8, np.int64)  # flow deaths at age 1, by views still tracked
    count_stops, step = track.Tracker._count_stops, track.Tracker.step

    def counted(self, obs, *args):
        # the tracker's own split (Tracker._count_stops), per trajectory
        st = self.state
        reasons = count_stops(self, obs, *args)
        age = np.array([st.frame + 1 - birth[int(i)] for i in st.ids], np.int64)
        for name, mask in reasons.items():
            ages[name].extend(age[mask].tolist())
        young = reasons["flow"] & (age == 1)
        flows = np.count_nonzero(finite_rows(obs), axis=0)
        young_flows[:] += np.bincount(np.minimum(flows[young], 7), minlength=8)
        return reasons

    losses = dict.fromkeys(
        ("views", "flow", "ransac", "visibility", "point_ended", "dropped_later"), 0
    )
    first_tri: list = []  # the step's first triangulation: the tracked points' flow
    triangulate_ransac = triangulate.triangulate_ransac

    def recorded(rig, obs, *args, **kwargs):
        tri = triangulate_ransac(rig, obs, *args, **kwargs)
        if not first_tri:
            first_tri.append((obs, tri))
        return tri

    def lost_views(self, prev, ids, t):
        """Count why the views ``prev`` (C, N) of points ``ids`` at ``t - 1`` are gone at t."""
        obs, tri = first_tri[0]
        thr = self.config.visibility_threshold
        now = self.state
        row = {i: j for j, i in enumerate(now.ids.tolist())}
        rows = np.array([row.get(i, -1) for i in ids.tolist()])
        alive = rows >= 0
        seen = np.zeros_like(prev)
        seen[:, alive] = (now.visibility[rows[alive]] > thr).T
        lost = prev & ~seen
        flowed = np.isfinite(obs[..., 0])
        kinds = {
            "flow": lost & ~flowed,
            "ransac": lost & flowed & ~tri.inliers,
            "visibility": lost & tri.inliers & (tri.visibility.T <= thr),
        }
        rest = lost & flowed & tri.inliers & (tri.visibility.T > thr)
        kinds["point_ended"] = rest & ~alive
        kinds["dropped_later"] = rest & alive
        losses["views"] += int(prev.sum())
        for name, mask in kinds.items():
            losses[name] += int(mask.sum())

    def stepped(self, t, images):
        st = self.state
        follows = st.frame == t - 1 and len(st) > 0
        prev = (st.visibility > self.config.visibility_threshold).T
        first_tri.clear()
        rec = step(self, t, images)
        if follows and first_tri:
            lost_views(self, prev, st.ids, t)
        for i in rec.ids.tolist():
            birth.setdefault(i, t)
        return rec

    track.Tracker._count_stops = counted
    track.Tracker.step = stepped
    triangulate.triangulate_ransac = recorded
    cap = Capture.open(args.capture)
    cfg = _config(args.config, args.overrides)
    if args.work.exists() and any(args.work.iterdir()) and not (args.work / "state").is_dir():
        ap.error(f"{args.work}: not empty and not a reconstruction's work folder; not emptied")
    shutil.rmtree(args.work, ignore_errors=True)
    args.work.mkdir(parents=True)
    reconstruct_capture(cap, args.work, range(args.frames), cfg)
    out = {"frames": args.frames, "overrides": args.overrides, "ended": {}}
    for name, a in ages.items():
        a = np.asarray(a, np.int64)
        out["ended"][name] = {
            "count": int(a.size),
            "by_age_1_to_8_and_more": np.bincount(np.minimum(a, 9), minlength=10)[1:].tolist(),
        }
    out["flow_at_age_1_by_views_tracked"] = young_flows[: max(2, cfg.min_views)].tolist()
    views = max(losses["views"], 1)
    out["view_losses"] = {
        "views_at_previous_frame": losses["views"],
        **{k: round(v / views, 4) for k, v in losses.items() if k != "views"},
    }
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
