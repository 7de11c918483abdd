"""Study: the paper's affinity study and the label accuracy of the graph cut, on synthetic captures.

1. **Affinity study** (paper Figure "aff", "Effectiveness of affinity measure"): on the
   ground-truth trajectories of a synthetic capture (optionally with Gaussian position noise),
   random neighbouring pairs are drawn uniformly in a 1 m ball around each trajectory (the
   paper's drop-out draws, :func:`pointtraj.affinity.candidate_pairs`) and binned by distance
   (0-1 m, 10 cm bins; a pair's distance is its largest distance over the shared lifetime, so
   every pair in bin [d, d + 0.1) is an ε_s-neighbour for ε_s = d + 0.1). Reported per bin: the
   fraction of pairs whose ground-truth labels differ among all pairs (``eps_s``) and among the
   SE(3)-affinity neighbours (``A > --threshold``) for each error mode and τ, and how many of the
   bin's same-label pairs the SE(3) neighbours keep (recall), since a test that keeps few pairs
   trivially has a low disagreement.
2. **Label accuracy** (``--work``): the work folder's trajectories (created from the ground
   truth when it has none) and semantic map (``pointtraj semantics WORK -r simulated``, default
   noise, created when missing). The true label of a trajectory is its ground-truth point's label
   when the trajectories are the ground truth, otherwise the majority label of the ground-truth
   label maps at its projections in the cameras that see it (visibility > 0.5); trajectories on
   the background are left out. Reported: accuracy, overall and for the hands and the ball, of
   argmax view- and average-pooled L3D, of the graph cut with the defaults, and of variants (each
   addition switched off, the former defaults, the paper's data cost, step mode, λ and τ sweeps),
   then a per-class table.

Usage (the captures of ``docs/labeling.md``)::

    .venv/bin/python benchmarks/study_affinity.py CAPTURE --work WORK [--noise 0 0.0005]
    .venv/bin/python benchmarks/study_affinity.py CAPTURE --work WORK --skip-affinity-study \\
        --semantics-option downsample=2
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

BINS = np.round(np.arange(0.0, 1.0001, 0.1), 2)


# -- data ---------------------------------------------------------------------------------------
def gt_trajectories(capture: Path):
    """(ground-truth Trajectories, label per trajectory (M,), class names)."""
    from pointtraj.synth.groundtruth import load_ground_truth

    gt = load_ground_truth(capture)
    traj = gt.to_trajectories()
    point = gt.segments()[0]
    return traj, gt.label[point].astype(np.int64), list(gt.class_names)


def with_noise(traj, sigma: float, seed: int = 0):
    """A copy of ``traj`` with i.i.d. Gaussian noise of ``sigma`` (m) on every coordinate."""
    if sigma <= 0:
        return traj
    rng = np.random.default_rng([seed, 7])
    return dataclasses.replace(
        traj, xyz=(traj.xyz + rng.normal(0, sigma, traj.xyz.shape)).astype(np.float32)
    )


def prepare_work(capture: Path, work: Path, options: list[str]):
    """(trajectories, truth (M,), SemanticMap, class names, 'ground truth' | 'voted')."""
    from pointtraj.semantics.semantic_map import SemanticMap
    from pointtraj.trajectories import Trajectories

    gt_traj, gt_label, names = gt_trajectories(capture)
    work.mkdir(parents=True, exist_ok=True)
    if not (work / "trajectories.npz").is_file():
        gt_traj.save(work / "trajectories.npz")
        (work / "work.toml").write_text(f'capture = "{capture.resolve()}"\n')
    if not (work / "semantic_map.npz").is_file():
        cmd = [sys.executable, "-m", "pointtraj", "semantics", str(work), "-r", "simulated"]
        cmd += [a for o in options for a in ("-o", o)]
        print("running:", " ".join(cmd), flush=True)
        subprocess.run(cmd, check=True)
    traj = Trajectories.load(work / "trajectories.npz")
    smap = SemanticMap.load(work / "semantic_map.npz")
    is_gt = traj.num_trajectories == gt_traj.num_trajectories and np.array_equal(
        traj.offsets, gt_traj.offsets
    )
    if is_gt and np.allclose(traj.xyz, gt_traj.xyz, atol=1e-6):
        return traj, gt_label, smap, names, "ground truth"
    from pointtraj.evaluate.groundtruth import voted_labels

    return traj, voted_labels(capture, traj), smap, names, "voted"


# -- 1. affinity study ---------------------------------------------------------------------------
def frac_by_bin(dist: np.ndarray, differ: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(fraction of differing pairs, pair count) per distance bin: the report's binning
    (:func:`pointtraj.evaluate.metrics.disagreement_by_distance`), empty bins 0."""
    from pointtraj.evaluate.metrics import disagreement_by_distance

    differ = np.asarray(differ, bool)
    frac, count = disagreement_by_distance(dist, differ, np.zeros_like(differ), BINS)
    return np.nan_to_num(frac), count


