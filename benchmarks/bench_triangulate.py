"""Benchmark robust multi-view triangulation against aniposelib and pycolmap.

Same observations for every method: points sampled uniformly in the stage cylinder, projected
into the rig (lens distortion included), 0.5 px Gaussian noise, and 30 % of the observed views
replaced by uniformly random pixels. Two rigs: ``ring12`` (12 cameras) and ``paper69`` (69
cameras, the paper's two-ring geometry), from :mod:`pointtraj.synth.presets` when available,
otherwise rebuilt here with :meth:`Camera.look_at`.

Methods
-------
pointtraj
    :func:`pointtraj.reconstruct.triangulate_ransac` on all points at once.
pycolmap
    ``pycolmap.estimate_triangulation`` (per-point LO-RANSAC in C++), residual type set to
    reprojection error with the same 2 px threshold, called per point from Python.
aniposelib
    ``CameraGroup.triangulate_ransac`` as installed (0.8: it enumerates camera subsets and
    triangulates each with jax), run in a child process under a time limit.
aniposelib-np
    The same subset enumeration with ``CameraGroup.triangulate`` replaced, in this benchmark
    only, by a plain numpy SVD triangulation (what aniposelib did before it moved to jax), so
    that the ratio is not only the per-call overhead of jax.

Slow peers run on the first points of the same sample; their rates are per point.

Usage::

    .venv/bin/python benchmarks/bench_triangulate.py            # full run, about 4 minutes
    .venv/bin/python benchmarks/bench_triangulate.py --quick    # smoke run, under a minute
    .venv/bin/python benchmarks/bench_triangulate.py --occlusion  # occlusion_test vs ray casting

Timing: every method runs single-threaded (BLAS threads default to 1); the table gives wall-clock
and CPU-time rates and the speed-up of pointtraj computed from CPU time, which is the robust one
on a shared, loaded machine (the wall-clock speed-up is shown beside it).

Installing the peers: pycolmap is a dependency. aniposelib is the optional ``bench`` extra
(``pip install aniposelib``, 0.8.0 here, with numpy 2.4 it needs no patch). It depends on the
non-headless ``opencv-contrib-python``, whose files overwrite those of the headless build this
project uses; restore it afterwards with::

    pip uninstall -y opencv-contrib-python
    pip install --force-reinstall --no-deps opencv-contrib-python-headless==5.0.0.93
"""

from __future__ import annotations

import os
import sys

# Single-threaded BLAS by default so that every method runs on one core (pycolmap's estimator and
# aniposelib's loop are single-threaded); --threads N (set before numpy loads) changes it.
_THREADS = "1"
if "--threads" in sys.argv:
    _THREADS = sys.argv[sys.argv.index("--threads") + 1]
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = _THREADS

import argparse  # noqa: E402
import json  # noqa: E402
import multiprocessing as mp  # noqa: E402
import time  # noqa: E402
from dataclasses import dataclass  # noqa: E402

import numpy as np  # noqa: E402

from pointtraj.camera import Camera, CameraRig, rodrigues_from_rotation  # noqa: E402
from pointtraj.reconstruct.triangulate import (  # noqa: E402
    TriangulationConfig,
    triangulate_ransac,
)

#: Mild barrel distortion added to every camera (OpenCV k1, k2).
DIST = (-0.05, 0.01, 0.0, 0.0, 0.0)
THRESHOLD_PX = 2.0
NOISE_PX = 0.5
OUTLIER_FRACTION = 0.3
#: A point counts as recovered when its 3D error is below this (metres).
RECOVERED_M = 0.01


def _fallback_rig(name: str) -> CameraRig:
    if name == "ring12":
        cams = [
            Camera.look_at(
                f"cam{i:02d}",
                [2.5 * np.cos(2 * np.pi * i / 12), 2.5 * np.sin(2 * np.pi * i / 12), 1.1 + 0.9 * (i % 2)],
                [0.0, 0.0, 0.9],
                (800, 640),
                420.0,
            )
            for i in range(12)
        ]  # fmt: skip
    else:
        cams = []
        for k, (n, h, aim, off) in enumerate([(35, 1.0, 0.9, 0.0), (34, 2.2, 1.1, np.pi / 34)]):
            for i in range(n):
                a = off + 2 * np.pi * i / n
                c = [1.6 * np.cos(a), 1.6 * np.sin(a), h]
                cams.append(
                    Camera.look_at(f"cam{i + 35 * k:02d}", c, [0, 0, aim], (1280, 1024), 600.0)
                )
    return CameraRig(cams)


