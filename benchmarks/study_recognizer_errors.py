"""Study: left/right swaps by viewing direction and soft part boundaries, real recogniser and simulator.

The simulated recogniser's correlated noise model (``pointtraj.semantics.recognizers.simulated``)
takes its rates from this study. Both recognisers are measured with the same definitions:

- **viewing direction** of a (camera, frame): the angle between the figure's facing direction
  and the direction from its pelvis to the camera centre, both horizontal; *front* below 60
  degrees, *back* above 120, *side* between;
- **view flip**: the recogniser reports the whole figure left/right mirrored in the view. For
  the real recogniser: its 33 MediaPipe landmarks are mirrored (left_* and right_* exchanged)
  relative to the skeleton triangulated over the 4 cameras (each view's labelling is chosen,
  mirrored or not, to minimise the reprojection error; the skeleton's own left is fixed by its
  nose, which is in front of the shoulders). For the simulator: more than half of the lateral
  ground-truth pixels that the argmax reports as a lateral class get the other side;
- **joint swap**: at the projection of each of the 12 lateral joints (shoulders, elbows, wrists,
  hips, knees, ankles; from the triangulated skeleton, or the ground truth), the argmax of the
  confidence map (above 0.3) is a lateral class of the other side; the rate is over the joints
  whose argmax is lateral. Occlusion counts: a hidden joint's projection shows its occluder;
- **boundary band**: the width (image pixels) of the band along the argmax boundary between
  neighbouring parts where the runner-up neighbour's confidence exceeds half the winner's:
  ambiguous cells over boundary edges, times the cell size. Also in torso lengths (the torso's
  projected length, mid-shoulder to mid-hip, in the same image).

The real recogniser (``body-parts``: ``pointtraj models fetch body-parts``) runs on the Pose2Sim
``Demo_SinglePerson`` images (``pointtraj examples fetch pose2sim --out P2S``) resized so that
their longer side is ``--size`` (640, the demo's 640x512); the simulator on a synthetic capture
(``pointtraj demo`` renders one) with its default noise unless ``--sim-option`` says otherwise.

Usage (the table of ``docs/recognizers.md``)::

    nice -n 10 .venv/bin/python benchmarks/study_recognizer_errors.py --pose2sim P2S \\
        --every 4 --synthetic DEMO/capture --sim-every 15 --sim-seeds 0 1 2 3 4 5 6 7 8 9 10 11

``--sim-option model=independent`` measures the independent model instead. The real
recogniser's swaps are measured on the frames where at least two cameras see the person (its
skeleton is triangulated per frame).
"""

from __future__ import annotations

import argparse
import itertools
import json
import time
from pathlib import Path

import numpy as np

from pointtraj.reconstruct.triangulate import triangulate_points
from pointtraj.semantics.recognizers.simulated import (
    confusion_tables,
    lateral_sides,
    view_cosines,
)
from pointtraj.session import Capture

BINS = ("front", "side", "back")
JOINT_TYPES = ("shoulder", "elbow", "wrist", "hip", "knee", "ankle")
#: MediaPipe landmark pairs (left, right) of the lateral joints, in JOINT_TYPES order.
MP_JOINTS = ((11, 12), (13, 14), (15, 16), (23, 24), (25, 26), (27, 28))
MIN_CONF = 0.3


def view_bin(cos: float) -> str:
    """``front`` (within 60 degrees), ``back`` (beyond 120) or ``side``."""
    return "front" if cos > 0.5 else ("back" if cos < -0.5 else "side")


def map_cells(L2D: np.ndarray, image_shape: tuple[int, int], pixels: np.ndarray) -> np.ndarray:
    """(N, 2) int (row, col) map cells of image pixels (the sampling convention of base.py)."""
    H, W = image_shape
    h, w = L2D.shape[:2]
    x = np.rint((pixels[:, 0] + 0.5) * w / W - 0.5).astype(np.int64)
    y = np.rint((pixels[:, 1] + 0.5) * h / H - 0.5).astype(np.int64)
    return np.stack([np.clip(y, 0, h - 1), np.clip(x, 0, w - 1)], axis=1)


