"""Where the wrong views are: view precision by the true surface's incidence angle (issue #20).

Usage (from the repository root)::

    .venv/bin/python benchmarks/study_view_precision.py CAPTURE WORK [--every 3]
        [--samples 3000] [--radius 0.03] [--depth-tol 0.01]

The audit of :mod:`pointtraj.evaluate.views` (a view is truly visible when the camera's depth
map sees the point's nearest ground-truth sample, within ``--depth-tol``), with samples drawn
afresh, ``--samples`` per part from the scene's meshes, so that each carries its triangle's
normal. For every observed view of an actor point it takes the angle between that normal and
the direction to the camera, and prints the views, their precision and the true views' recall
by angle. Then, for comparison, what dropping views beyond an angle to the *fitted* normal
(:func:`pointtraj.reconstruct.views.point_normals`, the one the tracker has) would give.
With ``--convex``, the same for normals taken from the point's offset to the centroid of its
neighbours (a limb is convex, so the offset points outwards wherever the neighbours reach
across it): k nearest (12, 24) or within a radius (6, 10 cm), the offset with the
neighbourhood's long axis removed, and the plane fit oriented by the offset; each with its
angle to the true normal. With ``--mesh``, views dropped where a surface made of the frame's
points lies in front of the point (their alpha shape, ray-cast with Open3D, or a sphere around
every other point); with ``--facing``, views far from the mean direction of the point's other
observing cameras. The figures of ``docs/reconstruction.md``, "Where the wrong views are".
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

BINS = (0, 30, 45, 60, 70, 80, 90, 180)
FITTED = (60, 70, 80, 90, 180)
CONVEX_KEPT = (80, 90, 100)
MESH_TOL = (0.01, 0.02, 0.03)
FACING = (60, 75, 90, 105, 120, 135, 150)


def mesh_hits(
    X: np.ndarray, centres: np.ndarray, alpha: float | None, sphere: float | None
) -> np.ndarray:
    """(N, C) depth in front of each point X (N, 3) at which the ray from camera centre
    ``centres`` (C, 3) first meets a surface made of the frame's points (``--mesh``): their
    alpha shape (``alpha`` in metres) or a sphere of radius ``sphere`` around every point;
    0 where the ray meets nothing before the point."""
    import open3d as o3d

    d = X[:, None] - centres[None]  # (N, C, 3)
    dist = np.linalg.norm(d, axis=2)
    u = d / dist[..., None]
    if alpha is None:  # the nearest other point within `sphere` of the ray, in front
        front = np.zeros(dist.shape)
        for c in range(len(centres)):
            t = (X - centres[c]) @ u[:, c].T  # (M, N): along the ray to point n
            perp2 = np.sum((X - centres[c]) ** 2, axis=1)[:, None] - t**2
            ahead = (perp2 < sphere**2) & (t > 0)
            np.fill_diagonal(ahead, False)
            front[:, c] = np.max(np.where(ahead, dist[None, :, c] - t, 0.0), axis=0)
        return front
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(X))
    mesh = o3d.geometry.TriangleMesh.create_from_point_cloud_alpha_shape(pcd, alpha)
    rs = o3d.t.geometry.RaycastingScene()
    rs.add_triangles(
        o3d.core.Tensor(np.asarray(mesh.vertices, np.float32)),
        o3d.core.Tensor(np.asarray(mesh.triangles, np.uint32)),
    )
    rays = np.concatenate([np.broadcast_to(centres[None], d.shape), u], axis=2)
    t = rs.cast_rays(o3d.core.Tensor(rays.astype(np.float32)))["t_hit"].numpy()
    return np.where(np.isfinite(t), np.maximum(dist - t, 0.0), 0.0)


def _table_head(title: str, lead: list[str], columns: list[str]) -> None:
    """Print a title and a Markdown table's header."""
    print(f"\n{title}")
    print("| " + " | ".join(lead + columns) + " |")
    print("|---" * len(lead) + "|" + "---|" * len(columns))


def _cells(kept: np.ndarray, total_true: int) -> str:
    """Table cells "precision / recall" of (kept views, right ones) rows (T, 2)."""
    return " | ".join(f"{h / max(k, 1):.3f} / {h / max(total_true, 1):.3f}" for k, h in kept)


def convex_normals(X: np.ndarray) -> dict[str, np.ndarray]:
    """Normals (N, 3) of a frame's points X (N, 3) from their offsets to their neighbours'
    centroid, by neighbourhood (``--convex``)."""
    from scipy.spatial import cKDTree

    def unit(v: np.ndarray) -> np.ndarray:
        return v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-12)

    tree = cKDTree(X)
    out = {}
    for k in (12, 24):
        _, idx = tree.query(X, min(k, len(X)))
        nb = X[idx]  # (N, k, 3)
        centre = nb.mean(axis=1)
        d = nb - centre[:, None]
        _, vec = np.linalg.eigh(np.einsum("nki,nkj->nij", d, d))  # ascending eigenvalues
        off = X - centre
        axis = vec[:, :, 2]
        plane = (
            vec[:, :, 0] * np.where(np.einsum("ni,ni->n", vec[:, :, 0], off) < 0, -1, 1)[:, None]
        )
        out[f"offset, {k} nearest"] = unit(off)
        out[f"offset across the long axis, {k} nearest"] = unit(
            off - np.einsum("ni,ni->n", off, axis)[:, None] * axis
        )
        out[f"plane fit oriented by the offset, {k} nearest"] = plane
    for r in (0.06, 0.10):
        centre = np.array([X[i].mean(axis=0) for i in tree.query_ball_point(X, r)])
        out[f"offset, within {r * 100:.0f} cm"] = unit(X - centre)
    return out