def make_bench_rig(name: str, distortion: bool = True) -> CameraRig:
    """The preset rig ``name`` (``ring12`` or ``paper69``), with mild lens distortion."""
    try:
        from pointtraj.synth.presets import make_rig

        rig = make_rig(name)
    except ImportError:
        rig = _fallback_rig(name)
    if not distortion:
        return rig
    return CameraRig([Camera(c.name, c.K, c.R, c.C, c.size, DIST) for c in rig])


def make_observations(
    rig: CameraRig, n: int, seed: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ground-truth points (n, 3), corrupted observations (C, n, 2), outlier mask (C, n).

    Points seen by fewer than 2 cameras are resampled, so every point is triangulable.
    """
    rng = np.random.default_rng(seed)
    pts = np.empty((0, 3))
    while len(pts) < n:
        r = 0.8 * np.sqrt(rng.random(2 * n))
        a = rng.uniform(0, 2 * np.pi, 2 * n)
        cand = np.stack([r * np.cos(a), r * np.sin(a), rng.uniform(0.1, 1.9, 2 * n)], axis=1)
        seen = rig.project(cand).in_image.sum(axis=0) >= 2
        pts = np.concatenate([pts, cand[seen]])
    X = pts[:n]
    proj = rig.project(X)
    seen = proj.in_image
    obs = proj.pixels + rng.normal(0.0, NOISE_PX, proj.pixels.shape)
    bad = seen & (rng.random(seen.shape) < OUTLIER_FRACTION)
    sizes = rig.sizes[:, None, :].astype(float) - 1.0  # (C, 1, 2)
    rand = rng.random(obs.shape) * sizes
    obs = np.where(bad[..., None], rand, obs)
    obs[~seen] = np.nan
    return X, obs, bad


@dataclass
class Result:
    method: str
    rig: str
    n_points: int
    seconds: float  # wall clock
    cpu_seconds: float  # CPU time of the process doing the work
    errors: np.ndarray  # (n,) 3D error in metres (NaN = not reconstructed)
    note: str = ""

    @property
    def rate(self) -> float:
        """Points per second of wall-clock time."""
        return self.n_points / self.seconds if self.seconds > 0 else float("nan")

    @property
    def cpu_rate(self) -> float:
        """Points per second of CPU time (robust on a shared, loaded machine)."""
        return self.n_points / self.cpu_seconds if self.cpu_seconds > 0 else float("nan")

    def stats(self) -> dict:
        e = self.errors
        ok = np.isfinite(e)
        return {
            "method": self.method,
            "rig": self.rig,
            "points": self.n_points,
            "seconds": round(self.seconds, 3),
            "cpu_seconds": round(self.cpu_seconds, 3),
            "points_per_s": round(self.rate, 2),
            "points_per_cpu_s": round(self.cpu_rate, 2),
            "us_per_point": round(1e6 / self.rate, 1) if self.n_points else None,
            "cpu_us_per_point": round(1e6 / self.cpu_rate, 1) if self.n_points else None,
            "median_mm": round(1e3 * float(np.median(e[ok])), 3) if ok.any() else None,
            "p90_mm": round(1e3 * float(np.percentile(e[ok], 90)), 3) if ok.any() else None,
            "recovered": round(float(np.mean(ok & (np.nan_to_num(e, nan=1e9) < RECOVERED_M))), 4)
            if self.n_points
            else None,
            "note": self.note,
        }


def run_pointtraj(
    rig: CameraRig, X: np.ndarray, obs: np.ndarray, name: str, repeats: int
) -> Result:
    cfg = TriangulationConfig(threshold_px=THRESHOLD_PX)
    triangulate_ransac(rig, obs[:, :2000], cfg)  # warm-up (page faults, caches)
    times, cpu = [], []
    for _ in range(repeats):  # best of: the machine is shared
        t, c = time.perf_counter(), time.process_time()
        res = triangulate_ransac(rig, obs, cfg)
        times.append(time.perf_counter() - t)
        cpu.append(time.process_time() - c)
    err = np.linalg.norm(res.points - X, axis=1)
    return Result("pointtraj", name, len(X), min(times), min(cpu), err, f"best of {repeats}")


def run_pycolmap(rig: CameraRig, X: np.ndarray, obs: np.ndarray, name: str, repeats: int) -> Result:
    import pycolmap

    cams, poses = [], []
    for c in rig:
        K, d = c.K, c.dist
        if np.any(d[4:]):
            raise ValueError("pycolmap OPENCV model: only k1 k2 p1 p2 are used here")
        cams.append(
            pycolmap.Camera(
                model="OPENCV",
                width=c.width,
                height=c.height,
                params=[K[0, 0], K[1, 1], K[0, 2], K[1, 2], d[0], d[1], d[2], d[3]],
            )
        )
        poses.append(pycolmap.Rigid3d(pycolmap.Rotation3d(c.R), c.t))
    opt = pycolmap.EstimateTriangulationOptions()
    opt.residual_type = pycolmap.TriangulationResidualType.REPROJECTION_ERROR
    opt.ransac.max_error = THRESHOLD_PX  # pixels with the reprojection residual
    opt.ransac.random_seed = 0
    seen = np.all(np.isfinite(obs), axis=-1)
    out = np.full((len(X), 3), np.nan)
    times, cpu = [], []
    for _ in range(repeats):
        t, c = time.perf_counter(), time.process_time()
        for n in range(len(X)):
            v = np.flatnonzero(seen[:, n])
            r = pycolmap.estimate_triangulation(
                obs[v, n], [poses[i] for i in v], [cams[i] for i in v], opt
            )
            if r is not None:
                out[n] = r["xyz"]
        times.append(time.perf_counter() - t)
        cpu.append(time.process_time() - c)
    err = np.linalg.norm(out - X, axis=1)
    return Result("pycolmap", name, len(X), min(times), min(cpu), err, f"best of {repeats}")


def _numpy_triangulate(self, points, undistort=True, progress=False, **kwargs):
    """Stand-in for aniposelib's jax ``CameraGroup.triangulate``: per-point SVD DLT."""
    pts = np.asarray(points, dtype=float)
    one = pts.ndim == 2
    if one:
        pts = pts.reshape(-1, 1, 2)
    if undistort:
        pts = np.stack([cam.undistort_points(np.copy(p)) for cam, p in zip(self.cameras, pts)])
    mats = np.stack([cam.get_extrinsics_mat()[:3] for cam in self.cameras])  # (C, 3, 4)
    out = np.full((pts.shape[1], 3), np.nan)
    for n in range(pts.shape[1]):
        ok = np.isfinite(pts[:, n, 0])
        if ok.sum() < 2:
            continue
        p, m = pts[ok, n], mats[ok]
        A = np.concatenate([p[:, :1] * m[:, 2] - m[:, 0], p[:, 1:] * m[:, 2] - m[:, 1]])
        h = np.linalg.svd(A)[2][-1]
        out[n] = h[:3] / h[3]
    return out[0] if one else out


def _anipose_worker(rig_name: str, distortion: bool, obs: np.ndarray, patch: bool, conn) -> None:
    """Child process: triangulate point by point, sending (index, xyz, (wall, cpu)) after
    each."""
    from aniposelib.cameras import Camera as ACamera
    from aniposelib.cameras import CameraGroup

    if patch:
        CameraGroup.triangulate = _numpy_triangulate
    rig = make_bench_rig(rig_name, distortion)
    group = CameraGroup(
        [
            ACamera(
                matrix=c.K,
                dist=c.dist[:5],
                size=c.size,
                rvec=rodrigues_from_rotation(c.R),
                tvec=c.t,
                name=c.name,
            )
            for c in rig
        ]
    )
    if not patch and len(rig) <= 16:  # compile jax's functions outside the timing
        group.triangulate_ransac(obs[:, :1], undistort=True, min_cams=2)
    conn.send(("ready", None, (0.0, 0.0)))
    t, c = time.perf_counter(), time.process_time()
    for n in range(obs.shape[1]):
        xyz = group.triangulate_ransac(obs[:, n : n + 1], undistort=True, min_cams=2)[0][0]
        conn.send((n, xyz, (time.perf_counter() - t, time.process_time() - c)))
    conn.send(("done", None, (time.perf_counter() - t, time.process_time() - c)))


def run_aniposelib(
    rig_name: str,
    distortion: bool,
    X: np.ndarray,
    obs: np.ndarray,
    time_limit: float,
    patch: bool,
) -> Result:
    method = "aniposelib-np" if patch else "aniposelib"
    ctx = mp.get_context("spawn")  # jax does not survive fork
    parent, child = ctx.Pipe(duplex=False)
    proc = ctx.Process(
        target=_anipose_worker, args=(rig_name, distortion, obs, patch, child), daemon=True
    )
    proc.start()
    child.close()
    out = np.full((obs.shape[1], 3), np.nan)
    finished, elapsed, note = 0, (0.0, 0.0), ""
    ready_deadline = time.monotonic() + 120.0
    started = None
    try:
        while True:
            deadline = ready_deadline if started is None else started + time_limit
            remaining = deadline - time.monotonic()
            if remaining <= 0 or not parent.poll(remaining):
                note = f"stopped at the {time_limit:.0f} s limit"
                break
            tag, xyz, secs = parent.recv()
            if tag == "ready":
                started = time.monotonic()
            elif tag == "done":
                break
            else:
                out[tag] = xyz
                finished, elapsed = tag + 1, secs
    except EOFError:
        note = "worker died"
    finally:
        if proc.is_alive():
            proc.terminate()
        proc.join()
    if finished == 0:
        elapsed = (time_limit, time_limit)
        note = f"no point finished within {time_limit:.0f} s"
    err = np.linalg.norm(out[:finished] - X[:finished], axis=1)
    return Result(method, rig_name, finished, elapsed[0], elapsed[1], err, note)


def run_occlusion_study(rig_names: list[str], distortion: bool, seed: int) -> list[dict]:
    """Compare :func:`occlusion_test` with ray-cast ground truth on two synthetic people.

    Points are sampled uniformly on the labelled surfaces of the ``two_people`` scene at t = 0;
    the truth is :meth:`pointtraj.synth.render.Renderer.unoccluded` (one ray per camera and
    point). Reported over the point-views inside the image: the fraction truly occluded, and
    the precision / recall of the occlusion flags.
    """
    from pointtraj.reconstruct.occlusion import _auto_cell_px, occlusion_test
    from pointtraj.synth.render import Renderer
    from pointtraj.synth.scenes import make_scene

    rows = []
    scene = make_scene("two_people", seed)
    poses = scene.poses(0.0)
    rng = np.random.default_rng(seed)
    pts = []
    for g, P in zip(scene.geometries, poses):
        if g.label < 0:
            continue
        v, tri = g.mesh.vertices, g.mesh.triangles
        k = max(1, len(tri) // 2)
        bary = rng.dirichlet([1.0, 1.0, 1.0], size=k)  # (k, 3)
        local = np.einsum("kj,kjd->kd", bary, v[tri[rng.integers(len(tri), size=k)]])
        pts.append(local @ P[:3, :3].T + P[:3, 3])
    X = np.concatenate(pts)
    for name in rig_names:
        rig = make_bench_rig(name, distortion)
        renderer = Renderer(scene, rig)
        renderer.scene_at_frame = renderer.build_raycasting_scene(poses)[0]
        seen = rig.project(X).in_image.T  # (N, C)
        truth = seen & ~renderer.unoccluded(X)
        proj = rig.project(X)
        auto = _auto_cell_px(proj.pixels, proj.in_image)
        print(
            f"\n== occlusion, {name}: {len(X)} surface points of two people, "
            f"{truth.sum() / seen.sum():.0%} of the in-image point-views occluded "
            f"(automatic cell {auto:.1f} px)"
        )
        print(
            f"{'tolerance m':>12}{'cell px':>10}{'precision':>11}{'recall':>8}{'accuracy':>10}{'ms':>7}"
        )
        for tol in (0.02, 0.05):
            for cell in (None, 8.0):
                t = time.perf_counter()
                occ = occlusion_test(rig, X, tol, cell_px=cell)
                ms = 1e3 * (time.perf_counter() - t)
                tp = int((occ & truth).sum())
                fp = int((occ & ~truth & seen).sum())
                fn = int((~occ & truth).sum())
                row = {
                    "rig": name,
                    "tolerance_m": tol,
                    "cell_px": round(auto if cell is None else cell, 2),
                    "precision": round(tp / max(tp + fp, 1), 3),
                    "recall": round(tp / max(tp + fn, 1), 3),
                    "accuracy": round(1 - (fp + fn) / max(int(seen.sum()), 1), 3),
                    "ms": round(ms, 1),
                }
                rows.append(row)
                label = f"{row['cell_px']:.1f}" + (" auto" if cell is None else "")
                print(
                    f"{tol:>12.2f}{label:>10}{row['precision']:>11.3f}{row['recall']:>8.3f}"
                    f"{row['accuracy']:>10.3f}{ms:>7.0f}"
                )
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--points", type=int, default=50000, help="points for pointtraj")
    ap.add_argument("--colmap-points", type=int, default=5000)
    ap.add_argument("--anipose-points", type=int, default=20, help="stock aniposelib, 12 cams")
    ap.add_argument("--anipose-np-points", type=int, default=100, help="numpy-patched, 12 cams")
    ap.add_argument("--time-limit", type=float, default=60.0, help="per aniposelib run, s")
    ap.add_argument("--rigs", default="ring12,paper69")
    ap.add_argument("--no-distortion", action="store_true")
    ap.add_argument("--skip-anipose", action="store_true")
    ap.add_argument("--quick", action="store_true", help="small sizes, for a smoke test")
    ap.add_argument(
        "--occlusion", action="store_true", help="only the occlusion-test study (synthetic truth)"
    )
    ap.add_argument("--json", help="also write the results to this JSON file")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--repeats", type=int, default=3, help="timing repeats (best is kept)")
    ap.add_argument("--threads", default=_THREADS, help="BLAS threads (default 1)")
    args = ap.parse_args()
    sys.stdout.reconfigure(line_buffering=True)  # progress shows when redirected to a file
    if args.quick:
        args.points, args.colmap_points, args.repeats = 5000, 300, 1
        args.anipose_points, args.anipose_np_points, args.time_limit = 2, 20, 15.0
    distortion = not args.no_distortion
    rows: list[dict] = []
    if args.occlusion:
        rows = run_occlusion_study(args.rigs.split(","), distortion, args.seed)
        if args.json:
            with open(args.json, "w", encoding="utf-8") as f:
                json.dump(rows, f, indent=1)
        return
    print(
        f"BLAS threads {os.environ['OPENBLAS_NUM_THREADS']}, load average "
        f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs, threshold {THRESHOLD_PX} px, "
        f"distortion {'k1 k2 = ' + str(DIST[:2]) if distortion else 'off'}"
    )
    for name in args.rigs.split(","):
        rig = make_bench_rig(name, distortion)
        X, obs, bad = make_observations(rig, args.points, args.seed)
        n_obs = np.isfinite(obs[..., 0]).sum(axis=0)
        print(
            f"\n== {name}: {len(rig)} cameras, {len(X)} points, views per point "
            f"mean {n_obs.mean():.1f} (min {n_obs.min()}, max {n_obs.max()}), "
            f"{bad.sum() / max(n_obs.sum(), 1):.0%} corrupted views, {NOISE_PX} px noise"
        )
        results = [run_pointtraj(rig, X, obs, name, args.repeats)]
        k = min(args.colmap_points, len(X))
        results.append(run_pycolmap(rig, X[:k], obs[:, :k], name, args.repeats))
        if not args.skip_anipose:
            for patch, k in ((True, args.anipose_np_points), (False, args.anipose_points)):
                k = min(k, len(X)) if len(rig) <= 16 else (1 + k // 10 if k else 0)
                if k <= 0:
                    continue
                results.append(
                    run_aniposelib(name, distortion, X[:k], obs[:, :k], args.time_limit, patch)
                )
        ours = results[0]
        print(
            f"{'method':<14}{'points':>7}{'pts/s':>10}{'pts/cpu-s':>11}{'cpu us/pt':>12}"
            f"{'median mm':>10}{'p90 mm':>8}{'recov.':>7}{'speed-up':>11}{'(wall)':>11}"
            "  pointtraj on the same points"
        )
        for r in results:
            s = r.stats()
            speed = ours.cpu_rate / r.cpu_rate if r.n_points else float("inf")
            speed_wall = ours.rate / r.rate if r.n_points else float("inf")
            # pointtraj's accuracy on exactly the peer's points, for a like-for-like check.
            sub = Result("", name, r.n_points, 1.0, 1.0, ours.errors[: r.n_points]).stats()
            s["speedup_of_pointtraj_cpu"] = round(speed, 1)
            s["speedup_of_pointtraj_wall"] = round(speed_wall, 1)
            s["pointtraj_same_points_median_mm"] = sub["median_mm"]
            s["pointtraj_same_points_recovered"] = sub["recovered"]
            rows.append(s)

            def fmt(v: object, spec: str) -> str:
                width = spec.split(".")[0]
                return format(v, spec) if v is not None else "-".rjust(int(width or 0))

            print(
                f"{r.method:<14}{r.n_points:>7}{fmt(s['points_per_s'], '10.2f')}"
                f"{fmt(s['points_per_cpu_s'], '11.2f')}{fmt(s['cpu_us_per_point'], '12.0f')}"
                f"{fmt(s['median_mm'], '10.3f')}{fmt(s['p90_mm'], '8.3f')}"
                f"{fmt(s['recovered'], '7.3f')}{speed:>10.1f}x{speed_wall:>10.1f}x"
                f"  median {fmt(sub['median_mm'], '.3f')} mm, recov. {fmt(sub['recovered'], '.3f')}"
                + (f"  [{r.note}]" if r.note else "")
            )
    if args.json:
        with open(args.json, "w", encoding="utf-8") as f:
            json.dump(rows, f, indent=1)


if __name__ == "__main__":
    main()