def joint_swaps(
    L2D: np.ndarray, image_shape: tuple[int, int], pixels: np.ndarray, side: np.ndarray, cls_side
) -> tuple[int, int]:
    """Joint projections whose argmax is lateral: (of the other side, all).

    ``pixels`` (J, 2) image pixels (NaN: skipped), ``side`` (J,) +1 left / -1 right,
    ``cls_side`` (K,) +1 / -1 / 0 per class.
    """
    ok = np.all(np.isfinite(pixels), axis=1)
    H, W = image_shape
    ok &= (pixels[:, 0] >= 0) & (pixels[:, 0] < W) & (pixels[:, 1] >= 0) & (pixels[:, 1] < H)
    if not ok.any():
        return 0, 0
    rc = map_cells(L2D, image_shape, pixels[ok])
    vals = L2D[rc[:, 0], rc[:, 1]]  # (n, K)
    arg = vals.argmax(axis=1)
    conf = vals.max(axis=1)
    s = cls_side[arg] * (conf > MIN_CONF)
    lateral = s != 0
    return int(np.sum(lateral & (s != side[ok]))), int(np.sum(lateral))


def boundary_band(L2D: np.ndarray, neighbour: np.ndarray, cell_px: float) -> tuple[float, int]:
    """Band width (image px) and boundary edges between neighbouring parts (see the docstring).

    ``neighbour`` (K, K) bool: which classes are neighbouring parts.
    """
    order = np.argsort(L2D, axis=2)
    first, second = order[..., -1], order[..., -2]  # (h, w)
    v1 = np.take_along_axis(L2D, first[..., None], 2)[..., 0]
    v2 = np.take_along_axis(L2D, second[..., None], 2)[..., 0]
    valid = v1 > MIN_CONF
    amb = valid & neighbour[first, second] & (v2 > 0.5 * v1)
    edges = 0
    for a, b, va, vb in (
        (first[:, 1:], first[:, :-1], valid[:, 1:], valid[:, :-1]),
        (first[1:], first[:-1], valid[1:], valid[:-1]),
    ):
        edges += int(np.sum(va & vb & neighbour[a, b]))
    if edges == 0:
        return float("nan"), 0
    return float(amb.sum()) / edges * cell_px, edges


def neighbour_matrix(names: list[str]) -> np.ndarray:
    """(K, K) bool: neighbouring parts (confusion_tables' neighbours)."""
    _, nbr = confusion_tables(names)
    m = np.zeros((len(names), len(names)), bool)
    for i, js in enumerate(nbr):
        m[i, js] = True
    return m


def _mirror_landmarks() -> np.ndarray:
    from pointtraj.semantics.recognizers.bodyparts import LANDMARK_NAMES

    idx = {n: i for i, n in enumerate(LANDMARK_NAMES)}
    perm = np.arange(len(LANDMARK_NAMES))
    for n, i in idx.items():
        for a, b in (
            ("left_", "right_"),
            ("right_", "left_"),
            ("_left", "_right"),
            ("_right", "_left"),
        ):
            if a in n and n.replace(a, b) in idx:
                perm[i] = idx[n.replace(a, b)]
    return perm


