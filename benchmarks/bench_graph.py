"""Benchmark: affinity + labelling time and peak memory at 10^5 and 10^6 trajectories.

Workload: ``bodies`` rigid boxes of points (0.4 m, side by side on a 0.45 m grid, so that
neighbouring boxes nearly touch) moving with different rigid motions over T = 10 frames, sampled
as M trajectories fragmented into random lifetimes (0.3 mm position noise, which gives
ε-neighbour residuals of 1-2 mm like the reconstructed demo trajectories). The true label of a
trajectory is its body. L3D is noisy: Dirichlet noise on every row and, for 15 % of the
trajectories, a wrong dominant class.

Stages (each in its own subprocess, so that its peak RSS, ``ru_maxrss``, is its own):

* ``affinity``: :func:`pointtraj.affinity.compute_affinity` with the default
  :class:`~pointtraj.affinity.AffinityConfig`; the graph is cached in ``--cache`` for the
  labelling stages.
* ``label-restricted``: :func:`pointtraj.labeling.alpha_expansion` with the default restricted
  moves on that graph (data costs and plausible labels as :func:`label_trajectories` builds
  them; the time covers the expansion only).
* ``label-full``: the plain whole-graph expansion (``method="full"``) on the same graph, for the
  energy and time comparison.

With ``--graph synthetic`` the labelling stages run on a synthetic graph instead (8 nearest
neighbours, 90 % kept, affinities high inside a label and low across), which needs no affinity
stage.

Usage::

    .venv/bin/python benchmarks/bench_graph.py --sizes 100000 1000000
    .venv/bin/python benchmarks/bench_graph.py --sizes 100000 --stages label-restricted
    .venv/bin/python benchmarks/bench_graph.py --open3d   # Open3D vs scipy/numpy micro-benchmarks
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

K_BODIES = 10


def synthetic_l3d(truth: np.ndarray, K: int, seed: int = 0) -> np.ndarray:
    """(M, K) noisy L3D: Dirichlet noise, 15 % of rows with a wrong dominant class."""
    rng = np.random.default_rng([seed, 3])
    M = truth.shape[0]
    dominant = truth.copy()
    wrong = rng.random(M) < 0.15
    dominant[wrong] = rng.integers(0, K, int(wrong.sum()))
    l3d = 0.45 * rng.dirichlet(np.full(K, 0.3), size=M)
    l3d[np.arange(M), dominant] += 0.55
    return l3d


def synthetic_graph(M: int, K: int = K_BODIES, seed: int = 0):
    """(truth (M,), l3d (M, K), row, col, weight) of a spatially structured labelling problem."""
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(seed)
    pts = rng.random((M, 3)) * np.array([2.0, 2.0, 1.0])
    seeds = rng.random((K, 3)) * np.array([2.0, 2.0, 1.0])
    _, truth = cKDTree(seeds).query(pts)
    _, nn = cKDTree(pts).query(pts, k=9, workers=-1)  # self + 8 nearest
    src = np.repeat(np.arange(M), 8)
    dst = nn[:, 1:].ravel()
    keep = rng.random(src.size) < 0.9
    lo, hi = np.minimum(src[keep], dst[keep]), np.maximum(src[keep], dst[keep])
    key = np.unique(lo * M + hi)
    row, col = key // M, key % M
    same = truth[row] == truth[col]
    weight = np.where(same, rng.uniform(0.5, 1.0, row.size), rng.uniform(0.0, 0.2, row.size))
    return truth, synthetic_l3d(truth, K, seed), row, col, weight


def synthetic_trajectories(
    M: int, T: int = 10, bodies: int = K_BODIES, noise: float = 0.0003, seed: int = 0
):
    """Fragmented trajectories on ``bodies`` rigid boxes with different rigid motions.

    Returns
    -------
    traj : Trajectories
    body : (M,) int64 ndarray
        The body (true label) of each trajectory.
    """
    from pointtraj.trajectories import Trajectories

    rng = np.random.default_rng(seed)
    body = rng.integers(0, bodies, M)
    cols = int(np.ceil(bodies / 2))
    grid = np.stack([np.arange(bodies) % cols, np.arange(bodies) // cols], axis=1)
    centres = np.c_[0.45 * (grid - grid.mean(axis=0)), np.full(bodies, 1.0)]
    local = rng.uniform(-0.2, 0.2, (M, 3))
    omega = rng.normal(0, 0.03, (bodies, 3))  # rad / frame, axis-angle
    vel = rng.normal(0, 0.01, (bodies, 3))  # m / frame
    first = rng.integers(0, T - 1, M)
    length = np.minimum(rng.integers(2, T + 1, M), T - first)
    P = int(length.sum())
    tr_of = np.repeat(np.arange(M), length)
    t_of = np.repeat(first, length) + (np.arange(P) - np.repeat(np.cumsum(length) - length, length))
    xyz = np.empty((P, 3), np.float32)
    for t in range(T):
        sel = np.flatnonzero(t_of == t)
        b = body[tr_of[sel]]
        ang = omega[b] * t
        theta = np.linalg.norm(ang, axis=1, keepdims=True) + 1e-12
        k = ang / theta
        p = local[tr_of[sel]]
        # Rodrigues rotation of each point about its body's axis
        rot = (
            p * np.cos(theta)
            + np.cross(k, p) * np.sin(theta)
            + k * (k * p).sum(1, keepdims=True) * (1 - np.cos(theta))
        )
        xyz[sel] = rot + centres[b] + vel[b] * t
    xyz += rng.normal(0, noise, xyz.shape).astype(np.float32)
    traj = Trajectories(
        first_frame=first,
        offsets=np.concatenate([[0], np.cumsum(length)]),
        xyz=xyz,
        visibility=np.zeros((P, 0), np.uint8),
        reprojection_error=np.zeros(P, np.float32),
        color=np.zeros((P, 3), np.uint8),
        num_frames=T,
    )
    return traj, body


def cache_path(cache: Path, M: int) -> Path:
    return cache / f"bench_graph_{M}.npz"


def run_affinity(M: int, cache: Path) -> dict:
    from pointtraj.affinity import AffinityConfig, compute_affinity

    traj, body = synthetic_trajectories(M)
    t0, c0 = time.perf_counter(), time.process_time()
    g = compute_affinity(traj, AffinityConfig())
    secs, cpu = time.perf_counter() - t0, time.process_time() - c0
    same = body[g.row] == body[g.col]
    np.savez(cache_path(cache, M), row=g.row, col=g.col, weight=g.weight, truth=body)
    return {
        "stage": "affinity",
        "M": M,
        "point_frames": traj.num_point_frames,
        "edges": g.num_edges,
        "seconds": round(secs, 2),
        "cpu_s": round(cpu, 2),
        "same_body_edge_weight_share": round(float(g.weight[same].sum() / g.weight.sum()), 4),
        "mean_A_same_body": round(float(g.affinity[same].mean()), 4) if same.any() else None,
        "mean_A_other_body": round(float(g.affinity[~same].mean()), 4) if (~same).any() else None,
    }


def run_label(M: int, method: str, graph: str, cache: Path) -> dict:
    from pointtraj.labeling import LabelingConfig, alpha_expansion, data_costs, plausible_labels

    if graph == "synthetic":
        truth, l3d, row, col, weight = synthetic_graph(M)
    else:
        path = cache_path(cache, M)
        if not path.is_file():
            sys.exit(f"{path}: missing, run the affinity stage first")
        with np.load(path) as z:
            row, col, weight, truth = z["row"], z["col"], z["weight"], z["truth"]
        l3d = synthetic_l3d(truth, K_BODIES)
    cfg = LabelingConfig(method=method)
    D = data_costs(l3d, cfg.data_cost)
    plaus = plausible_labels(l3d, cfg.plausible_threshold)
    t0, c0 = time.perf_counter(), time.process_time()
    res = alpha_expansion(D, row, col, weight, cfg, init=l3d.argmax(1), plausible=plaus)
    secs, cpu = time.perf_counter() - t0, time.process_time() - c0
    return {
        "stage": f"label-{method}",
        "M": M,
        "edges": int(row.size),
        "seconds": round(secs, 2),
        "cpu_s": round(cpu, 2),
        "energy": res.energy[-1],
        "energy_trace": res.energy,
        "moves": res.moves,
        "acc_argmax": round(float((l3d.argmax(1) == truth).mean()), 4),
        "acc_cut": round(float((res.labels == truth).mean()), 4),
    }


def bench_open3d() -> dict:
    """Open3D vs scipy fixed-radius pairs; Open3D point-to-point vs batched numpy Kabsch."""
    import open3d as o3d
    from scipy.spatial import cKDTree

    from pointtraj.geometry import fit_rigid

    out = {}
    rng = np.random.default_rng(0)
    for n in (100_000, 1_000_000):
        # points in a 3 m x 3 m x 2 m capture volume; all pairs within 5 cm
        pts = rng.random((n, 3)) * np.array([3.0, 3.0, 2.0])
        t0 = time.perf_counter()
        pairs = cKDTree(pts).query_pairs(0.05, output_type="ndarray")
        out[f"scipy_query_pairs_{n}"] = (round(time.perf_counter() - t0, 3), int(len(pairs)))
        t0 = time.perf_counter()
        p32 = o3d.core.Tensor(pts.astype(np.float32))
        nns = o3d.core.nns.NearestNeighborSearch(p32)
        nns.fixed_radius_index(0.05)
        idx, _, _ = nns.fixed_radius_search(p32, 0.05)
        out[f"open3d_fixed_radius_{n}"] = (
            round(time.perf_counter() - t0, 3),
            (int(idx.shape[0]) - n) // 2,
        )
    # rigid fits: 20 points each
    B, S = 100_000, 20
    a = rng.normal(size=(B, S, 3))
    b = a + 0.001 * rng.normal(size=a.shape)
    t0 = time.perf_counter()
    fit_rigid(a, b, center=False)
    out["numpy_kabsch_100k_fits_20pts_s"] = round(time.perf_counter() - t0, 3)
    est = o3d.pipelines.registration.TransformationEstimationPointToPoint()
    src = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(a[0]))
    dst = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(b[0]))
    corr = o3d.utility.Vector2iVector(np.c_[np.arange(S), np.arange(S)].astype(np.int32))
    n_calls = 2000
    t0 = time.perf_counter()
    for k in range(n_calls):
        src.points = o3d.utility.Vector3dVector(a[k])
        dst.points = o3d.utility.Vector3dVector(b[k])
        est.compute_transformation(src, dst, corr)
    out["open3d_compute_transformation_us_per_call"] = round(
        1e6 * (time.perf_counter() - t0) / n_calls, 1
    )
    t0 = time.perf_counter()
    n_r = 200
    for k in range(n_r):
        src.points = o3d.utility.Vector3dVector(a[k])
        dst.points = o3d.utility.Vector3dVector(b[k])
        o3d.pipelines.registration.registration_ransac_based_on_correspondence(
            src,
            dst,
            corr,
            0.01,
            est,
            3,
            [],
            o3d.pipelines.registration.RANSACConvergenceCriteria(8, 0.999),
        )
    out["open3d_ransac_on_correspondence_us_per_call"] = round(
        1e6 * (time.perf_counter() - t0) / n_r, 1
    )
    return out


def child(stage: str, M: int, graph: str, cache: Path) -> None:
    if stage == "affinity":
        res = run_affinity(M, cache)
    else:
        res = run_label(M, stage.split("-", 1)[1], graph, cache)
    use = resource.getrusage(resource.RUSAGE_SELF)
    res["peak_rss_MiB"] = round(use.ru_maxrss / 1024, 1)
    res["process_cpu_s"] = round(use.ru_utime + use.ru_stime, 1)  # incl. building the input
    print(json.dumps(res))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[100_000, 1_000_000])
    ap.add_argument(
        "--stages",
        nargs="+",
        default=["affinity", "label-restricted", "label-full"],
        choices=["affinity", "label-restricted", "label-full"],
    )
    ap.add_argument(
        "--graph",
        choices=["affinity", "synthetic"],
        default="affinity",
        help="labelling input: the affinity stage's graph (default) or a synthetic graph",
    )
    ap.add_argument("--cache", type=Path, help="folder for the affinity graphs (default: temp)")
    ap.add_argument("--open3d", action="store_true", help="Open3D micro-benchmarks only")
    ap.add_argument("--child", nargs=2, metavar=("STAGE", "M"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        child(args.child[0], int(args.child[1]), args.graph, args.cache)
        return
    if args.open3d:
        print(json.dumps(bench_open3d(), indent=1))
        return
    with tempfile.TemporaryDirectory(prefix="bench_graph_") as tmp:
        cache = args.cache or Path(tmp)
        cache.mkdir(parents=True, exist_ok=True)
        stages = list(args.stages)
        need_graph = args.graph == "affinity" and any(s.startswith("label") for s in stages)
        for M in args.sizes:
            todo = stages
            if need_graph and "affinity" not in stages and not cache_path(cache, M).is_file():
                todo = ["affinity", *stages]
            energies = {}
            for stage in todo:
                cmd = [sys.executable, __file__, "--child", stage, str(M), "--graph", args.graph]
                cmd += ["--cache", str(cache)]
                proc = subprocess.run(cmd, capture_output=True, text=True)
                if proc.returncode != 0:
                    sys.exit(f"{stage} M={M} failed:\n{proc.stderr[-3000:]}")
                r = json.loads(proc.stdout.strip().splitlines()[-1])
                if "energy" in r:
                    energies[stage] = r["energy"]
                print(
                    f"M={M:>8} {stage:<17} {r['seconds']:>8.2f} s  peak {r['peak_rss_MiB']:>8.1f} "
                    "MiB  "
                    + ", ".join(
                        f"{k}={v}"
                        for k, v in r.items()
                        if k not in ("stage", "M", "seconds", "peak_rss_MiB", "energy_trace")
                    ),
                    flush=True,
                )
            if {"label-restricted", "label-full"} <= energies.keys():
                er, ef = energies["label-restricted"], energies["label-full"]
                print(
                    f"M={M:>8} energy restricted / full = {er / ef:.6f} "
                    f"({'equal or lower' if er <= ef * (1 + 1e-9) else 'HIGHER'})",
                    flush=True,
                )


if __name__ == "__main__":
    main()
