"""Study: which views view discovery searches each frame, and what it finds (issue #14).

View discovery (``[reconstruct.views]``) searches the cameras that should see a point and do not
observe it. A tracked point's camera is searched at once where its failure count is 0, and after
a back-off where it failed before (:func:`pointtraj.reconstruct.views.retry_due`). This study
reconstructs frames ``0:N`` of a capture into a fresh work folder with the tracker wrapped, and
splits each frame's searched views of tracked points by why they were due:

- ``lost``: observed at the end of the previous frame, lost at this one (count 0);
- ``fresh``: count 0 and not observed at the previous frame: the camera never searched the
  point, or did not see it at the previous frame (occluded, outside the image), which restarts
  the count;
- ``retry 1``, ``retry 2``, ``retry 3+``: due again after that many failures;

each on the floor (height below ``--floor-m``, for scenes whose floor is ``z = 0``) and above
it, with the share found by the sweep and the share kept by the re-triangulation, and the share
of points that moved less than 1 mm since the previous frame. The new points' searches are
counted apart.

On a synthetic capture (``--truth``) it also audits the tracker's last occlusion test of each
frame, the one that zeroes views before the points are kept: of the observed views it zeroes,
the share that the ground truth sees (floor points: the depth map at the point's own projection
within 2 cm; points above: the nearest ground-truth sample within 3 cm, as
:mod:`pointtraj.evaluate.views`), against the same share among the views it keeps.

Usage::

    .venv/bin/python benchmarks/study_view_search.py CAPTURE --config pipelines/paper69.toml \\
        --frames 6 [--truth] [--json out.json]
"""

from __future__ import annotations

import argparse
import collections
import json
import shutil
import tempfile
from pathlib import Path

import numpy as np

CATEGORIES = ("lost", "fresh", "retry 1", "retry 2", "retry 3+")


