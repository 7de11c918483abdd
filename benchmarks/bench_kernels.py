"""Benchmark: the reconstruction's kernels on real inputs, timed and checked against stored outputs.

Two steps. ``capture`` reconstructs the first frames of a capture with the tracker and records
the inputs and outputs of the kernels as they are called (every call of the pair matcher and of
triangulation, one call in ``--every`` of the NCC and of ``CameraRig.project``), together with
the features of the first frame's images. ``time`` replays the recorded calls with the code now
importable, reports CPU seconds per call and per kernel, and checks that every output equals
the recorded one: bit for bit (``identical``), or where it differs, the largest absolute and
relative difference.

Record with one version of the code, replay with another, and the check says whether the
outputs changed; the CPU seconds of both replays, taken side by side, say how much faster.
``PYTHONPATH`` picks the version (the script itself works with both). The figures of
``docs/reconstruction.md`` ("Kernel costs"), with the old code checked out in ``/work/main``::

    PYTHONPATH=/work/main python benchmarks/bench_kernels.py capture /tmp/p69/cap \
        pipelines/paper69.toml /tmp/kernels.pkl --frames 2          # records the old outputs
    PYTHONPATH=/work/main python benchmarks/bench_kernels.py time /tmp/kernels.pkl   # before
    PYTHONPATH=. python benchmarks/bench_kernels.py time /tmp/kernels.pkl            # after

The capture step costs one reconstruction of ``--frames`` frames and writes about 1 GB (the
triangulation calls hold (C, N, 2) observations of up to 100k points). The recorded outputs are
copies taken when each call returns (callers may modify them afterwards).
"""

from __future__ import annotations

import argparse
import copy
import pickle
import time
from pathlib import Path

import numpy as np


def _kp_tuple(k) -> tuple:
    return (k.pt[0], k.pt[1], k.size, k.angle, k.response, k.octave, k.class_id)


def _features_state(f) -> dict:
    return {
        "pixels": f.pixels,
        "descriptors": f.descriptors,
        "keypoints": [_kp_tuple(k) for k in f.keypoints],
        "size": f.size,
    }


def _features(state: dict):
    import cv2

    from pointtraj.reconstruct.matching import Features

    kps = [
        cv2.KeyPoint(x=x, y=y, size=s, angle=a, response=r, octave=o, class_id=c)
        for x, y, s, a, r, o, c in state["keypoints"]
    ]
    return Features(state["pixels"], state["descriptors"], kps, tuple(state["size"]))


