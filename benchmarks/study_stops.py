"""Study: why trajectories end, by their age.

The tracker counts why trajectories end (``Tracker.stops``, logged at the end of a
reconstruction with ``-v``). This study reconstructs frames ``0:N`` of a capture into a fresh
work folder with the tracker's counting wrapped, so that each ended trajectory is counted by its
reason and its age (frames since its birth): a point that dies one frame after it was born and
one that dies after 30 frames have different causes. For the trajectories that lose their flow
one frame after birth it also counts how many views they still had.

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
    from pointtraj.reconstruct import track
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

    def stepped(self, t, images):
        rec = step(self, t, images)
        for i in rec.ids.tolist():
            birth.setdefault(i, t)
        return rec

    track.Tracker._count_stops = counted
    track.Tracker.step = stepped
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
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
