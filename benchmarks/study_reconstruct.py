"""Accuracy, drift, coverage and density of ``pointtraj reconstruct`` on a synthetic capture.

Usage (from the repository root)::

    .venv/bin/pointtraj synth --preset ring12 --scene dribble --frames 10 --out /tmp/ring12
    .venv/bin/python benchmarks/study_reconstruct.py /tmp/ring12 --work /tmp/ring12_work \\
        [--frames 0:10] [--config my.toml] [--report report.json]

Runs the reconstruction (or resumes / reuses it in ``--work``), then measures against the ground
truth written by ``pointtraj synth``:

- **3D error**: distance from each reconstructed point to the ground-truth surface of the same
  frame (:func:`pointtraj.evaluate.groundtruth.surface_errors`: point to the plane of the GT
  depth map's pixels around its projection, the smallest over the cameras that see it); split
  into points on the actors (within ``--actor-radius`` of a GT actor point) and the rest
  (floor, background).
- **Drift**: for each trajectory that starts within ``--actor-radius`` of an actor, the local
  rigid motion of its 8 nearest GT points of the same part (Kabsch) predicts where it should be at
  its last frame; drift is the distance between prediction and reconstruction.
- **Coverage**: per GT class, the fraction of GT points seen by >= 2 cameras that have a
  reconstructed point within ``--coverage-radius``.
- **Density**: trajectories and point-frames per second, points per frame on the actors, and
  the trajectory length distribution.

With ``--board DATA`` (a real caliscope capture such as ``/work/shared/data/caliscope_board_4cam``;
``CAPTURE`` is then created with ``rig.toml`` and symlinked ``videos/`` if it has no rig) it
measures instead the trajectories on the ChArUco board: points within the extent of caliscope's
triangulated corners (plus a margin) and near their plane; trajectories with >= 80 % of their
frames there; the change of their pairwise distances over the shared lifetime (a rigid board keeps
them) and their residual to the plane::

    .venv/bin/python benchmarks/study_reconstruct.py /tmp/cal_capture --work /tmp/cal_work \
        --board /work/shared/data/caliscope_board_4cam
"""

from __future__ import annotations

import argparse
import json
import logging
import time
from pathlib import Path

import numpy as np


def actor_mask(gt, traj, frames: range, radius: float) -> np.ndarray:
    """(P,) bool: point-frames within ``radius`` of a GT actor point of their frame."""
    from scipy.spatial import cKDTree

    mask = np.zeros(traj.num_point_frames, bool)
    for t in frames:
        rows = traj.frame_rows(t)
        g = gt.xyz[:, t]
        g = g[np.all(np.isfinite(g), axis=1)]
        if rows.size == 0 or len(g) == 0:
            continue
        d, _ = cKDTree(g).query(traj.xyz[rows].astype(np.float64), k=1)
        mask[rows] = d <= radius
    return mask