# -- the real recogniser on Pose2Sim ---------------------------------------------------------
def measure_real(path: Path, every: int, size: int, threads: int) -> list[dict]:
    """One record per (camera, frame) of the real body-parts recogniser on a Pose2Sim capture."""
    import cv2

    from pointtraj.semantics.recognizers.bodyparts import BODY_PARTS, BodyPartRecognizer

    cap = Capture.open(path)
    rig = cap.rig
    names = list(BODY_PARTS)
    rec = BodyPartRecognizer(names, threads=threads)
    cls_side = lateral_sides(names)
    nbr = neighbour_matrix(names)
    mirror = _mirror_landmarks()
    C = len(rig)
    frames = list(range(0, cap.num_frames, every))
    records: list[dict] = []
    for t in frames:
        obs = np.full((C, 33, 2), np.nan)
        maps, scales, shapes, torso_px = [], [], [], []
        for c, cam in enumerate(rig.names):
            img = cap.read(cam, t)
            H, W = img.shape[:2]
            s = size / max(H, W)
            small = cv2.resize(img, (round(W * s), round(H * s)), interpolation=cv2.INTER_AREA)
            poses = rec.estimate_poses(small)
            L2D, best, best_size = None, None, -1.0
            for p in poses:
                part = rec.part_maps(p, small.shape)[..., :14]
                L2D = part if L2D is None else np.maximum(L2D, part)
                ext = np.ptp(p.landmarks[:, 1])
                if ext > best_size:
                    best, best_size = p, ext
            if best is not None:
                ok = best.visibility >= 0.5
                obs[c, ok] = (best.landmarks[ok] + 0.5) / s - 0.5  # full-resolution pixels
                lm = best.landmarks
                torso_px.append(
                    float(np.linalg.norm((lm[11] + lm[12]) / 2 - (lm[23] + lm[24]) / 2))
                )
            else:
                torso_px.append(float("nan"))
            maps.append(L2D)
            scales.append(s)
            shapes.append(small.shape[:2])
        # Each view's labelling, mirrored or not, to fit the others best (view 0 fixed).
        seen = [c for c in range(C) if np.isfinite(obs[c]).any()]
        if len(seen) < 2:
            continue
        best_err, best_flip = np.inf, None
        for combo in itertools.product((0, 1), repeat=len(seen) - 1):
            flip = dict(zip(seen, (0, *combo)))
            o = obs.copy()
            for c, f in flip.items():
                if f:
                    o[c] = obs[c][mirror]
            X = triangulate_points(rig, o[:, :29])
            err = rig.reprojection_errors(X, o[:, :29])
            e = float(np.nanmean(np.minimum(err, 100.0)))
            if e < best_err:
                best_err, best_flip = e, flip
        o = obs.copy()
        for c, f in best_flip.items():
            if f:
                o[c] = obs[c][mirror]
        X = triangulate_points(rig, o)  # (33, 3)
        mid_sh, mid_hip = (X[11] + X[12]) / 2, (X[23] + X[24]) / 2
        up = mid_sh - mid_hip
        up /= np.linalg.norm(up)
        fwd = X[0] - mid_sh
        fwd -= (fwd @ up) * up
        fwd /= np.linalg.norm(fwd)
        # The skeleton's own left lies along up x forward (x forward, y left, z up).
        lat = (X[11] - X[12]) + (X[23] - X[24])
        mirrored = float(lat @ np.cross(up, fwd)) < 0
        feet = (X[31] + X[32]) / 2 - (X[29] + X[30]) / 2
        feet_agree = float(feet @ fwd) > 0
        cos = view_cosines(fwd[None, None], mid_hip[None, None], rig, up)[0, 0]  # (C,)
        left = np.array([X[r if mirrored else l] for l, r in MP_JOINTS])  # true left joints
        right = np.array([X[l if mirrored else r] for l, r in MP_JOINTS])
        joints = np.concatenate([left, right])  # (12, 3)
        jside = np.array([1] * 6 + [-1] * 6)
        proj = rig.project(joints).pixels  # (C, 12, 2) full resolution
        for c in seen:
            L2D, s = maps[c], scales[c]
            if L2D is None:
                continue
            n_sw, n_lat = joint_swaps(L2D, shapes[c], (proj[c] + 0.5) * s - 0.5, jside, cls_side)
            cell_px = shapes[c][1] / L2D.shape[1]
            band, edges = boundary_band(L2D, nbr, cell_px)
            records.append(
                dict(
                    camera=rig.names[c],
                    frame=t,
                    cos=float(cos[c]),
                    bin=view_bin(float(cos[c])),
                    flipped=bool(best_flip[c]) != mirrored,
                    joint_swaps=n_sw,
                    joint_lateral=n_lat,
                    band_px=band,
                    band_edges=edges,
                    torso_px=torso_px[c],
                    cell_px=cell_px,
                    feet_agree=feet_agree,
                    fit_px=best_err,
                )
            )
    return records