def capture(path: Path, config: Path, out: Path, frames: int, every: int) -> None:
    """Reconstruct ``frames`` frames and record the kernels' calls into ``out`` (pickle)."""
    from pointtraj import stages
    from pointtraj.camera import CameraRig
    from pointtraj.reconstruct import densify, matching, triangulate
    from pointtraj.reconstruct.track import Tracker
    from pointtraj.session import Capture

    cap = Capture.open(path)
    rig = cap.rig
    cfg = stages.load_reconstruct_config(config)
    rec: dict = {"capture": str(path), "config": cfg, "rig": rig, "frames": frames}
    rec.update(pairs=[], features={}, ncc=[], project=[], triangulate=[])
    counter = {"ncc": 0, "project": 0}
    frame_now = [0]

    orig_pair, orig_ncc, orig_project = matching.match_pair, densify._ncc, CameraRig.project
    orig_tri = triangulate.triangulate_ransac

    def match_pair(rig_, a, b, fa, fb, cfg_=None):
        out_ = orig_pair(rig_, a, b, fa, fb, cfg_)
        if frame_now[0] == 0:
            rec["features"].setdefault(a, _features_state(fa))
            rec["features"].setdefault(b, _features_state(fb))
            rec["pairs"].append((a, b, out_.copy()))
        return out_

    def ncc(image, other, cam, rays, z, ref, shifts=None):
        out_ = orig_ncc(image, other, cam, rays, z, ref, shifts)
        counter["ncc"] += 1
        if counter["ncc"] % every == 0:
            args = (other.name, cam.name, rays, z, ref, shifts)
            rec["ncc"].append((frame_now[0], copy.deepcopy(args), copy.deepcopy(out_)))
        return out_

    def project(self, points):
        out_ = orig_project(self, points)
        counter["project"] += 1
        if counter["project"] % every == 0 and len(self) == len(rig):
            rec["project"].append((np.array(points, dtype=np.float64), copy.deepcopy(out_)))
        return out_

    def triangulate_ransac(rig_, observations, config_=None):
        out_ = orig_tri(rig_, observations, config_)
        if len(rig_) == len(rig):
            rec["triangulate"].append((np.array(observations), config_, copy.deepcopy(out_)))
        return out_

    matching.match_pair = match_pair
    densify._ncc = ncc
    CameraRig.project = project
    triangulate.triangulate_ransac = triangulate_ransac
    try:
        tracker = Tracker(rig, cfg)
        for t in range(frames):
            frame_now[0] = t
            tracker.step(t, [cap.read(n, t) for n in rig.names])
    finally:
        matching.match_pair, densify._ncc, CameraRig.project = orig_pair, orig_ncc, orig_project
        triangulate.triangulate_ransac = orig_tri
    with open(out, "wb") as fh:
        pickle.dump(rec, fh, protocol=pickle.HIGHEST_PROTOCOL)
    print(
        f"recorded {len(rec['pairs'])} pairs, {len(rec['ncc'])} NCC, {len(rec['project'])} "
        f"project, {len(rec['triangulate'])} triangulation calls into {out}"
    )


def _compare(a, b) -> tuple[bool, float, float]:
    """(bit-identical, max abs difference, max relative difference) of two arrays or tuples."""
    if isinstance(a, tuple) or hasattr(a, "__dataclass_fields__"):
        items_a = a if isinstance(a, tuple) else [getattr(a, f) for f in a.__dataclass_fields__]
        items_b = b if isinstance(b, tuple) else [getattr(b, f) for f in b.__dataclass_fields__]
        res = [_compare(x, y) for x, y in zip(items_a, items_b)]
        return all(r[0] for r in res), max(r[1] for r in res), max(r[2] for r in res)
    a, b = np.asarray(a), np.asarray(b)
    if a.shape != b.shape:
        return False, np.inf, np.inf
    if np.array_equal(a, b, equal_nan=a.dtype.kind == "f"):
        return True, 0.0, 0.0
    if a.dtype.kind not in "fc" or b.dtype.kind not in "fc":
        return False, np.inf, np.inf
    if not np.array_equal(np.isnan(a), np.isnan(b)):
        return False, np.inf, np.inf
    fin = np.isfinite(a) & np.isfinite(b)
    d = np.abs(a[fin].astype(np.float64) - b[fin])
    rel = d / np.maximum(np.abs(a[fin]), 1e-300)
    return False, float(d.max(initial=0)), float(rel.max(initial=0))


def _report(name: str, calls: int, cpu: float, per: str, checks: list) -> None:
    same = sum(c[0] for c in checks)
    worst_abs = max((c[1] for c in checks), default=0.0)
    worst_rel = max((c[2] for c in checks), default=0.0)
    print(
        f"{name:<26} {calls:>6} calls {cpu:8.2f} CPU-s  {1e3 * cpu / max(calls, 1):8.2f} ms {per}"
        f"  identical {same}/{len(checks)}  max |diff| {worst_abs:.2e} (rel {worst_rel:.2e})"
    )


