"""Per-part 6-DoF motion and joint centres from labelled trajectories (``segments.npz``).

Every labelled body part of every person moves almost rigidly, so its labelled trajectories
give its motion:

- **Segment poses** (:func:`fit_segment_poses`). A segment is one (class, person). Its
  *reference frame* is the frame where most of its trajectories are alive; there every
  trajectory's position is its *reference coordinate*. Frame by frame, outwards from the
  reference (forward, then backward), the pose ``x_t = R_t x_ref + t_t`` is a RANSAC rigid fit
  (:func:`pointtraj.geometry.ransac_rigid_groups`, all segments of a frame at once) of the
  trajectories alive at t that have a reference coordinate; mislabelled points are the
  outliers. A trajectory born later gets its reference coordinate from the first pose fitted
  while it is alive (``x_ref = R_t^T (x_t - t_t)``), so fragmentary trajectories chain the
  motion across the capture. Memory: O(M) for the reference coordinates, O(N_t) per frame.
- **Joint centres** (:func:`fit_joint_centres`): for each pair of adjacent parts (the
  ``[[joints]]`` of ``labels.toml``, :data:`pointtraj.labelset.BODY_JOINTS` by default) of one
  person, SCoRE (Ehrig et al. 2006): the point ``c_A`` fixed in part A and ``c_B`` fixed in
  part B that stay together, ``min Σ_t ‖R_A(t) c_A + t_A(t) - R_B(t) c_B - t_B(t)‖²``, a
  linear least squares in six unknowns over the frames where both poses exist.

A joint is *observable* along the directions in which the two parts rotate relative to each
other. With rotation about three axes (``"ball"``) its centre is unique; about one axis
(``"hinge"``: knees, elbows) the centre is only known to lie on the functional axis, and
pointtraj reports the point of the axis nearest the child part's centroid (for a limb, the
axis's crossing with the limb's midplane; ``SegmentsConfig.hinge_centres = false`` makes these
NaN instead). A joint whose parts
have too few common frames or too little relative rotation is NaN, with its status saying why.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from .errors import FileFormatError, ValidationError, check_array
from .geometry import ransac_rigid_groups
from .scale import SceneLength

if TYPE_CHECKING:
    from .labelset import LabelSet
    from .trajectories import Trajectories

__all__ = [
    "SegmentsConfig",
    "Segments",
    "JOINT_STATUS",
    "fit_segment_poses",
    "fit_joint_centres",
    "compute_segments",
    "save_segments",
    "load_segments",
    "FORMAT_VERSION",
]

logger = logging.getLogger(__name__)

FORMAT_VERSION = 1

#: Joint status codes (``joint_status`` of ``segments.npz``), in code order: ``ball`` (0, a
#: unique centre), ``hinge`` (1, rotation about one axis: the point of the axis nearest the
#: child part's centroid), ``few_frames`` (2, NaN: fewer than ``min_frames`` frames with both
#: poses), ``no_rotation`` (3, NaN: less relative rotation than ``min_rotation_deg`` about
#: two axes), ``missing_part`` (4, NaN: a part with no pose at all), ``hinge_off`` (5, NaN: a
#: hinge with ``hinge_centres`` off), ``uncertain`` (6, NaN: the centre's standard error along
#: its least-rotated solved direction is above ``max_uncertainty``).
JOINT_STATUS: tuple[str, ...] = (
    "ball",
    "hinge",
    "few_frames",
    "no_rotation",
    "missing_part",
    "hinge_off",
    "uncertain",
)


@dataclass(frozen=True)
class SegmentsConfig:
    """Settings of the segment poses and joint centres (table ``[segments]`` of a pipeline).

    Attributes
    ----------
    ransac_threshold : float
        Inlier distance of the rigid fits, metres.
    ransac_iterations : int
        RANSAC hypotheses per segment and frame.
    refinements : int
        Inlier re-selections and refits after the best hypothesis.
    min_points : int
        Fewest inliers a segment needs in a frame for a pose (at least 3).
    min_frames : int
        Fewest frames with both parts' poses for a joint centre.
    min_rotation_deg : float
        Least root-mean-square relative rotation (degrees) about an axis for that axis to
        count: below it about two axes the joint is not observable, about one it is a hinge.
    hinge_centres : bool
        Report a hinge's centre (the point of its axis nearest the child part's centroid);
        False makes it NaN.
    prior_deg : float
        Weight of the pull towards the child's centroid, as an RMS relative rotation
        (degrees): it decides the centre along a hinge's axis and shrinks a direction rotated
        by θ by ``θ² / (θ² + prior_deg²)`` (a ball joint rotated 20° is biased by 0.25 % of the
        child centroid's distance to the joint; 0 turns the pull off).
    max_uncertainty : float
        Largest standard error (metres) of a joint centre along its least-rotated solved
        direction, estimated from the residual gap between the two parts' copies of the centre:
        above it the joint is ``uncertain`` (NaN). Small rotations with noisy poses, or two
        parts that do not share a fixed point (a joint in between), fail it.
    classes : str
        Which classes get segments: ``"body"`` (the label set's body parts) or ``"all"``.
    seed : int
        Seed of the RANSAC samples.
    """

    ransac_threshold: float = SceneLength(0.02)
    ransac_iterations: int = 64
    refinements: int = 2
    min_points: int = 8
    min_frames: int = 10
    min_rotation_deg: float = 3.0
    hinge_centres: bool = True
    prior_deg: float = 1.0
    max_uncertainty: float = SceneLength(0.02)
    classes: str = "body"
    seed: int = 0

    def __post_init__(self) -> None:
        if not (self.ransac_threshold > 0 and np.isfinite(self.ransac_threshold)):
            raise ValidationError(
                f"ransac_threshold must be positive, got {self.ransac_threshold!r}"
            )
        for name in ("ransac_iterations", "min_frames"):
            if int(getattr(self, name)) < 1:
                raise ValidationError(f"{name} must be at least 1, got {getattr(self, name)!r}")
        if int(self.min_points) < 3:
            raise ValidationError(f"min_points must be at least 3, got {self.min_points!r}")
        if int(self.refinements) < 0:
            raise ValidationError(f"refinements must be non-negative, got {self.refinements!r}")
        if not (0 <= self.min_rotation_deg < 90):
            raise ValidationError(
                f"min_rotation_deg must lie in [0, 90), got {self.min_rotation_deg!r}"
            )
        if not self.max_uncertainty > 0:
            raise ValidationError(f"max_uncertainty must be positive, got {self.max_uncertainty!r}")
        if not (0 <= self.prior_deg < 90):
            raise ValidationError(f"prior_deg must lie in [0, 90), got {self.prior_deg!r}")
        if self.classes not in ("body", "all"):
            raise ValidationError(f"classes must be 'body' or 'all', got {self.classes!r}")


@dataclass(eq=False)
class Segments:
    """Poses of S segments over T frames and J joint centres (``segments.npz``).

    A pose maps a segment's reference coordinates (world positions at its reference frame)
    to frame t: ``x_t = rotation[s, t] @ x_ref + translation[s, t]``; it is the identity at
    the reference frame and NaN where the segment has no pose.

    Attributes
    ----------
    class_names : tuple of K str
        The label set's classes.
    segment_label : (S,) int64 ndarray
        Class of each segment.
    segment_instance : (S,) int64 ndarray
        Person of each segment (0 without person instances; -1 = no person).
    reference_frame : (S,) int64 ndarray
    origin : (S, 3) float64 ndarray
        Centroid of the segment's trajectories in reference coordinates.
    rotation : (S, T, 3, 3) float64 ndarray
    translation : (S, T, 3) float64 ndarray
    points : (S, T) int64 ndarray
        Trajectories of the segment alive at t with a reference coordinate (the fit's input).
    inliers : (S, T) int64 ndarray
        RANSAC inliers of the pose (0 without a pose).
    residual : (S, T) float64 ndarray
        Root mean square distance of the inliers to the fitted pose, metres (NaN without).
    joint_names : tuple of J str
    joint_segments : (J, 2) int64 ndarray
        Parent and child segment of each joint.
    joint_instance : (J,) int64 ndarray
    joint_local : (J, 2, 3) float64 ndarray
        The centre in the parent's and in the child's reference coordinates (NaN if not
        observable).
    joint_status : (J,) int8 ndarray
        Index into :data:`JOINT_STATUS`.
    joint_frames : (J,) int64 ndarray
        Frames with both poses.
    joint_rotation_deg : (J, 3) float64 ndarray
        RMS relative rotation about the three least-rotated directions, ascending, degrees.
    joint_residual : (J,) float64 ndarray
        RMS distance between the centre as carried by the parent and by the child, metres.
    joint_uncertainty : (J,) float64 ndarray
        Standard error of the centre along its least-rotated solved direction, metres.
    fps : float
    params : dict
        The settings used.
    """

    class_names: tuple[str, ...]
    segment_label: np.ndarray
    segment_instance: np.ndarray
    reference_frame: np.ndarray
    origin: np.ndarray
    rotation: np.ndarray
    translation: np.ndarray
    points: np.ndarray
    inliers: np.ndarray
    residual: np.ndarray
    joint_names: tuple[str, ...] = ()
    joint_segments: np.ndarray | None = None
    joint_instance: np.ndarray | None = None
    joint_local: np.ndarray | None = None
    joint_status: np.ndarray | None = None
    joint_frames: np.ndarray | None = None
    joint_rotation_deg: np.ndarray | None = None
    joint_residual: np.ndarray | None = None
    joint_uncertainty: np.ndarray | None = None
    fps: float = 30.0
    params: dict | None = None

    def __post_init__(self) -> None:
        self.class_names = tuple(str(n) for n in self.class_names)
        self.joint_names = tuple(str(n) for n in self.joint_names)
        S, T = np.shape(self.points)
        J = len(self.joint_names)
        self.segment_label = np.asarray(self.segment_label, np.int64)
        self.segment_instance = np.asarray(self.segment_instance, np.int64)
        self.reference_frame = np.asarray(self.reference_frame, np.int64)
        self.origin = np.asarray(self.origin, np.float64)
        self.rotation = np.asarray(self.rotation, np.float64)
        self.translation = np.asarray(self.translation, np.float64)
        self.points = np.asarray(self.points, np.int64)
        self.inliers = np.asarray(self.inliers, np.int64)
        self.residual = np.asarray(self.residual, np.float64)
        defaults = {
            "joint_segments": ((J, 2), np.int64, -1),
            "joint_instance": ((J,), np.int64, 0),
            "joint_local": ((J, 2, 3), np.float64, np.nan),
            "joint_status": ((J,), np.int8, JOINT_STATUS.index("missing_part")),
            "joint_frames": ((J,), np.int64, 0),
            "joint_rotation_deg": ((J, 3), np.float64, np.nan),
            "joint_residual": ((J,), np.float64, np.nan),
            "joint_uncertainty": ((J,), np.float64, np.nan),
        }
        for name, (shape, dtype, fill) in defaults.items():
            value = getattr(self, name)
            value = np.full(shape, fill, dtype) if value is None else np.asarray(value, dtype)
            setattr(self, name, value)
        shapes = {
            "segment_label": (S,),
            "segment_instance": (S,),
            "reference_frame": (S,),
            "origin": (S, 3),
            "rotation": (S, T, 3, 3),
            "translation": (S, T, 3),
            "inliers": (S, T),
            "residual": (S, T),
            **{name: shape for name, (shape, _, _) in defaults.items()},
        }
        for name, shape in shapes.items():
            if getattr(self, name).shape != shape:
                raise ValidationError(
                    f"{name}: expected shape {shape}, got {getattr(self, name).shape}"
                )
        if self.params is None:
            self.params = {}

    @property
    def num_segments(self) -> int:
        """S."""
        return int(self.points.shape[0])

    @property
    def num_frames(self) -> int:
        """T."""
        return int(self.points.shape[1])

    def segment_names(self) -> list[str]:
        """Name of each segment: its class, prefixed by ``person<i>/`` when there are persons.

        Segments of person -1 (labelled points that belong to no person) are ``nobody/<class>``.
        """
        persons = set(self.segment_instance.tolist()) | set(self.joint_instance.tolist())
        many = persons not in (set(), {0})
        return [
            _prefixed(self.class_names[k], i, many)
            for k, i in zip(self.segment_label, self.segment_instance)
        ]

    def joint_labels(self) -> list[str]:
        """Name of each joint, prefixed like :meth:`segment_names`."""
        persons = set(self.segment_instance.tolist()) | set(self.joint_instance.tolist())
        many = persons not in (set(), {0})
        return [_prefixed(n, i, many) for n, i in zip(self.joint_names, self.joint_instance)]

    def centroids(self) -> np.ndarray:
        """(S, T, 3) float64 world position of each segment's origin (NaN without a pose)."""
        return np.einsum("stij,sj->sti", self.rotation, self.origin) + self.translation

    def joint_positions(self) -> np.ndarray:
        """(J, T, 3) float64 world joint centres: the mean of the centre as the parent and the
        child carry it; NaN where the joint is not observable or a pose is missing."""
        J, T = len(self.joint_names), self.num_frames
        if J == 0:
            return np.zeros((0, T, 3))
        seg = np.maximum(self.joint_segments, 0)  # (J, 2)
        ends = [
            np.einsum("jtik,jk->jti", self.rotation[seg[:, e]], self.joint_local[:, e])
            + self.translation[seg[:, e]]
            for e in (0, 1)
        ]  # 2 x (J, T, 3)
        out = 0.5 * (ends[0] + ends[1])
        out[(self.joint_segments < 0).any(axis=1)] = np.nan
        return out


def _prefixed(name: str, instance: int, many: bool) -> str:
    if not many:
        return name
    return f"person{instance}/{name}" if instance >= 0 else f"nobody/{name}"


# -- segment poses -------------------------------------------------------------------------------
def _segment_index(
    labels: np.ndarray, instance: np.ndarray, classes: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Segments (class, person) and the segment of every trajectory (-1 = none)."""
    use = (labels >= 0) & np.isin(labels, classes)
    pairs = np.stack([labels[use], instance[use]], axis=1)  # (M', 2)
    uniq, inv = np.unique(pairs, axis=0, return_inverse=True)
    seg = np.full(labels.shape[0], -1, np.int64)
    seg[use] = inv.reshape(-1)
    return seg, uniq[:, 0].astype(np.int64), uniq[:, 1].astype(np.int64)


def fit_segment_poses(
    trajectories: Trajectories,
    labels: np.ndarray,
    instance: np.ndarray | None = None,
    classes: Sequence[int] | None = None,
    config: SegmentsConfig | None = None,
    *,
    class_names: Sequence[str] = (),
    progress: Callable[[int, int], None] | None = None,
) -> Segments:
    """Fit the 6-DoF pose of every labelled part (and person) in every frame.

    Parameters
    ----------
    trajectories : Trajectories
        M trajectories over T frames.
    labels : (M,) int ndarray
        Class of each trajectory (-1 = unlabelled).
    instance : (M,) int ndarray, optional
        Person of each trajectory (-1 = none); without it every labelled trajectory is person 0.
    classes : sequence of int, optional
        Classes that get segments (default: every class that occurs).
    config : SegmentsConfig, optional
    class_names : sequence of str
        The K class names (stored in the result).
    progress : callable, optional
        ``progress(done, total)`` after each frame of the two sweeps.

    Returns
    -------
    Segments
        Without joints (:func:`fit_joint_centres` adds them).

    Raises
    ------
    ValidationError
        If ``labels`` or ``instance`` do not have one entry per trajectory.
    """
    cfg = config or SegmentsConfig()
    M, T = trajectories.num_trajectories, trajectories.num_frames
    labels = check_array("labels", labels, (M,), dtype=np.int64)
    instance = (
        np.zeros(M, np.int64)
        if instance is None
        else check_array("instance", instance, (M,), dtype=np.int64)
    )
    classes = np.unique(labels[labels >= 0]) if classes is None else np.asarray(classes, np.int64)
    seg_of_track, seg_label, seg_inst = _segment_index(labels, instance, classes)
    S = seg_label.shape[0]
    # points of each segment alive per frame: the reference frame is the best-populated one
    row_seg = seg_of_track[trajectories.row_track]  # (P,)
    keep = row_seg >= 0
    counts = np.bincount(row_seg[keep] * T + trajectories.row_frame[keep], minlength=S * T).reshape(
        S, T
    )
    del row_seg, keep
    ref = counts.argmax(axis=1) if S else np.zeros(0, np.int64)
    rot = np.full((S, T, 3, 3), np.nan)
    trans = np.full((S, T, 3), np.nan)
    npts = np.zeros((S, T), np.int64)
    inl = np.zeros((S, T), np.int64)
    res = np.full((S, T), np.nan)
    canon = np.full((M, 3), np.nan)  # reference coordinates, set once per trajectory
    rng = np.random.default_rng([cfg.seed, 18])
    order = [(t, True) for t in range(T)] + [(t, False) for t in range(T - 1, -1, -1)]
    for step, (t, forward) in enumerate(order):
        active = (ref <= t) if forward else (ref > t)  # (S,)
        if S == 0 or not active.any():
            continue
        rows = trajectories.frame_rows(t)
        tracks = trajectories.row_track[rows]
        seg = seg_of_track[tracks]
        ok = seg >= 0
        ok[ok] = active[seg[ok]]
        rows, tracks, seg = rows[ok], tracks[ok], seg[ok]
        xyz = trajectories.xyz[rows].astype(np.float64)  # (N, 3)
        if forward:  # segments whose reference frame this is: identity pose
            seed = ref[seg] == t
            canon[tracks[seed]] = xyz[seed]
            here = np.flatnonzero(ref == t)
            rot[here, t] = np.eye(3)
            trans[here, t] = 0.0
            npts[here, t] = inl[here, t] = counts[here, t]
            res[here, t] = 0.0
            rows, tracks, seg, xyz = rows[~seed], tracks[~seed], seg[~seed], xyz[~seed]
        known = np.isfinite(canon[tracks, 0])
        npts[:, t] = np.where(active & (ref != t), np.bincount(seg[known], minlength=S), npts[:, t])
        if known.any():
            fit = ransac_rigid_groups(
                canon[tracks[known]],
                xyz[known],
                seg[known],
                S,
                threshold=cfg.ransac_threshold,
                iterations=cfg.ransac_iterations,
                rng=rng,
                min_inliers=cfg.min_points,
                refinements=cfg.refinements,
            )
            good = fit.valid & active & (ref != t)
            rot[good, t] = fit.rotation[good]
            trans[good, t] = fit.translation[good]
            inl[good, t] = fit.inliers[good]
            res[good, t] = fit.residual[good]
            # trajectories new to the segment get their reference coordinates from this pose
            new = ~known & good[seg]
            s_new = seg[new]
            canon[tracks[new]] = np.einsum(
                "nji,nj->ni", rot[s_new, t], xyz[new] - trans[s_new, t]
            )  # R^T (x - t)
        if progress is not None:
            progress(step + 1, len(order))
    # origin: centroid of each segment's reference coordinates
    have = (seg_of_track >= 0) & np.isfinite(canon[:, 0])
    sums = np.stack(
        [np.bincount(seg_of_track[have], weights=canon[have, k], minlength=S) for k in range(3)],
        axis=1,
    )
    n = np.bincount(seg_of_track[have], minlength=S)
    with np.errstate(invalid="ignore", divide="ignore"):
        origin = sums / n[:, None]
    logger.info(
        "segment poses: %d segments, %d of %d segment-frames posed",
        S,
        int(np.isfinite(rot[:, :, 0, 0]).sum()),
        S * T,
    )
    return Segments(
        class_names=tuple(class_names),
        segment_label=seg_label,
        segment_instance=seg_inst,
        reference_frame=ref,
        origin=origin,
        rotation=rot,
        translation=trans,
        points=npts,
        inliers=inl,
        residual=res,
        fps=float(trajectories.fps),
        params={k: getattr(cfg, k) for k in cfg.__dataclass_fields__},
    )


# -- joint centres -------------------------------------------------------------------------------
def fit_joint_centres(
    segments: Segments,
    joints: Sequence[tuple[str, str, str]],
    config: SegmentsConfig | None = None,
) -> Segments:
    """SCoRE joint centres between adjacent segments of each person.

    For a joint between parts A (parent) and B (child), with offsets ``a``, ``b`` from their
    origins ``o_A``, ``o_B`` (reference coordinates), every frame t with both poses gives three
    equations ``[R_A(t), -R_B(t)] [a; b] = C_B(t) - C_A(t)`` (``C`` the world centroids). The
    normal equations ``N x = g`` (6 x 6) are summed over the frames; with ``N / T``'s three
    smallest eigenvalues ``λ_i``, ``sqrt(2 λ_i)`` is the RMS relative rotation about the
    matching direction. Directions rotated less than ``min_rotation_deg`` are dropped from the
    solve (the minimum-norm solution): one dropped is a hinge, whose centre then slides along
    the axis to the point nearest the child's centroid; two or more leave the joint
    unobservable (NaN).

    Parameters
    ----------
    segments : Segments
        Poses from :func:`fit_segment_poses`.
    joints : sequence of (str, str, str)
        ``(name, parent class, child class)``; a joint is made for every person that has
        a segment of either part.
    config : SegmentsConfig, optional

    Returns
    -------
    Segments
        ``segments`` with the ``joint_*`` fields filled.

    References
    ----------
    R. M. Ehrig, W. R. Taylor, G. N. Duda, M. O. Heller, "A survey of formal methods for
    determining the centre of rotation of ball joints", J. Biomech. 39(15), 2006 (SCoRE).
    """
    cfg = config or SegmentsConfig()
    names = segments.class_names
    index = {
        (int(k), int(i)): s
        for s, (k, i) in enumerate(zip(segments.segment_label, segments.segment_instance))
    }
    persons = sorted(set(segments.segment_instance.tolist()))
    rows = []  # (name, instance, parent segment, child segment)
    for person in persons:
        for jn, parent, child in joints:
            if parent not in names or child not in names:
                continue
            sa = index.get((names.index(parent), person), -1)
            sb = index.get((names.index(child), person), -1)
            if sa < 0 and sb < 0:
                continue
            rows.append((jn, person, sa, sb))
    J = len(rows)
    seg = np.array([[r[2], r[3]] for r in rows], np.int64).reshape(J, 2)
    status = np.full(J, JOINT_STATUS.index("missing_part"), np.int8)
    local = np.full((J, 2, 3), np.nan)
    frames = np.zeros(J, np.int64)
    spread = np.full((J, 3), np.nan)
    resid = np.full(J, np.nan)
    uncert = np.full(J, np.nan)
    both = (seg >= 0).all(axis=1)
    if both.any():
        sa, sb = seg[both, 0], seg[both, 1]
        Ra, Rb = segments.rotation[sa], segments.rotation[sb]  # (J', T, 3, 3)
        C = segments.centroids()
        y = C[sb] - C[sa]  # (J', T, 3)
        ok = np.isfinite(Ra[..., 0, 0]) & np.isfinite(Rb[..., 0, 0])  # (J', T)
        A = np.concatenate([Ra, -Rb], axis=-1)  # (J', T, 3, 6)
        A = np.where(ok[..., None, None], A, 0.0)
        y = np.where(ok[..., None], y, 0.0)
        N = np.einsum("jtki,jtkl->jil", A, A)  # (J', 6, 6)
        g = np.einsum("jtki,jtk->ji", A, y)  # (J', 6)
        nt = ok.sum(axis=1)  # (J',)
        lam, vec = np.linalg.eigh(N / np.maximum(nt, 1)[:, None, None])  # ascending
        ang = np.degrees(np.sqrt(2.0 * np.clip(lam[:, :3], 0.0, None)))  # (J', 3)
        dropped = (ang < cfg.min_rotation_deg).sum(axis=1)  # (J',)
        # ridge towards the child's centroid (b = 0), weighted as a relative rotation of
        # prior_deg: negligible along well-rotated directions, decisive along a hinge's axis
        mu = max(0.5 * np.radians(cfg.prior_deg) ** 2, 1e-12)  # > 0: solvable on a hinge
        Nn = N / np.maximum(nt, 1)[:, None, None] + mu * np.diag([0.0, 0, 0, 1, 1, 1])
        Nn = Nn + 1e-12 * np.eye(6)  # solvable without common frames (those are NaN below)
        x = np.linalg.solve(Nn, (g / np.maximum(nt, 1)[:, None])[..., None])[..., 0]  # (J', 6)
        st = np.where(dropped == 0, 0, np.where(dropped == 1, 1, 3)).astype(np.int8)
        if not cfg.hinge_centres:
            st[st == 1] = JOINT_STATUS.index("hinge_off")
        st[nt < cfg.min_frames] = JOINT_STATUS.index("few_frames")
        ca = segments.origin[sa] + x[:, :3]
        cb = segments.origin[sb] + x[:, 3:]
        lc = np.stack([ca, cb], axis=1)  # (J', 2, 3)
        wa = np.einsum("jtik,jk->jti", Ra, lc[:, 0]) + segments.translation[sa]
        wb = np.einsum("jtik,jk->jti", Rb, lc[:, 1]) + segments.translation[sb]
        d2 = np.where(ok, ((wa - wb) ** 2).sum(axis=-1), 0.0)
        with np.errstate(invalid="ignore", divide="ignore"):
            rj = np.sqrt(d2.sum(axis=1) / nt)  # (J',) RMS gap between the two ends
            # standard error along the least-rotated solved direction: the residual per
            # coordinate over sqrt(frames x eigenvalue) (the hinge's axis is the prior's)
            lam_solved = lam[np.arange(len(nt)), np.minimum(dropped, 5)]
            un = (rj / np.sqrt(3.0)) / np.sqrt(nt * np.maximum(lam_solved, 1e-300))
        st[(st <= 1) & ~(un <= cfg.max_uncertainty)] = JOINT_STATUS.index("uncertain")
        good = st <= 1
        lc[~good] = np.nan
        status[both], local[both], frames[both] = st, lc, nt
        spread[both], resid[both] = ang, np.where(good, rj, np.nan)
        uncert[both] = np.where(nt > 0, un, np.nan)
    for (jn, person, _, _), st in zip(rows, status):
        if st > 1:
            logger.info("joint %s (person %d): not observable (%s)", jn, person, JOINT_STATUS[st])
    segments.joint_names = tuple(r[0] for r in rows)
    segments.joint_instance = np.array([r[1] for r in rows], np.int64)
    segments.joint_segments = seg
    segments.joint_local = local
    segments.joint_status = status
    segments.joint_frames = frames
    segments.joint_rotation_deg = spread
    segments.joint_residual = resid
    segments.joint_uncertainty = uncert
    segments.params = {**(segments.params or {}), "joints": [list(j) for j in joints]}
    return segments


def compute_segments(
    trajectories: Trajectories,
    labels: np.ndarray,
    labelset: LabelSet,
    instance: np.ndarray | None = None,
    config: SegmentsConfig | None = None,
    *,
    progress: Callable[[int, int], None] | None = None,
) -> Segments:
    """Segment poses and joint centres of a labelled capture.

    Parameters
    ----------
    trajectories : Trajectories
    labels : (M,) int ndarray
        Class per trajectory (-1 = unlabelled).
    labelset : LabelSet
        Its classes, kinds and joints; without ``[[joints]]`` the body joints
        (:func:`pointtraj.labelset.body_joints`) of its body classes are used.
    instance : (M,) int ndarray, optional
        Person per trajectory (-1 = none); without it the labelled body is one person.
    config : SegmentsConfig, optional
    progress : callable, optional
        ``progress(done, total)`` per frame.

    Returns
    -------
    Segments
    """
    from .labelset import body_joints

    cfg = config or SegmentsConfig()
    classes = (
        labelset.classes_of_kind("body") if cfg.classes == "body" else np.arange(len(labelset))
    )
    joints = labelset.joints or body_joints([labelset.names[k] for k in classes])
    segments = fit_segment_poses(
        trajectories,
        labels,
        instance,
        classes,
        cfg,
        class_names=labelset.names,
        progress=progress,
    )
    return fit_joint_centres(segments, joints, cfg)


# -- segments.npz --------------------------------------------------------------------------------
_ARRAYS = (
    "segment_label",
    "segment_instance",
    "reference_frame",
    "origin",
    "rotation",
    "translation",
    "points",
    "inliers",
    "residual",
    "joint_segments",
    "joint_instance",
    "joint_local",
    "joint_status",
    "joint_frames",
    "joint_rotation_deg",
    "joint_residual",
    "joint_uncertainty",
)


def save_segments(segments: Segments, path: str | os.PathLike) -> None:
    """Write ``segments.npz`` atomically (``data_specs/segments.md``)."""
    import json

    from .atomic import save_npz_atomic

    save_npz_atomic(
        path,
        format_version=np.int64(FORMAT_VERSION),
        class_names=np.array(segments.class_names, dtype=str),
        joint_names=np.array(segments.joint_names, dtype=str),
        joint_status_names=np.array(JOINT_STATUS, dtype=str),
        fps=np.float64(segments.fps),
        params=np.array(json.dumps(segments.params, sort_keys=True, default=str)),
        **{name: getattr(segments, name) for name in _ARRAYS},
    )


def load_segments(path: str | os.PathLike) -> Segments:
    """Read ``segments.npz``.

    Raises
    ------
    FileFormatError
        Naming the file: missing, not an npz, another format version, a missing array or
        inconsistent shapes.
    """
    import json

    from .npzfile import load_npz

    path = Path(path)
    arrays = load_npz(
        path,
        ("format_version", "class_names", "joint_names", "fps", *_ARRAYS[:-1]),
        "a segments file",
        hint="run `pointtraj segments` first",
    )
    version = int(arrays["format_version"])
    if version != FORMAT_VERSION:
        raise FileFormatError(path, f"format_version {version} (expected {FORMAT_VERSION})")
    try:
        params = json.loads(str(arrays["params"])) if "params" in arrays else {}
        return Segments(
            class_names=tuple(str(n) for n in arrays["class_names"]),
            joint_names=tuple(str(n) for n in arrays["joint_names"]),
            fps=float(arrays["fps"]),
            params=params,
            **{name: arrays.get(name) for name in _ARRAYS},  # joint_uncertainty: optional
        )
    except (ValidationError, ValueError, TypeError) as exc:
        raise FileFormatError(path, str(exc)) from None