def affinity_study(traj, label, taus, modes, threshold: float, seed: int, draws: int) -> None:
    from pointtraj.affinity import (
        AffinityConfig,
        candidate_pairs,
        local_transforms,
        pair_errors,
        symmetric_affinity,
    )

    cfg = AffinityConfig(seed=seed)
    rng = np.random.default_rng([seed, 0])
    t0 = time.perf_counter()
    tf = local_transforms(traj, cfg, rng)
    i, j, d = candidate_pairs(traj, 1.0, 0, draws, rng)
    differ = label[i] != label[j]
    same_count = frac_by_bin(d[~differ], differ[~differ])[1]
    rows = {"eps_s (all pairs)": (*frac_by_bin(d, differ), None)}
    for mode in modes:
        e = np.stack([pair_errors(traj, tf, i, j, mode), pair_errors(traj, tf, j, i, mode)], 1)
        for tau in taus:
            a = symmetric_affinity(e[:, 0], e[:, 1], tau)  # NaN: untestable, not kept
            keep = np.nan_to_num(a) > threshold
            frac, count = frac_by_bin(d[keep], differ[keep])
            kept_same = frac_by_bin(d[keep & ~differ], differ[keep & ~differ])[1]
            rows[f"SE(3) {mode} tau={tau * 1000:g}mm"] = (
                frac,
                count,
                kept_same / np.maximum(same_count, 1),
            )
    print(f"  ({i.size} pairs, {time.perf_counter() - t0:.1f} s)")
    header = "bin (cm)".ljust(32) + "".join(
        f"{int(round(b * 100)):>4}-{int(round(c * 100)):<4}" for b, c in zip(BINS[:-1], BINS[1:])
    )
    print("fraction of pairs whose labels differ:")
    print(header)
    for name, (frac, count, _) in rows.items():
        print(
            name.ljust(32)
            + "".join(f"{f:9.3f}" if c >= 20 else "        -" for f, c in zip(frac, count))
            + f"   ({int(count.sum())} pairs)"
        )
    print("same-label pairs kept as SE(3) neighbours (recall):")
    print(header)
    for name, (_, _, recall) in rows.items():
        if recall is not None:
            print(name.ljust(32) + "".join(f"{r:9.3f}" for r in recall))


# -- 2. label accuracy ---------------------------------------------------------------------------
def variants(lambdas, taus):
    """(name, AffinityConfig overrides, LabelingConfig overrides, pooling) rows of the table."""
    rows = [
        ("cut: defaults", {}, {}, "view"),
        ("cut: defaults, average-pooled L3D", {}, {}, "average"),
        ("cut: paper data cost", {}, {"data_cost": "paper"}, "view"),
        ("cut: step mode", {"mode": "step"}, {}, "view"),
        ("cut: no spatial kernel", {"distance_scale": 0.0}, {}, "view"),
        ("cut: drop-out draws only", {"near_neighbors": 0}, {}, "view"),
        ("cut: near neighbours only", {"max_neighbors": 0}, {}, "view"),
        ("cut: untestable pairs dropped", {"missing_affinity": 0.0}, {}, "view"),
        ("cut: no SE(3) test (kernel only)", {"tau": 1e3}, {}, "view"),
        (
            "cut: former defaults",
            {
                "tau": 0.02,
                "mode": "step",
                "near_neighbors": 0,
                "distance_scale": 0.0,
                "missing_affinity": 0.0,
                "min_affinity": 1e-4,
            },
            {"smoothness": 1.0},
            "view",
        ),
    ]
    rows += [(f"cut: lambda={lam:g}", {}, {"smoothness": lam}, "view") for lam in lambdas]
    rows += [(f"cut: tau={tau * 1000:g}mm", {"tau": tau}, {}, "view") for tau in taus]
    return rows