def dense_samples(
    capture: Path, per_part: int
) -> tuple[object, np.ndarray, np.ndarray, np.ndarray]:
    """The capture's scene (posed by ``scene.poses(t / fps)``), and ``per_part`` samples per
    labelled geometry: geometry index (M,), local points (M, 3) and local normals (M, 3)."""
    from pointtraj.config import load_toml
    from pointtraj.synth.scenes import make_scene, scale_scene

    doc = load_toml(capture / "gt" / "synth.toml")
    scene = make_scene(str(doc["scene"]), int(doc["seed"]))
    if "scale" in doc:
        from pointtraj.synth.presets import PRESETS

        scene = scale_scene(scene, float(doc["scale"]), PRESETS[str(doc["preset"])].target)
    rng = np.random.default_rng(5)
    geo, loc, nrm = [], [], []
    for g, geom in enumerate(scene.geometries):
        if geom.label < 0:
            continue
        pts, tri = geom.mesh.sample_surface(per_part, rng)
        c = geom.mesh.vertices[geom.mesh.triangles[tri]]  # (n, 3, 3)
        n = np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0])
        geo.append(np.full(len(pts), g))
        loc.append(pts)
        nrm.append(n / np.linalg.norm(n, axis=1, keepdims=True))
    return scene, np.concatenate(geo), np.concatenate(loc), np.concatenate(nrm)