# -- the simulator on a synthetic capture ----------------------------------------------------
def measure_simulated(path: Path, every: int, options: dict) -> list[dict]:
    """One record per (camera, frame) of the simulated recogniser on a synthetic capture."""
    import cv2

    from pointtraj.labelset import LabelSet
    from pointtraj.semantics.recognizers import ImageContext, make_recognizer
    from pointtraj.synth.groundtruth import load_label_map, segment_ground_truth

    cap = Capture.open(path)
    rig = cap.rig
    labels = LabelSet.load(path / "labels.toml")
    names = list(labels.names)
    rec = make_recognizer("simulated", labels, **options)
    cls_side = lateral_sides(names)
    nbr = neighbour_matrix(names)
    seg = segment_ground_truth(path)
    torso = int(np.flatnonzero(np.array([names[k] for k in seg.part_label]) == "torso")[0])
    pose = seg.part_poses[torso]  # (T, 4, 4)
    fwd = pose[:, :3, 0]
    centre = pose[:, :3, 3]
    up = np.array([0.0, 0.0, 1.0])
    cos = view_cosines(fwd[None], centre[None], rig, up)[0]  # (T, C)
    jn = seg.joint_names
    want = [f"{s}_{j}" for s in ("left", "right") for j in JOINT_TYPES]
    jidx = [jn.index(n) for n in want]
    jside = np.array([1] * 6 + [-1] * 6)
    sh = [jn.index("left_shoulder"), jn.index("right_shoulder")]
    hp = [jn.index("left_hip"), jn.index("right_hip")]
    records = []
    for t in range(0, cap.num_frames, every):
        proj = rig.project(seg.joints[jidx, t]).pixels  # (C, 12, 2)
        tp = rig.project(
            np.stack([seg.joints[sh, t].mean(0), seg.joints[hp, t].mean(0)])
        ).pixels  # (C, 2, 2)
        for c, cam in enumerate(rig.names):
            lab = load_label_map(path, cam, t)
            L2D = rec.recognize(None, ImageContext(cam, t, str(path)))
            H, W = lab.shape
            n_sw, n_lat = joint_swaps(L2D, (H, W), proj[c], jside, cls_side)
            cell_px = W / L2D.shape[1]
            band, edges = boundary_band(L2D, nbr, cell_px)
            # View flip: the argmax side against the ground-truth side on lateral pixels.
            up_map = cv2.resize(L2D, (W, H), interpolation=cv2.INTER_NEAREST)
            arg, conf = up_map.argmax(2), up_map.max(2)
            gt_side = np.where(lab >= 0, cls_side[np.maximum(lab, 0)], 0)
            rep_side = cls_side[arg] * (conf > MIN_CONF)
            both = (gt_side != 0) & (rep_side != 0)
            flipped = bool(both.sum() > 0 and np.mean(gt_side[both] != rep_side[both]) > 0.5)
            records.append(
                dict(
                    camera=cam,
                    frame=t,
                    cos=float(cos[t, c]),
                    bin=view_bin(float(cos[t, c])),
                    flipped=flipped,
                    joint_swaps=n_sw,
                    joint_lateral=n_lat,
                    band_px=band,
                    band_edges=edges,
                    torso_px=float(np.linalg.norm(tp[c, 0] - tp[c, 1])),
                    cell_px=cell_px,
                )
            )
    return records