def replay(path: Path, repeat: int) -> None:
    """Time the recorded calls with the code now importable and check their outputs."""
    from pointtraj.camera import CameraRig
    from pointtraj.reconstruct import densify, matching, triangulate
    from pointtraj.session import Capture

    with open(path, "rb") as fh:
        rec = pickle.load(fh)
    rig, cfg = CameraRig(list(rec["rig"])), rec["config"]  # built by this version
    mcfg = cfg.matching
    cap = Capture.open(rec["capture"])
    print(f"{path}: {len(rig)} cameras, frames 0-{rec['frames'] - 1}, repeat {repeat}")

    # features of frame 0 (ORB), then the pair matcher on the recorded features
    images = [cap.read(n, 0) for n in rig.names]
    c0 = time.process_time()
    feats = [matching.detect_features(img, mcfg) for img in images]
    cpu = time.process_time() - c0
    checks = []
    for c, st in rec["features"].items():
        checks.append(_compare(feats[c].pixels, st["pixels"]))
        checks.append(_compare(feats[c].descriptors, st["descriptors"]))
    _report("detect_features", len(images), cpu, "an image", checks)

    stored = {c: _features(st) for c, st in rec["features"].items()}
    edges = np.array([(a, b) for a, b, _ in rec["pairs"]], dtype=np.int64)
    best = np.inf
    for _ in range(repeat):
        c0 = time.process_time()
        if hasattr(matching, "match_pairs"):  # each image's terms once (this version)
            out = matching.match_pairs(rig, stored, edges, mcfg)
        else:
            out = [matching.match_pair(rig, a, b, stored[a], stored[b], mcfg) for a, b in edges]
        best = min(best, time.process_time() - c0)
    checks = [_compare(o, p) for o, (_, _, p) in zip(out, rec["pairs"])]
    _report("match pairs (frame 0)", len(edges), best, "a pair", checks)

    by_name = {n: i for i, n in enumerate(rig.names)}
    prepared = {}

    def image(name: str, t: int) -> np.ndarray:
        i = by_name[name]
        if (i, t) not in prepared:
            grey = [_grey(cap.read(name, t))]
            prepared[i, t] = densify.prepare_images(rig.subset([i]), grey)[0]
        return prepared[i, t]

    calls = rec["ncc"]
    for t, args, _ in calls:  # prepare outside the timing
        image(args[0], t)
    best = np.inf
    for _ in range(repeat):
        c0 = time.process_time()
        outs = [
            densify._ncc(image(o, t), rig[o], rig[cname], rays, z, ref, shifts)
            for t, (o, cname, rays, z, ref, shifts), _ in calls
        ]
        best = min(best, time.process_time() - c0)
    checks = [_compare(o, r[2]) for o, r in zip(outs, calls)]
    _report("densify._ncc", len(calls), best, "a call", checks)

    best = np.inf
    for _ in range(repeat):
        c0 = time.process_time()
        outs = [rig.project(X) for X, _ in rec["project"]]
        best = min(best, time.process_time() - c0)
    checks = [_compare(o, r[1]) for o, r in zip(outs, rec["project"])]
    _report("CameraRig.project", len(outs), best, "a call", checks)

    best = np.inf
    for _ in range(repeat):
        c0 = time.process_time()
        outs = [triangulate.triangulate_ransac(rig, obs, tc) for obs, tc, _ in rec["triangulate"]]
        best = min(best, time.process_time() - c0)
    checks = [_compare(o, r[2]) for o, r in zip(outs, rec["triangulate"])]
    _report("triangulate_ransac", len(outs), best, "a call", checks)


def _grey(img: np.ndarray) -> np.ndarray:
    from pointtraj.reconstruct.flow import to_grey

    return to_grey(img)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    sub = p.add_subparsers(dest="cmd", required=True)
    c = sub.add_parser("capture", help="record the kernels' calls")
    c.add_argument("capture", type=Path)
    c.add_argument("config", type=Path)
    c.add_argument("out", type=Path)
    c.add_argument("--frames", type=int, default=2)
    c.add_argument("--every", type=int, default=25)
    t = sub.add_parser("time", help="replay, time and check the recorded calls")
    t.add_argument("record", type=Path)
    t.add_argument("--repeat", type=int, default=1)
    a = p.parse_args()
    if a.cmd == "capture":
        capture(a.capture, a.config, a.out, a.frames, a.every)
    else:
        replay(a.record, a.repeat)


if __name__ == "__main__":
    main()