def main() -> None:
    from scipy.spatial import cKDTree

    from pointtraj.config import load_toml
    from pointtraj.evaluate.views import true_visibility
    from pointtraj.reconstruct.views import _directions, point_normals
    from pointtraj.session import Capture
    from pointtraj.trajectories import Trajectories, dequantize_visibility

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("capture", type=Path)
    ap.add_argument("work", type=Path)
    ap.add_argument("--every", type=int, default=3, help="audit every n-th frame")
    ap.add_argument("--samples", type=int, default=3000, help="ground-truth samples per part")
    ap.add_argument("--radius", type=float, default=0.03)
    ap.add_argument("--depth-tol", type=float, default=0.01)
    ap.add_argument("--neighbors", type=int, default=12, help="of the fitted normals")
    ap.add_argument("--convex", action="store_true", help="also the offset-to-centroid normals")
    ap.add_argument(
        "--facing",
        action="store_true",
        help="also views far from the mean direction of the point's other observing cameras",
    )
    ap.add_argument(
        "--mesh",
        action="store_true",
        help="also views hidden by a surface of the frame's points (alpha shapes, spheres)",
    )
    args = ap.parse_args()

    scene, geo, loc, nrm = dense_samples(args.capture, args.samples)
    fps = float(load_toml(args.capture / "gt" / "synth.toml")["fps"])
    traj = Trajectories.load(args.work / "trajectories.npz")
    rig = Capture.open(args.capture).rig.subset(traj.camera_names)
    nb = len(BINS) - 1
    obs_n, hit_n, true_n = np.zeros(nb), np.zeros(nb), np.zeros(nb)
    fit_obs, fit_hit = np.zeros(len(FITTED)), np.zeros(len(FITTED))
    total_true = 0
    convex: dict[str, list] = {}  # name: [angle errors, (kept views, right) per threshold]
    meshes = {f"alpha shape, {a * 100:.0f} cm": (a, None) for a in (0.04, 0.06, 0.08, 0.12)}
    meshes |= {f"spheres, {r * 100:.1f} cm": (None, r) for r in (0.015, 0.025, 0.035)}
    mesh_kept = {k: np.zeros((len(MESH_TOL), 2)) for k in meshes}
    facing_kept = np.zeros((len(FACING), 2))
    for t in range(0, traj.num_frames, args.every):
        rows = traj.frame_rows(t)
        if not len(rows):
            continue
        poses = scene.poses(t / fps)
        R = poses[geo, :3, :3]
        xyz = np.einsum("mij,mj->mi", R, loc) + poses[geo, :3, 3]
        normal = np.einsum("mij,mj->mi", R, nrm)
        X = traj.xyz[rows].astype(np.float64)
        observed = dequantize_visibility(traj.visibility[rows]) > 0.05  # (N, C)
        dist, idx = cKDTree(xyz).query(X)
        actor = dist <= args.radius
        s, sn = xyz[idx[actor]], normal[idx[actor]]
        vis, _ = true_visibility(args.capture, rig, t, s, args.depth_tol)  # (A, C)
        obs = observed[actor]
        to_cam = _directions(rig, s)  # (C, A, 3)
        angle = np.degrees(np.arccos(np.clip(np.einsum("cak,ak->ac", to_cam, sn), -1, 1)))
        b = np.digitize(angle, BINS) - 1
        for i in range(nb):
            obs_n[i] += (obs & (b == i)).sum()
            hit_n[i] += (obs & vis & (b == i)).sum()
            true_n[i] += (vis & (b == i)).sum()
        total_true += vis.sum()
        fitted = point_normals(rig, X, observed.T, args.neighbors)
        cos_fit = np.einsum("cnk,nk->nc", _directions(rig, X), fitted)[actor]
        fit_angle = np.degrees(np.arccos(np.clip(cos_fit, -1, 1)))
        for i, th in enumerate(FITTED):
            keep = obs & (fit_angle <= th)
            fit_obs[i] += keep.sum()
            fit_hit[i] += (keep & vis).sum()
        if args.facing:
            to_X = _directions(rig, X)  # (C, N, 3)
            o = observed.T.astype(float)  # (C, N)
            total = np.einsum("cn,cnk->nk", o, to_X)
            others = total[None] - o[..., None] * to_X  # (C, N, 3): the other cameras' sum
            others /= np.maximum(np.linalg.norm(others, axis=2, keepdims=True), 1e-12)
            ang = np.degrees(np.arccos(np.clip(np.einsum("cnk,cnk->nc", others, to_X), -1, 1)))
            ang = ang[actor]
            for i, th in enumerate(FACING):
                keep = obs & (ang <= th)
                facing_kept[i] += keep.sum(), (keep & vis).sum()
        if args.mesh:
            for name, (a, r) in meshes.items():
                front = mesh_hits(X, rig.C, a, r)[actor]
                for i, tol in enumerate(MESH_TOL):
                    keep = obs & (front <= tol)
                    mesh_kept[name][i] += keep.sum(), (keep & vis).sum()
        if args.convex:
            to_X = _directions(rig, X)
            for name, n in convex_normals(X).items():
                acc = convex.setdefault(name, [[], np.zeros((len(CONVEX_KEPT), 2))])
                cos_true = np.clip(np.einsum("ak,ak->a", n[actor], sn), -1, 1)
                acc[0].append(np.degrees(np.arccos(cos_true)))
                cos = np.clip(np.einsum("cnk,nk->nc", to_X, n)[actor], -1, 1)
                ang = np.degrees(np.arccos(cos))
                for i, th in enumerate(CONVEX_KEPT):
                    keep = obs & (ang <= th)
                    acc[1][i] += keep.sum(), (keep & vis).sum()
    print(
        f"observed views of actor points by the true surface's incidence ({args.samples} "
        f"samples a part, every {args.every} frames):"
    )
    print("| incidence | observed views | precision | true views | recall |")
    print("|---|---:|---:|---:|---:|")
    for i in range(nb):
        print(
            f"| {BINS[i]}-{BINS[i + 1]} deg | {int(obs_n[i]):,} | {hit_n[i] / max(obs_n[i], 1):.3f} "
            f"| {int(true_n[i]):,} | {hit_n[i] / max(true_n[i], 1):.3f} |"
        )
    print(
        f"| all | {int(obs_n.sum()):,} | {hit_n.sum() / max(obs_n.sum(), 1):.3f} "
        f"| {int(true_n.sum()):,} | {hit_n.sum() / max(true_n.sum(), 1):.3f} |"
    )
    print("\ndropping observed views beyond an angle to the fitted normal:")
    print("| views kept up to | views kept | precision | recall |")
    print("|---|---:|---:|---:|")
    for i, th in enumerate(FITTED):
        print(
            f"| {th} deg | {int(fit_obs[i]):,} | {fit_hit[i] / max(fit_obs[i], 1):.3f} "
            f"| {fit_hit[i] / max(total_true, 1):.3f} |"
        )
    if args.facing:
        print("\nviews dropped beyond an angle to the other observing cameras' mean (--facing):")
        print("| views kept up to | views kept | precision | recall |")
        print("|---|---:|---:|---:|")
        for th, (k, h) in zip(FACING, facing_kept, strict=True):
            print(f"| {th} deg | {int(k):,} | {h / max(k, 1):.3f} | {h / max(total_true, 1):.3f} |")
    if args.mesh:
        _table_head(
            "views dropped where a surface of the frame's points lies in front (--mesh):",
            ["surface"],
            [f"in front by > {t * 100:.0f} cm: precision / recall" for t in MESH_TOL],
        )
        for name, kept in mesh_kept.items():
            print(f"| {name} | {_cells(kept, total_true)} |")
    if convex:
        _table_head(
            "normals from the offset to the neighbours' centroid (--convex):",
            ["normal", "angle to the true normal, median / p75 / p90"],
            [f"views kept up to {th} deg: precision / recall" for th in CONVEX_KEPT],
        )
        for name, (errs, kept) in convex.items():
            e = np.concatenate(errs)
            print(
                f"| {name} | {np.median(e):.1f} / {np.percentile(e, 75):.1f} / "
                f"{np.percentile(e, 90):.1f} | {_cells(kept, total_true)} |"
            )


if __name__ == "__main__":
    main()