def summarise(records: list[dict]) -> dict:
    """Rates per viewing-direction bin and overall."""
    out = {}
    for b in (*BINS, "all"):
        rs = [r for r in records if b == "all" or r["bin"] == b]
        if not rs:
            out[b] = None
            continue
        sw = sum(r["joint_swaps"] for r in rs)
        lat = sum(r["joint_lateral"] for r in rs)
        bands = [r["band_px"] for r in rs if np.isfinite(r["band_px"])]
        rel = [
            r["band_px"] / r["torso_px"] for r in rs if np.isfinite(r["band_px"] / r["torso_px"])
        ]
        out[b] = dict(
            views=len(rs),
            view_flip=float(np.mean([r["flipped"] for r in rs])),
            joint_swap=sw / lat if lat else float("nan"),
            joints=lat,
            band_px=float(np.median(bands)) if bands else float("nan"),
            band_torso=float(np.median(rel)) if rel else float("nan"),
            torso_px=float(np.nanmedian([r["torso_px"] for r in rs])),
            cell_px=float(np.median([r["cell_px"] for r in rs])),
        )
    return out


def _table(name: str, summary: dict) -> list[str]:
    lines = []
    for b in (*BINS, "all"):
        s = summary[b]
        if s is None:
            lines.append(f"| {name} | {b} | 0 | | | | | |")
            continue
        lines.append(
            f"| {name} | {b} | {s['views']} | {100 * s['view_flip']:.1f} % | "
            f"{100 * s['joint_swap']:.1f} % ({s['joints']}) | {s['band_px']:.1f} | "
            f"{s['band_torso']:.3f} | {s['torso_px']:.0f} / {s['cell_px']:.2f} |"
        )
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pose2sim", type=Path, help="Pose2Sim capture (pointtraj examples fetch)")
    ap.add_argument("--every", type=int, default=5, help="Every n-th Pose2Sim frame.")
    ap.add_argument("--size", type=int, default=640, help="Longer image side for the real one.")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--synthetic", type=Path, help="Synthetic capture (pointtraj demo's capture/)")
    ap.add_argument("--sim-every", type=int, default=3, help="Every n-th synthetic frame.")
    ap.add_argument(
        "--sim-option",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="Simulated recogniser option, e.g. model=independent (repeatable).",
    )
    ap.add_argument(
        "--sim-seeds",
        type=int,
        nargs="+",
        default=[0, 1, 2, 3, 4],
        help="Noise seeds of the simulator (its flips are held for blocks of frames, so one "
        "short capture gives few independent draws).",
    )
    ap.add_argument("--json", type=Path, help="Write the records and summaries here.")
    args = ap.parse_args()
    results: dict = {}
    if args.pose2sim:
        t0 = time.perf_counter()
        recs = measure_real(args.pose2sim, args.every, args.size, args.threads)
        results["real"] = dict(records=recs, summary=summarise(recs))
        agree = np.mean([r["feet_agree"] for r in recs])
        print(
            f"real: {len(recs)} views in {time.perf_counter() - t0:.0f} s; facing from the "
            f"nose agrees with the feet in {100 * agree:.0f} % of the views; median "
            f"skeleton fit {np.median([r['fit_px'] for r in recs]):.1f} px"
        )
    if args.synthetic:
        opts = {}
        for kv in args.sim_option:
            k, v = kv.split("=", 1)
            try:
                opts[k] = json.loads(v)
            except json.JSONDecodeError:
                opts[k] = v
        t0 = time.perf_counter()
        recs = []
        for seed in args.sim_seeds:
            recs += measure_simulated(args.synthetic, args.sim_every, {"seed": seed, **opts})
        results["simulated"] = dict(records=recs, summary=summarise(recs), options=opts)
        print(f"simulated: {len(recs)} views in {time.perf_counter() - t0:.0f} s")
    print(
        "| recogniser | view | views | view flip | joint swap (joints) | band px | band / torso "
        "| torso px / cell px |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    for name, res in results.items():
        for line in _table(name, res["summary"]):
            print(line)
    if args.json:
        args.json.write_text(json.dumps(results, indent=1, default=float), encoding="utf-8")


if __name__ == "__main__":
    main()