def kabsch_batch(src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rigid (R, t) mapping ``src`` (B, k, 3) onto ``dst`` (B, k, 3), batched."""
    from pointtraj.geometry import fit_rigid

    fit = fit_rigid(src, dst)
    return fit.rotation, fit.translation


def drift(gt, traj, radius: float, k: int = 8) -> np.ndarray:
    """(M',) end-of-lifetime drift of trajectories that start on an actor (length >= 2)."""
    from scipy.spatial import cKDTree

    out = []
    multi = np.flatnonzero(traj.lengths >= 2)
    for t0 in np.unique(traj.first_frame[multi]):
        sel = multi[traj.first_frame[multi] == t0]
        g0 = gt.xyz[:, t0].astype(np.float64)
        ok = np.all(np.isfinite(g0), axis=1)
        idx = np.flatnonzero(ok)
        tree = cKDTree(g0[idx])
        x0 = traj.xyz[traj.offsets[sel]].astype(np.float64)
        d, nn = tree.query(x0, k=1)
        on = d <= radius
        sel, x0, nn = sel[on], x0[on], nn[on]
        if sel.size == 0:
            continue
        part = gt.geometry[idx[nn]]
        _, nbr = tree.query(x0, k=4 * k)  # candidates, then keep the same part
        nbr_part = gt.geometry[idx[nbr]]
        order = np.argsort(nbr_part != part[:, None], axis=1, kind="stable")[:, :k]
        nbr = idx[np.take_along_axis(nbr, order, axis=1)]  # (B, k) GT point ids
        t1 = traj.last_frame[sel]
        src = g0[nbr]
        dst = gt.xyz[nbr, t1[:, None]].astype(np.float64)  # (B, k, 3)
        good = np.all(np.isfinite(dst), axis=(1, 2))
        R, t = kabsch_batch(src[good], dst[good])
        pred = np.einsum("bij,bj->bi", R, x0[good]) + t
        x1 = traj.xyz[traj.offsets[sel[good] + 1] - 1].astype(np.float64)
        out.append(np.linalg.norm(x1 - pred, axis=1))
    return np.concatenate(out) if out else np.zeros(0)


def coverage(gt, traj, frames: range, radius: float) -> dict[str, float]:
    """Per class: fraction of GT points seen by >= 2 cameras with a reconstructed point nearby."""
    from scipy.spatial import cKDTree

    hit = np.zeros(len(gt.class_names))
    tot = np.zeros(len(gt.class_names))
    for t in frames:
        seen = gt.visible[:, t].sum(axis=1) >= 2
        g = gt.xyz[seen, t].astype(np.float64)
        fs = traj.frame(t)
        if len(g) == 0:
            continue
        if len(fs.xyz):
            d, _ = cKDTree(fs.xyz.astype(np.float64)).query(g, k=1)
            np.add.at(hit, gt.label[seen], d <= radius)
        np.add.at(tot, gt.label[seen], 1)
    return {n: float(h / c) for n, h, c in zip(gt.class_names, hit, tot) if c > 0}


def evaluate(capture_dir: Path, traj, frames: range, args) -> dict:
    from pointtraj.evaluate.groundtruth import surface_errors
    from pointtraj.session import Capture
    from pointtraj.synth.groundtruth import load_ground_truth

    cap = Capture.open(capture_dir)
    gt = load_ground_truth(capture_dir)
    rig = cap.rig.subset(traj.camera_names)
    err = surface_errors(capture_dir, rig, traj, frames)
    rows = np.concatenate([traj.frame_rows(t) for t in frames])
    on_actor = actor_mask(gt, traj, frames, args.actor_radius)[rows]
    actors = int(on_actor.sum())
    none = np.isnan(err)  # no surface near the point in any camera: counted apart
    err, on_actor = err[~none], on_actor[~none]
    dr = drift(gt, traj, args.actor_radius)
    seconds = len(frames) / traj.fps
    lengths = traj.lengths

    def q(a, p):
        return float(np.percentile(a, p)) if len(a) else float("nan")

    return {
        "capture": str(capture_dir),
        "frames": [frames.start, frames.stop],
        "cameras": len(cap.rig),
        "image_size": [int(s) for s in cap.rig.sizes[0]],
        "trajectories": traj.num_trajectories,
        "point_frames": traj.num_point_frames,
        "trajectories_per_second": traj.num_trajectories / seconds,
        "point_frames_per_second": traj.num_point_frames / seconds,
        "actor_points_per_frame": actors / len(frames),
        "actor_point_frames_per_second": actors / seconds,
        "error_no_surface_point_frames": int(none.sum()),
        "error_all_median_m": q(err, 50),
        "error_all_p90_m": q(err, 90),
        "error_actor_median_m": q(err[on_actor], 50),
        "error_actor_p90_m": q(err[on_actor], 90),
        "error_other_median_m": q(err[~on_actor], 50),
        "drift_trajectories": int(len(dr)),
        "drift_median_m": q(dr, 50),
        "drift_p90_m": q(dr, 90),
        "coverage": coverage(gt, traj, frames, args.coverage_radius),
        "length_percentiles_10_50_90": [q(lengths, 10), q(lengths, 50), q(lengths, 90)],
        "length_histogram": np.bincount(lengths).tolist(),
    }


# -- real capture: a rigid ChArUco board -------------------------------------------------------


def load_charuco_corners(csv_path: Path, frame_offset: int) -> dict[int, np.ndarray]:
    """Caliscope's triangulated board corners per video frame: {t: (K_t, 3)}.

    ``xyz_CHARUCO.csv`` is indexed by caliscope's ``sync_index``; video frame = sync_index -
    ``frame_offset``.
    """
    a = np.genfromtxt(csv_path, delimiter=",", skip_header=1, usecols=(0, 3, 4, 5))
    out: dict[int, np.ndarray] = {}
    for s in np.unique(a[:, 0]).astype(int):
        out[s - frame_offset] = a[a[:, 0] == s, 1:4]
    return out


def board_points(traj, corners: dict[int, np.ndarray], margin: float, slab: float):
    """Per frame, the rows of reconstructed points on the board and their plane residuals.

    A point is on the board when its projection onto the plane fitted to the frame's corners lies
    within the corners' extent grown by ``margin`` and it is within ``slab`` of the plane.
    """
    rows_all, res_all = [], []
    for t, K in corners.items():
        if not 0 <= t < traj.num_frames or len(K) < 4:
            continue
        c0 = K.mean(axis=0)
        _, _, vt = np.linalg.svd(K - c0)
        u, v, n = vt  # in-plane axes and normal
        rows = traj.frame_rows(t)
        X = traj.xyz[rows].astype(np.float64) - c0
        pu, pv, pn = X @ u, X @ v, X @ n
        ku, kv = (K - c0) @ u, (K - c0) @ v
        inside = (
            (pu >= ku.min() - margin)
            & (pu <= ku.max() + margin)
            & (pv >= kv.min() - margin)
            & (pv <= kv.max() + margin)
            & (np.abs(pn) <= slab)
        )
        rows_all.append(rows[inside])
        res_all.append(pn[inside])
    rows = np.concatenate(rows_all) if rows_all else np.zeros(0, np.int64)
    res = np.concatenate(res_all) if res_all else np.zeros(0)
    return rows, res


def pairwise_distance_change(traj, tracks: np.ndarray, max_pairs: int, seed: int = 0):
    """(Q,) per pair of trajectories: max |d_ij(t) - d_ij(t0)| over their shared frames."""
    rng = np.random.default_rng(seed)
    X = traj.dense_positions(tracks).astype(np.float64)  # (Mb, T, 3)
    Mb = len(tracks)
    i, j = np.triu_indices(Mb, k=1)
    if len(i) > max_pairs:
        pick = rng.choice(len(i), max_pairs, replace=False)
        i, j = i[pick], j[pick]
    D = np.linalg.norm(X[i] - X[j], axis=2)  # (Q, T), NaN outside the shared lifetime
    shared = np.isfinite(D)
    keep = shared.sum(axis=1) >= 2
    D, shared = D[keep], shared[keep]
    d0 = D[np.arange(len(D)), np.argmax(shared, axis=1)]
    return np.nanmax(np.abs(D - d0[:, None]), axis=1), np.sum(shared, axis=1)


def lagged_distance_change(traj, tracks: np.ndarray, lag: int, max_pairs: int, seed: int = 0):
    """Board rigidity at a fixed lag, apart from how long the trajectories live.

    Returns ``(change, verified)``: ``|d_ij(t + lag) - d_ij(t)|`` over every pair of ``tracks``
    and frame where both exist at both times (the maximum over the shared lifetime, of
    :func:`pairwise_distance_change`, grows with it), and per value whether both trajectories
    are seen by 3 cameras or more on average (V > 0.05) over their lives.
    """
    from pointtraj.trajectories import dequantize_visibility

    rng = np.random.default_rng(seed)
    views = (dequantize_visibility(traj.visibility) > 0.05).sum(axis=1)
    mean_views = np.bincount(traj.row_track, weights=views, minlength=traj.num_trajectories)
    three = (mean_views / np.maximum(traj.lengths, 1))[tracks] >= 3
    X = traj.dense_positions(tracks).astype(np.float64)  # (Mb, T, 3)
    i, j = np.triu_indices(len(tracks), k=1)
    if len(i) > max_pairs:
        pick = rng.choice(len(i), max_pairs, replace=False)
        i, j = i[pick], j[pick]
    D = np.linalg.norm(X[i] - X[j], axis=2)  # (Q, T)
    d = np.abs(D[:, lag:] - D[:, :-lag])
    ok = np.isfinite(d)
    both = np.broadcast_to((three[i] & three[j])[:, None], d.shape)
    return d[ok], both[ok]


def make_caliscope_capture(data_dir: Path, capture: Path) -> None:
    """A capture folder for caliscope's board recording: rig.toml plus symlinked videos."""
    from pointtraj.rigio.caliscope import load_caliscope
    from pointtraj.rigio.toml import save_rig_toml

    rig = load_caliscope(data_dir / "camera_array.toml")
    (capture / "videos").mkdir(parents=True, exist_ok=True)
    save_rig_toml(rig, capture / "rig.toml")
    for name in rig.names:  # cameras are called cam_N like the videos
        link = capture / "videos" / f"{name}.mp4"
        if not link.exists():
            link.symlink_to((data_dir / "calibration" / "extrinsic" / f"{name}.mp4").resolve())


def evaluate_board(data_dir: Path, traj, args) -> dict:
    """Rigidity and planarity of the trajectories on the caliscope ChArUco board."""
    corners = load_charuco_corners(
        data_dir / "calibration" / "extrinsic" / "CHARUCO" / "xyz_CHARUCO.csv", args.frame_offset
    )
    rows, residual = board_points(traj, corners, args.board_margin, args.board_slab)
    on = np.zeros(traj.num_point_frames, bool)
    on[rows] = True
    frac = np.bincount(traj.row_track[on], minlength=traj.num_trajectories) / traj.lengths
    board = np.flatnonzero((frac >= 0.8) & (traj.lengths >= 2))
    change, shared = pairwise_distance_change(traj, board, args.max_pairs)
    # plane residual of the board trajectories' points, against a plane fitted to them
    # per frame (independent of caliscope's corners)
    fit_res = []
    for t in np.unique(traj.row_frame[traj.rows_of(board)]) if len(board) else []:
        fs_rows = traj.frame_rows(int(t))
        sel = fs_rows[np.isin(traj.row_track[fs_rows], board)]
        if len(sel) < 10:
            continue
        X = traj.xyz[sel].astype(np.float64)
        c = np.median(X, axis=0)
        n = np.linalg.svd(X - c)[2][2]
        fit_res.append(np.abs((X - c) @ n))
    fit_res = np.concatenate(fit_res) if fit_res else np.zeros(0)

    def q(a, p):
        return float(np.percentile(a, p)) if len(a) else float("nan")

    lagged, verified = lagged_distance_change(traj, board, 3, args.max_pairs)
    return {
        "frames_with_corners": len(corners),
        "board_point_frames": int(len(rows)),
        "board_trajectories": int(len(board)),
        "board_trajectory_length_median": q(traj.lengths[board], 50),
        "pairs": int(len(change)),
        "pair_shared_frames_median": q(shared, 50),
        "pairwise_distance_change_median_m": q(change, 50),
        "pairwise_distance_change_p90_m": q(change, 90),
        "lag3_change_median_m": q(lagged, 50),
        "lag3_change_p90_m": q(lagged, 90),
        "lag3_verified_share": float(np.mean(verified)) if len(verified) else float("nan"),
        "lag3_change_verified_median_m": q(lagged[verified], 50),
        "lag3_change_verified_p90_m": q(lagged[verified], 90),
        "lag3_change_two_view_median_m": q(lagged[~verified], 50),
        "lag3_change_two_view_p90_m": q(lagged[~verified], 90),
        "residual_to_corner_plane_median_m": q(np.abs(residual), 50),
        "residual_to_corner_plane_p90_m": q(np.abs(residual), 90),
        "residual_to_fitted_plane_median_m": q(fit_res, 50),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("capture", type=Path)
    ap.add_argument("--work", type=Path, required=True)
    ap.add_argument("--frames", default=None, help="A:B (default all)")
    ap.add_argument("--config", type=Path, default=None, help="TOML with [reconstruct]")
    ap.add_argument("--report", type=Path, default=None, help="write the figures as JSON")
    ap.add_argument("--actor-radius", type=float, default=0.02)
    ap.add_argument("--coverage-radius", type=float, default=0.02)
    ap.add_argument(
        "--board",
        type=Path,
        default=None,
        help="real capture mode: the caliscope data folder (with calibration/extrinsic/CHARUCO)",
    )
    ap.add_argument("--frame-offset", type=int, default=35, help="board: sync_index - frame")
    ap.add_argument("--board-margin", type=float, default=0.054, help="board: beyond corners, m")
    ap.add_argument("--board-slab", type=float, default=0.03, help="board: plane distance, m")
    ap.add_argument("--max-pairs", type=int, default=200000)
    ap.add_argument("-v", "--verbose", action="store_true")
    args = ap.parse_args()
    logging.basicConfig(
        level=logging.INFO if args.verbose else logging.WARNING,
        format="%(levelname)s %(name)s: %(message)s",
    )
    from pointtraj.reconstruct.stage import reconstruct_capture
    from pointtraj.session import Capture
    from pointtraj.stages import load_reconstruct_config
    from pointtraj.workdir import parse_frames

    if args.board is not None and not (args.capture / "rig.toml").is_file():
        make_caliscope_capture(args.board, args.capture)
    cap = Capture.open(args.capture)
    frames = parse_frames(args.frames, cap.num_frames)
    cfg = load_reconstruct_config(args.config)
    t0 = time.perf_counter()
    done = {"n": 0}

    def tick(rec):
        done["n"] += 1
        print(f"  frame {rec.frame}: {len(rec)} points ({rec.num_new} new)", flush=True)

    traj = reconstruct_capture(cap, args.work, frames, cfg, on_frame=tick)
    elapsed = time.perf_counter() - t0
    if args.board is not None:
        res = evaluate_board(args.board, traj, args)
    else:
        res = evaluate(args.capture, traj, frames, args)
    res["seconds_total"] = elapsed
    res["config"] = str(args.config) if args.config else "defaults"
    for k, v in res.items():
        if k not in ("length_histogram",):
            print(f"{k}: {v}")
    if args.report:
        args.report.write_text(json.dumps(res, indent=2))


if __name__ == "__main__":
    main()