def label_study(traj, truth, smap, names, noise: float, lambdas, taus, seed: int) -> None:
    from pointtraj.affinity import AffinityConfig, compute_affinity
    from pointtraj.labeling import LabelingConfig, label_trajectories

    fg = truth >= 0
    groups = {
        "hands": np.isin(truth, [k for k, n in enumerate(names) if n.endswith("_hand")]),
        "ball": truth == (names.index("ball") if "ball" in names else -9),
    }
    noisy = with_noise(traj, noise, seed)
    graphs: dict = {}
    results: dict[str, np.ndarray] = {}

    def row(name: str, pred: np.ndarray, extra: str = "") -> None:
        results[name] = pred
        cells = [f"{100 * (pred[fg] == truth[fg]).mean():6.1f}"]
        for m in groups.values():
            cells.append(f"{100 * (pred[m] == truth[m]).mean():6.1f}" if m.any() else "     -")
        print(f"| {name:<36} | " + " | ".join(cells) + f" | {extra}")

    print("| labels                               |    all |  hands |   ball | notes")
    print("|--------------------------------------|--------|--------|--------|------")
    for pooling in smap.poolings:
        row(f"argmax {pooling}-pooled L3D", smap.L3D[pooling].astype(np.float64).argmax(1))
    for name, aff_over, lab_over, pooling in variants(lambdas, taus):
        acfg = AffinityConfig(seed=seed, **aff_over)
        if acfg not in graphs:
            t0 = time.perf_counter()
            graphs[acfg] = (compute_affinity(noisy, acfg), time.perf_counter() - t0)
        g, secs = graphs[acfg]
        l3d = smap.L3D[pooling].astype(np.float64)
        res = label_trajectories(
            l3d, g.row, g.col, g.weight, LabelingConfig(**lab_over), support=smap.count[pooling]
        )
        changed = int((res.labels != l3d.argmax(1)).sum())
        assert all(b <= a + 1e-9 * max(1.0, abs(a)) for a, b in zip(res.energy, res.energy[1:]))
        row(
            name,
            res.labels,
            f"{g.num_edges / max(traj.num_trajectories, 1):.1f} edges/traj, {changed} changed, "
            f"affinity {secs:.1f} s, cut {res.seconds:.1f} s",
        )
    # per class
    base, cut = results["argmax view-pooled L3D"], results["cut: defaults"]
    print("\nper class (view-pooled L3D): count, argmax %, cut %")
    for k, n in enumerate(names):
        m = truth == k
        if m.any():
            print(
                f"  {n:<16} {int(m.sum()):6d} {100 * (base[m] == k).mean():6.1f}"
                f" {100 * (cut[m] == k).mean():6.1f}"
            )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("capture", type=Path, help="synthetic capture folder (with gt/)")
    ap.add_argument("--work", type=Path, help="work folder for the label accuracy study")
    ap.add_argument(
        "--semantics-option",
        dest="semantics_options",
        action="append",
        default=[],
        help="option of the simulated recogniser when the semantic map is created, e.g. "
        "downsample=2 (repeatable)",
    )
    ap.add_argument("--noise", type=float, nargs="+", default=[0.0, 0.0005], help="m")
    ap.add_argument("--tau", type=float, nargs="+", default=[0.001, 0.002, 0.005, 0.02])
    ap.add_argument("--modes", nargs="+", default=["accumulated", "step"])
    ap.add_argument("--threshold", type=float, default=0.5, help="A above this = neighbour")
    ap.add_argument("--draws", type=int, default=32, help="pairs drawn per trajectory (1 m)")
    ap.add_argument("--lambda", dest="lambdas", type=float, nargs="+", default=[0.1, 0.5, 1.0])
    ap.add_argument("--label-tau", type=float, nargs="+", default=[0.001, 0.005])
    ap.add_argument("--skip-affinity-study", action="store_true")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("-v", "--verbose", action="store_true")
    args = ap.parse_args()
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING)
    if not (args.capture / "gt").is_dir():
        sys.exit(f"{args.capture}: no gt/ folder (render one with `pointtraj synth`)")
    if not args.skip_affinity_study:
        traj, label, _ = gt_trajectories(args.capture)
        print(
            f"# affinity study: {traj.num_trajectories} ground-truth trajectories, "
            f"{traj.num_point_frames} point-frames, {traj.num_frames} frames"
        )
        for noise in args.noise:
            print(f"\n## position noise {noise * 1000:g} mm")
            affinity_study(
                with_noise(traj, noise, args.seed),
                label,
                args.tau,
                args.modes,
                args.threshold,
                args.seed,
                args.draws,
            )
    if args.work is not None:
        traj, truth, smap, names, kind = prepare_work(
            args.capture, args.work, args.semantics_options
        )
        fg = truth >= 0
        print(
            f"\n# label accuracy: {traj.num_trajectories} trajectories ({kind} labels; "
            f"{int(fg.sum())} on labelled parts), {traj.num_frames} frames, "
            f"{traj.num_cameras} cameras"
        )
        noises = args.noise if kind == "ground truth" else [0.0]
        for noise in noises:
            print(f"\n## position noise {noise * 1000:g} mm\n")
            label_study(traj, truth, smap, names, noise, args.lambdas, args.label_tau, args.seed)


if __name__ == "__main__":
    main()