def main() -> None:
    import pointtraj.reconstruct.track as T
    from pointtraj import stages
    from pointtraj.evaluate.views import frame_truth, nearest_sample, true_visibility
    from pointtraj.reconstruct.stage import reconstruct_capture
    from pointtraj.session import Capture

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("capture", type=Path)
    ap.add_argument("--config", type=Path, default=None, help="TOML with [reconstruct]")
    ap.add_argument("--frames", type=int, default=6, help="frames 0 .. N-1")
    ap.add_argument("--floor-m", type=float, default=0.03, help="floor: z below this")
    ap.add_argument("--truth", action="store_true", help="audit the occlusion test (synthetic)")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()

    capture = Capture.open(args.capture)
    cfg = stages.load_reconstruct_config(args.config) if args.config else None
    ctx: dict = {}
    prev: dict = {}
    rows: list[dict] = []
    totals: dict = collections.defaultdict(lambda: np.zeros(4, np.int64))

    discover_views = T.discover_views

    def dv(rig, images, xyz, pix, cand, *a, **k):
        out, searched = discover_views(rig, images, xyz, pix, cand, *a, **k)
        unobserved = ~np.isfinite(pix[..., 0])
        ctx.update(cand=cand & unobserved, found=np.isfinite(out[..., 0]) & unobserved, xyz=xyz)
        return out, searched

    discover = T.Tracker._discover

    def disc(self, t, images, xyz, vis, err, pix, old_ids, misses, proj=None):
        ctx.update(old_ids=old_ids.copy(), misses=misses.copy())
        out = discover(self, t, images, xyz, vis, err, pix, old_ids, misses, proj)
        ctx["after"] = np.isfinite(out[3][..., 0])
        return out

    occluded = T.Tracker._occluded

    def occ(self, xyz, vis, projection=None, misses=None):
        out = occluded(self, xyz, vis, projection, misses)
        ctx["last_occlusion"] = (xyz.copy(), vis.copy(), out.copy())
        return out

    step = T.Tracker.step

    def tracked_step(self, t, images):
        record = step(self, t, images)
        row = {"frame": t}
        if "cand" in ctx:
            n = len(ctx["old_ids"])
            cand, found = ctx["cand"][:, :n], ctx["found"][:, :n]
            kept = found & ctx["after"][:, :n]
            m = ctx["misses"][:n].T.astype(np.int64)
            X = ctx["xyz"][:n]
            seen_before = np.zeros_like(cand)
            moved = np.full(n, np.inf)
            if "ids" in prev and n:
                idx = _positions(prev["ids"], ctx["old_ids"])
                ok = idx >= 0
                seen_before[:, ok] = prev["observed"][:, idx[ok]]
                moved[ok] = np.linalg.norm(X[ok] - prev["xyz"][idx[ok]], axis=1)
            floor = np.broadcast_to((X[:, 2] < args.floor_m)[None, :], cand.shape)
            still = np.broadcast_to((moved < 1e-3)[None, :], cand.shape)
            masks = {
                "lost": (m == 0) & seen_before,
                "fresh": (m == 0) & ~seen_before,
                "retry 1": m == 1,
                "retry 2": m == 2,
                "retry 3+": m >= 3,
            }
            for name, mask in masks.items():
                for where_, part in (("floor", floor), ("above", ~floor)):
                    s = cand & mask & part
                    key = f"{name}, {where_}"
                    counts = [s.sum(), (s & found).sum(), (s & kept).sum(), (s & still).sum()]
                    row[key] = [int(c) for c in counts]
                    totals[key] += counts
            new = [int(ctx["cand"][:, n:].sum()), int(ctx["found"][:, n:].sum())]
            row["new points: searched, found"] = new
            totals["new points"] += [*new, 0, 0]
        if args.truth and "last_occlusion" in ctx:
            xyz, vis, occ_ = ctx["last_occlusion"]
            observed = vis > self.config.visibility_threshold  # (N, C)
            truth = frame_truth(args.capture, self.rig, t)
            near, on_actor = nearest_sample(truth, xyz, 0.03)
            visible = truth.visible[near]  # (N, C)
            floor = xyz[:, 2] < args.floor_m
            if floor.any():
                visible[floor] = true_visibility(args.capture, self.rig, t, xyz[floor], 0.02)[0]
            for where_, part in (("floor", floor), ("above", on_actor & ~floor)):
                zeroed = observed & occ_ & part[:, None]
                kept_ = observed & ~occ_ & part[:, None]
                counts = [
                    zeroed.sum(),
                    (zeroed & visible).sum(),
                    kept_.sum(),
                    (kept_ & visible).sum(),
                ]
                row[f"occlusion zeroed, {where_}"] = [int(c) for c in counts]
                totals[f"occlusion zeroed, {where_}"] += counts
        st = self.state
        prev.update(ids=st.ids.copy(), observed=np.isfinite(st.pixels[..., 0]), xyz=st.xyz.copy())
        rows.append(row)
        _print_row(row)
        return record

    T.discover_views = dv
    T.Tracker._discover = disc
    T.Tracker._occluded = occ
    T.Tracker.step = tracked_step
    work = Path(tempfile.mkdtemp(prefix="view_search_"))
    try:
        reconstruct_capture(capture, work, range(args.frames), cfg)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    print("\nframes 1 on, searched views of tracked points:")
    print("| why due | where | searched | found | kept | point moved < 1 mm |")
    print("|---|---|---:|---:|---:|---:|")
    for key, (s, f, k, still) in totals.items():
        if key.startswith(CATEGORIES):
            name, where_ = key.split(", ")
            print(
                f"| {name} | {where_} | {s:,} | {f / max(s, 1):.3f} | {k / max(s, 1):.3f} | {still / max(s, 1):.3f} |"
            )
    if "new points" in totals:
        s, f = totals["new points"][:2]
        print(f"new points' views: {s:,} searched, {f / max(s, 1):.3f} found")
    for where_ in ("floor", "above"):
        key = f"occlusion zeroed, {where_}"
        if key in totals:
            z, zv, k, kv = totals[key]
            print(
                f"last occlusion test, {where_}: {z:,} observed views zeroed, "
                f"{zv / max(z, 1):.3f} truly visible; {k:,} kept, {kv / max(k, 1):.3f} truly visible"
            )
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))


def _positions(ids: np.ndarray, wanted: np.ndarray) -> np.ndarray:
    """(n,) position of each of ``wanted`` in ``ids`` (unique), -1 where absent."""
    if len(ids) == 0:
        return np.full(len(wanted), -1, np.int64)
    order = np.argsort(ids, kind="stable")
    pos = order[np.minimum(np.searchsorted(ids, wanted, sorter=order), len(ids) - 1)]
    return np.where(ids[pos] == wanted, pos, -1)


def _print_row(row: dict) -> None:
    parts = [f"frame {row['frame']}:"]
    for key, value in row.items():
        if key != "frame" and value and value[0]:
            parts.append(f"{key} {value}")
    print("  ".join(parts), flush=True)


if __name__ == "__main__":
    main()
