"""The 3D semantic map L3D: per trajectory, the time average of view-pooled 2D confidences.

The paper's Eq. 1-2: for trajectory i alive over frames T_e..T_d,
``L3D(X^i) = 1 / (T_d - T_e + 1) sum_t Pool_c L2D(P(X_t^i, c) | I_c)``.

:func:`build_semantic_map` streams over frames: at frame t it runs the recogniser once per
camera image, keeps that frame's C maps (coarse, a few MB each), samples them at the projections
of the points alive at t in chunks of :attr:`SemanticsConfig.chunk_size` points, pools each
point-frame across cameras (:func:`~pointtraj.semantics.pooling.pool_views`) and adds the result
to per-trajectory (M, K) accumulators; then the maps are dropped. Memory is therefore
O(M K + C h w K + chunk C K) and does not grow with the number of frames. Point-frames for which
pooling yields NaN (no usable camera) are left out of the average.

Each frame (recognition, sampling, pooling) is a task of an executor (:mod:`pointtraj.executor`):
serial by default, or on Dask workers that each load the recogniser once. Only the frame's
pooled (N, K) confidences come back, in frame order, and are accumulated here, so the map is
the same on any executor.

For the temporal-consistency study the pooled per-frame confidences of a seeded random subset
of trajectories (all of them when they fit in :attr:`SemanticsConfig.sample_budget_mb`) are kept
as well (:attr:`SemanticMap.samples`). The file format is ``data_specs/semantic_map.md``.
"""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, Protocol

import numpy as np

from ..atomic import save_npz_atomic
from ..errors import FileFormatError, ValidationError, check_array
from ..executor import Executor, SerialExecutor
from ..scale import SceneLength
from ..trajectories import Trajectories
from .pooling import POOLINGS, pool_views
from .recognizers import RecognizerSpec
from .recognizers.base import ImageContext, Recognizer
from .sampling import sample_confidences

__all__ = [
    "SemanticsConfig",
    "SemanticMap",
    "build_semantic_map",
    "geometric_visibility",
    "sample_views",
    "normalized_correlation",
    "load_semantic_map",
    "save_semantic_map",
]

logger = logging.getLogger(__name__)

FORMAT_VERSION = 1


#: A camera "sees no class" at a point when every confidence there is below this
#: (``SemanticsConfig.background_vote``).
NOTHING_CONFIDENCE = 0.05


@dataclass(frozen=True)
class SemanticsConfig:
    """Parameters of the semantic map.

    Attributes
    ----------
    eps_e : float
        The paper's visibility threshold ε_e: only cameras with ``V(X, c) > eps_e`` take part in
        view pooling. With ``V = exp(-(e / σ)^2)`` the default 0.1 keeps cameras whose
        reprojection error is below about 1.5 σ; with ground-truth visibility (0 or 1) any value
        in (0, 1) is the same.
    poolings : tuple of str
        Pooling methods to compute (see :mod:`pointtraj.semantics.pooling`); the first is the
        default one of the map.
    chunk_size : int
        Points sampled and pooled at once (bounds the (C, chunk, K) temporaries).
    sample_budget_mb : float
        Memory cap of the per-frame pooled samples kept for the temporal-consistency study.
    sample_tracks : int or None
        At most this many trajectories get per-frame samples (None: as many as fit the budget).
    seed : int
        Seed of the random choice of sampled trajectories.
    visibility : {"geometric", "observed"}
        The visibility V that pooling uses. ``"observed"``: the trajectory store's, which is 0
        in every camera without an observation of the point (reprojection-error visibility,
        the paper's Equation (visibility)). ``"geometric"`` (default): also
        ``unobserved_visibility`` in the cameras where the point projects into the image and is
        not occluded by the frame's own points (:func:`geometric_visibility`): the matches chain
        into tracks of only a few views, so observed visibility leaves view pooling one or
        two cameras to choose from (``docs/semantics.md`` has the measurement).
    unobserved_visibility : float
        V of an unoccluded camera without an observation, with ``"geometric"``.
    occlusion_depth_m : float
        Depth tolerance of the occlusion test (m), with ``"geometric"``.
    occlusion_cell_px : float
        Z-buffer cell of the occlusion test (pixels), with ``"geometric"``.
    background_vote : float
        Silhouette consistency (0 turns it off). A point-frame is pooled as "nothing" (a
        zero vector) when at least this fraction of its cameras (``V > eps_e``, inside the
        image) see no class there (every confidence below :data:`NOTHING_CONFIDENCE`): a point
        on a person projects onto the person in every camera that sees it, so a point that
        half of its cameras see as background is background or misplaced in depth.
    person_budget_mb : float
        Memory cap of the person votes (:attr:`SemanticMap.person_votes`, 12 bytes per
        point-frame and camera in a person mask): past it, votes are kept on every s-th frame
        only (s from an upper bound, P C 12 bytes). 0 keeps none.
    """

    eps_e: float = 0.1
    poolings: tuple[str, ...] = ("view", "average")
    chunk_size: int = 4096
    sample_budget_mb: float = 256.0
    sample_tracks: int | None = None
    seed: int = 0
    visibility: Literal["geometric", "observed"] = "geometric"
    unobserved_visibility: float = 0.5
    occlusion_depth_m: float = SceneLength(0.05)
    occlusion_cell_px: float = 8.0
    background_vote: float = 0.0
    person_budget_mb: float = 256.0

    def __post_init__(self) -> None:
        if self.visibility not in ("geometric", "observed"):
            raise ValidationError(f"visibility: 'geometric' or 'observed', got {self.visibility!r}")
        if not 0.0 <= self.eps_e < 1.0:  # first: unobserved_visibility's range depends on it
            raise ValidationError(f"eps_e: must be in [0, 1), got {self.eps_e}")
        if not self.eps_e < self.unobserved_visibility <= 1.0:
            raise ValidationError(
                f"unobserved_visibility: must be in (eps_e, 1], got {self.unobserved_visibility}"
            )
        if not 0.0 <= self.background_vote <= 1.0:
            raise ValidationError(f"background_vote: must be in [0, 1], got {self.background_vote}")
        if not (self.occlusion_depth_m > 0 and self.occlusion_cell_px > 0):
            raise ValidationError("occlusion_depth_m and occlusion_cell_px must be > 0")
        if not self.poolings:
            raise ValidationError("poolings: need at least one pooling method")
        for p in self.poolings:
            if p not in POOLINGS:
                raise ValidationError(f"poolings: unknown {p!r} (valid: {', '.join(POOLINGS)})")
        if len(set(self.poolings)) != len(self.poolings):
            raise ValidationError(f"poolings: duplicates in {self.poolings}")
        if self.chunk_size < 1:
            raise ValidationError(f"chunk_size: must be >= 1, got {self.chunk_size}")
        if self.sample_budget_mb < 0:
            raise ValidationError(f"sample_budget_mb: must be >= 0, got {self.sample_budget_mb}")
        if self.person_budget_mb < 0:
            raise ValidationError(f"person_budget_mb: must be >= 0, got {self.person_budget_mb}")


def geometric_visibility(
    rig: Any, xyz: np.ndarray, visibility: np.ndarray, config: SemanticsConfig
) -> np.ndarray:
    """Observed visibility, raised where a camera sees the point unoccluded without observing it.

    Parameters
    ----------
    rig : CameraRig
        C cameras.
    xyz : (N, 3) float ndarray
        One frame's points (all of them: they are the occluders).
    visibility : (N, C) float ndarray
        Observed visibility (the trajectory store's).
    config : SemanticsConfig
        ``unobserved_visibility``, ``occlusion_depth_m``, ``occlusion_cell_px``.

    Returns
    -------
    (N, C) float32 ndarray
        ``max(V, unobserved_visibility)`` where the point is inside camera c's image, in front
        of it and not behind the frame's z-buffer there
        (:func:`pointtraj.reconstruct.occlusion.occlusion_test`); ``V`` elsewhere.
    """
    from ..reconstruct.occlusion import occlusion_test

    V = np.asarray(visibility, np.float32)
    if len(xyz) == 0:
        return V
    X = np.asarray(xyz, np.float64)
    proj = rig.project(X)
    occluded = occlusion_test(
        rig, X, config.occlusion_depth_m, cell_px=config.occlusion_cell_px, projection=proj
    )  # (N, C)
    seen = proj.in_image.T & ~occluded  # (N, C) in front, inside the image, not occluded
    return np.where(seen, np.maximum(V, np.float32(config.unobserved_visibility)), V)


class CaptureLike(Protocol):
    """What :func:`build_semantic_map` needs of a capture (``pointtraj.session.Capture``)."""

    rig: Any

    def read(self, camera: str | int, frame: int) -> np.ndarray: ...


def normalized_correlation(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Pearson correlation across the K classes of row pairs (the paper's NC).

    Parameters
    ----------
    a, b : (n, K) float ndarrays

    Returns
    -------
    (n,) float64 ndarray
        ``sum_k (a_k - mean a)(b_k - mean b) / (||a - mean a|| ||b - mean b||)``; NaN where a
        row has zero variance or contains NaN.

    Examples
    --------
    >>> normalized_correlation(np.array([[1.0, 0, 0], [1, 0, 0]]), np.array([[2.0, 0, 0], [0, 1, 0]]))
    array([ 1. , -0.5])
    """
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if a.shape != b.shape or a.ndim != 2:
        raise ValidationError(f"a, b: expected two (n, K) arrays, got {a.shape} and {b.shape}")
    a = a - a.mean(axis=1, keepdims=True)
    b = b - b.mean(axis=1, keepdims=True)
    den = np.sqrt((a * a).sum(axis=1) * (b * b).sum(axis=1))
    with np.errstate(invalid="ignore", divide="ignore"):
        nc = (a * b).sum(axis=1) / den
    nc[~(den > 0)] = np.nan
    return nc


@dataclass(eq=False)
class SemanticMap:
    """The 3D semantic map of M trajectories over K classes, for one or more poolings.

    Attributes
    ----------
    class_names : tuple of K str
    L3D : dict of str to (M, K) float32 ndarray
        Per pooling, the mean over each trajectory's lifetime of its pooled confidences; a
        trajectory with no pooled frame (``count == 0``) has a row of zeros.
    count : dict of str to (M,) int32 ndarray
        Per pooling, the number of frames that entered the average.
    sample_tracks : (S,) int64 ndarray
        Trajectories whose per-frame pooled confidences are kept (sorted).
    sample_offsets : (S + 1,) int64 ndarray
        Rows ``sample_offsets[s]:sample_offsets[s + 1]`` of :attr:`samples` are trajectory
        ``sample_tracks[s]``'s frames, first frame first.
    sample_first_frame : (S,) int64 ndarray
        First frame of each sampled trajectory.
    samples : dict of str to (Q, K) float32 ndarray
        Per pooling, the pooled confidences of the sampled point-frames (NaN rows where pooling
        found no usable camera).
    eps_e : float
        Visibility threshold used.
    recognizer : str
        Name of the recogniser used.
    fps : float
        Frame rate of the trajectories.
    recognizer_options : dict
        The recogniser's options (strings, numbers and booleans), so that a later stage (the
        report's predictive validity) can run the same recogniser.
    person_votes : (E, 3) int32 ndarray
        Where the recogniser gives person masks (:meth:`Recognizer.recognize_people`): one row
        ``(trajectory, image, person)`` per point-frame and camera (``V > eps_e``, inside the
        image) that falls in a person mask, ``image = frame * C + camera``, ``person`` the
        image's own person id. Empty without masks. The labelling stage's instances vote with
        them (:mod:`pointtraj.instances`).
    """

    class_names: tuple[str, ...]
    L3D: dict[str, np.ndarray]
    count: dict[str, np.ndarray]
    sample_tracks: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    sample_offsets: np.ndarray = field(default_factory=lambda: np.zeros(1, np.int64))
    sample_first_frame: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    samples: dict[str, np.ndarray] = field(default_factory=dict)
    eps_e: float = SemanticsConfig.eps_e
    recognizer: str = ""
    fps: float = 30.0
    recognizer_options: dict[str, Any] = field(default_factory=dict)
    person_votes: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.int32))

    def __post_init__(self) -> None:
        self.class_names = tuple(self.class_names)
        self.person_votes = np.asarray(self.person_votes, np.int32)
        if self.person_votes.ndim != 2 or self.person_votes.shape[1] != 3:
            raise ValidationError(
                f"person_votes: expected shape (E, 3), got {self.person_votes.shape}"
            )
        K = len(self.class_names)
        if not self.L3D:
            raise ValidationError("L3D: needs at least one pooling")
        M = None
        for p, arr in self.L3D.items():
            if arr.ndim != 2 or arr.shape[1] != K or (M is not None and arr.shape[0] != M):
                raise ValidationError(f"L3D[{p!r}]: expected shape (M, {K}), got {arr.shape}")
            M = arr.shape[0]
            if p not in self.count or self.count[p].shape != (M,):
                raise ValidationError(f"count[{p!r}]: expected shape ({M},)")
        S = len(self.sample_tracks)
        if self.sample_offsets.shape != (S + 1,) or self.sample_first_frame.shape != (S,):
            raise ValidationError("sample_offsets/sample_first_frame: inconsistent with tracks")
        Q = int(self.sample_offsets[-1])
        for p, arr in self.samples.items():
            if arr.shape != (Q, K):
                raise ValidationError(f"samples[{p!r}]: expected shape ({Q}, {K}), got {arr.shape}")

    @property
    def poolings(self) -> tuple[str, ...]:
        """The pooling methods held, the default first."""
        return tuple(self.L3D)

    @property
    def num_trajectories(self) -> int:
        """M."""
        return next(iter(self.L3D.values())).shape[0]

    @property
    def confidences(self) -> np.ndarray:
        """(M, K) float32 L3D of the default (first) pooling."""
        return self.L3D[self.poolings[0]]

    def argmax_labels(self, pooling: str | None = None) -> np.ndarray:
        """(M,) int64 argmax class of L3D; -1 for trajectories with no pooled frame."""
        p = self._pooling(pooling)
        labels = np.argmax(self.L3D[p], axis=1).astype(np.int64)
        labels[self.count[p] == 0] = -1
        return labels

    def _pooling(self, pooling: str | None) -> str:
        if pooling is None:
            return self.poolings[0]
        if pooling not in self.L3D:
            raise ValidationError(
                f"pooling: {pooling!r} not in this map (has: {', '.join(self.poolings)})"
            )
        return pooling

    def temporal_consistency(
        self, lag: int, pooling: str | None = None, trajectories: np.ndarray | None = None
    ) -> tuple[float, float, int]:
        """The paper's temporal consistency: NC between first-frame and later pooled confidences.

        Parameters
        ----------
        lag : int
            Frames between the two samples (e.g. ``fps`` for 1 s).
        pooling : str, optional
            Default: the map's first pooling.
        trajectories : (M,) bool ndarray, optional
            Only these trajectories (e.g. the labelled ones: background trajectories have
            confidences of noise only, whose NC says nothing about a semantic map).

        Returns
        -------
        mean, std : float
            Over the sampled trajectories that live at least ``lag + 1`` frames and whose two
            pooled samples are defined (NaN if there are none), of
            ``NC(L_pool(first frame), L_pool(first frame + lag))`` (:func:`normalized_correlation`).
        n : int
            Number of trajectories averaged.
        """
        _, nc = self.first_frame_nc(lag, pooling, trajectories)
        if nc.size == 0:
            return float("nan"), float("nan"), 0
        return float(nc.mean()), float(nc.std()), int(nc.size)

    def first_frame_nc(
        self, lag: int, pooling: str | None = None, trajectories: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Per trajectory, the NC that :meth:`temporal_consistency` averages.

        Parameters
        ----------
        lag, pooling, trajectories
            As :meth:`temporal_consistency`.

        Returns
        -------
        tracks : (n,) int64 ndarray
            The sampled trajectories that live at least ``lag + 1`` frames and whose two pooled
            samples give a defined NC.
        nc : (n,) float64 ndarray
            ``NC(L_pool(first frame), L_pool(first frame + lag))`` of each.
        """
        p = self._pooling(pooling)
        if p not in self.samples:
            raise ValidationError(f"pooling: no per-frame samples kept for {p!r}")
        lengths = np.diff(self.sample_offsets)
        ok = lengths > lag
        if trajectories is not None:
            mask = check_array("trajectories", trajectories, (self.num_trajectories,), dtype=bool)
            ok &= mask[self.sample_tracks]
        start = self.sample_offsets[:-1][ok]
        nc = normalized_correlation(self.samples[p][start], self.samples[p][start + lag])
        defined = np.isfinite(nc)
        return self.sample_tracks[ok][defined].astype(np.int64), nc[defined]

    def save(self, path: str | os.PathLike) -> None:
        """Write ``semantic_map.npz`` atomically (format: ``data_specs/semantic_map.md``)."""
        arrays: dict[str, np.ndarray] = {
            "format_version": np.array(FORMAT_VERSION),
            "class_names": np.array(self.class_names, dtype=str),
            "poolings": np.array(self.poolings, dtype=str),
            "sample_tracks": self.sample_tracks.astype(np.int64),
            "sample_offsets": self.sample_offsets.astype(np.int64),
            "sample_first_frame": self.sample_first_frame.astype(np.int64),
            "eps_e": np.array(self.eps_e, dtype=np.float64),
            "recognizer": np.array(self.recognizer),
            "fps": np.array(self.fps, dtype=np.float64),
            "recognizer_options": np.array(json.dumps(self.recognizer_options, sort_keys=True)),
        }
        if len(self.person_votes):
            arrays["person_votes"] = self.person_votes.astype(np.int32)
        for p in self.poolings:
            arrays[f"L3D_{p}"] = self.L3D[p].astype(np.float32)
            arrays[f"count_{p}"] = self.count[p].astype(np.int32)
            if p in self.samples:
                arrays[f"samples_{p}"] = self.samples[p].astype(np.float32)
        save_npz_atomic(path, **arrays)

    @classmethod
    def load(cls, path: str | os.PathLike) -> SemanticMap:
        """Read ``semantic_map.npz``.

        Raises
        ------
        FileFormatError
            Missing file, missing array, wrong version or inconsistent shapes (naming the array).
        """
        from ..npzfile import load_npz

        path = Path(path)
        arrays = load_npz(path, ("format_version", "class_names", "poolings"), "a semantic map")
        if int(arrays["format_version"]) != FORMAT_VERSION:
            raise FileFormatError(
                path, f"format_version {int(arrays['format_version'])} (expected {FORMAT_VERSION})"
            )
        poolings = [str(p) for p in arrays["poolings"]]
        L3D, count, samples = {}, {}, {}
        for p in poolings:
            for key in (f"L3D_{p}", f"count_{p}"):
                if key not in arrays:
                    raise FileFormatError(path, f"missing array {key!r}")
            L3D[p] = arrays[f"L3D_{p}"].astype(np.float32)
            count[p] = arrays[f"count_{p}"].astype(np.int32)
            if f"samples_{p}" in arrays:
                samples[p] = arrays[f"samples_{p}"].astype(np.float32)
        try:
            return cls(
                class_names=tuple(str(n) for n in arrays["class_names"]),
                L3D=L3D,
                count=count,
                sample_tracks=arrays.get("sample_tracks", np.zeros(0, np.int64)),
                sample_offsets=arrays.get("sample_offsets", np.zeros(1, np.int64)),
                sample_first_frame=arrays.get("sample_first_frame", np.zeros(0, np.int64)),
                samples=samples,
                eps_e=float(arrays.get("eps_e", SemanticsConfig.eps_e)),
                recognizer=str(arrays.get("recognizer", "")),
                fps=float(arrays.get("fps", 30.0)),
                recognizer_options=json.loads(str(arrays.get("recognizer_options", "{}"))),
                person_votes=arrays.get("person_votes", np.zeros((0, 3), np.int32)),
            )
        except json.JSONDecodeError:
            raise FileFormatError(path, "recognizer_options: not JSON") from None
        except ValidationError as exc:
            raise FileFormatError(path, str(exc)) from None


def load_semantic_map(path: str | os.PathLike) -> SemanticMap:
    """Read ``semantic_map.npz`` (same as :meth:`SemanticMap.load`)."""
    return SemanticMap.load(path)


def save_semantic_map(semantic_map: SemanticMap, path: str | os.PathLike) -> None:
    """Write ``semantic_map.npz`` (same as :meth:`SemanticMap.save`)."""
    semantic_map.save(path)


def _select_sample_tracks(
    trajectories: Trajectories, K: int, n_poolings: int, config: SemanticsConfig
) -> np.ndarray:
    """Sorted trajectories whose per-frame samples fit the memory budget."""
    lengths = trajectories.lengths
    M = len(lengths)
    max_rows = int(config.sample_budget_mb * 2**20 // max(1, 4 * K * n_poolings))
    limit = M if config.sample_tracks is None else min(M, config.sample_tracks)
    if limit >= M and lengths.sum() <= max_rows:
        return np.arange(M, dtype=np.int64)
    order = np.random.default_rng(config.seed).permutation(M)[:limit]
    keep = order[np.cumsum(lengths[order]) <= max_rows]
    return np.sort(keep).astype(np.int64)


def build_semantic_map(
    capture: CaptureLike | str | os.PathLike,
    trajectories: Trajectories | str | os.PathLike,
    recognizer: Recognizer,
    poolings: tuple[str, ...] | None = None,
    eps_e: float | None = None,
    *,
    config: SemanticsConfig | None = None,
    frames: range | None = None,
    capture_dir: str | os.PathLike | None = None,
    progress: Callable[[str, int, int], None] | None = None,
    executor: Executor | None = None,
) -> SemanticMap:
    """Build the 3D semantic map of trajectories from a capture's images.

    Parameters
    ----------
    capture : Capture or path-like
        The capture (``pointtraj.session.Capture``, or its folder): its rig must contain the
        trajectories' cameras.
    trajectories : Trajectories or path-like
        The trajectory store (or its ``trajectories.npz``); its visibility gives V.
    recognizer : Recognizer or RecognizerSpec
        Produces L2D per image; its ``class_names`` are the map's classes. On a Dask executor
        give a :class:`~pointtraj.semantics.recognizers.RecognizerSpec`: each worker then makes
        the recogniser (loads its model) once, instead of receiving it pickled.
    poolings : tuple of str, optional
        Overrides ``config.poolings``.
    eps_e : float, optional
        Overrides ``config.eps_e``.
    config : SemanticsConfig, optional
    frames : range, optional
        Frames to process (default: all ``trajectories.num_frames``). Point-frames outside are
        left out of the averages.
    capture_dir : path-like, optional
        Capture folder passed to the recogniser in :class:`ImageContext` (default: the
        capture's ``path`` attribute, or ``capture`` itself when it is a path).
    progress : callable, optional
        ``progress("semantic map", done, total)``: ``done`` of the ``total`` frames, from 0
        before the first frame to ``total`` after the last (the command line draws a bar).
    executor : Executor, optional
        Where the frames are recognised, sampled and pooled (default: serially, here); the map
        is the same on any executor (each frame's pooled confidences come back in frame order
        and are summed here).

    Returns
    -------
    SemanticMap

    Raises
    ------
    ValidationError
        If a trajectory camera is missing from the rig, or the recogniser's output has the
        wrong number of channels.
    """
    config = config or SemanticsConfig()
    if poolings is not None or eps_e is not None:
        from dataclasses import replace

        config = replace(
            config,
            **({"poolings": tuple(poolings)} if poolings is not None else {}),
            **({"eps_e": float(eps_e)} if eps_e is not None else {}),
        )
    if isinstance(capture, str | os.PathLike):
        from ..session import Capture

        capture_dir = capture_dir or capture
        capture = Capture.open(capture)
    if capture_dir is None:
        for attr in ("path", "root", "directory"):
            if getattr(capture, attr, None) is not None:
                capture_dir = getattr(capture, attr)
                break
    if isinstance(trajectories, str | os.PathLike):
        trajectories = Trajectories.load(trajectories)
    names = list(trajectories.camera_names)
    missing = [n for n in names if n not in capture.rig.names]
    if missing:
        raise ValidationError(
            f"trajectories: camera {missing[0]!r} is not in the capture's rig "
            f"({len(capture.rig)} cameras)"
        )
    rig = capture.rig.subset(names)
    class_names = tuple(recognizer.class_names)
    recognizer_name = recognizer.name
    K = len(class_names)
    M, C = len(trajectories), len(names)
    pools = config.poolings
    ctx_capture = None if capture_dir is None else os.fspath(capture_dir)

    sums = {p: np.zeros((M, K), dtype=np.float64) for p in pools}
    counts = {p: np.zeros(M, dtype=np.int32) for p in pools}
    sample_tracks = _select_sample_tracks(trajectories, K, len(pools), config)
    lengths = trajectories.lengths
    sample_offsets = np.zeros(len(sample_tracks) + 1, dtype=np.int64)
    np.cumsum(lengths[sample_tracks], out=sample_offsets[1:])
    slot = np.full(M, -1, dtype=np.int64)
    slot[sample_tracks] = np.arange(len(sample_tracks))
    samples = {p: np.full((int(sample_offsets[-1]), K), np.nan, np.float32) for p in pools}
    first_frame = trajectories.first_frame
    logger.info(
        "semantic map: %d trajectories, %d cameras, %d classes, poolings %s; per-frame samples "
        "of %d trajectories",
        M,
        C,
        K,
        ", ".join(pools),
        len(sample_tracks),
    )

    frames = range(trajectories.num_frames) if frames is None else frames
    executor = executor or SerialExecutor()
    # person votes: an upper bound of 12 bytes per point-frame and camera, kept under budget
    vote_bytes = 12.0 * len(trajectories.xyz) * C
    budget = config.person_budget_mb * 2**20
    person_stride = 0 if budget <= 0 else max(1, int(np.ceil(vote_bytes / budget)))
    if person_stride > 1:
        logger.info("person votes on every %d-th frame (person_budget_mb)", person_stride)
    votes: list[np.ndarray] = []
    job = _FrameJob(
        capture=capture,
        trajectories=trajectories,
        recognizer=recognizer,
        rig=rig,
        names=tuple(names),
        config=config,
        K=K,
        capture_dir=ctx_capture,
        person_stride=person_stride,
    )
    if progress is not None:
        progress("semantic map", 0, len(frames))
    pooled_frames = executor.map(
        _pool_frame,
        [int(t) for t in frames],
        label="semantic map",
        progress=progress,
        context=job,
    )
    for t, pooled in zip(frames, pooled_frames, strict=True):
        if pooled is None:  # no point alive, or no camera needed
            continue
        track_id = trajectories.row_track[trajectories.frame_rows(int(t))]
        if "_people" in pooled:  # (E_t, 3): point of the frame, camera, person
            local = pooled["_people"]
            votes.append(
                np.stack(
                    [track_id[local[:, 0]], int(t) * C + local[:, 1], local[:, 2]], axis=1
                ).astype(np.int32)
            )
        sel = slot[track_id]  # (N,)
        has_sample = sel >= 0
        rows = sample_offsets[sel[has_sample]] + (int(t) - first_frame[track_id[has_sample]])
        for p in pools:
            ok = np.isfinite(pooled[p]).all(axis=1)
            sums[p][track_id[ok]] += pooled[p][ok]  # track ids are unique within a frame
            counts[p][track_id[ok]] += 1
            if rows.size:
                samples[p][rows] = pooled[p][has_sample]

    L3D = {}
    for p in pools:
        with np.errstate(invalid="ignore", divide="ignore"):
            mean = sums[p] / counts[p][:, None]
        mean[counts[p] == 0] = 0.0
        L3D[p] = mean.astype(np.float32)
    return SemanticMap(
        class_names=class_names,
        L3D=L3D,
        count=counts,
        sample_tracks=sample_tracks,
        sample_offsets=sample_offsets,
        sample_first_frame=first_frame[sample_tracks].astype(np.int64),
        samples=samples,
        eps_e=config.eps_e,
        recognizer=recognizer_name,
        fps=float(trajectories.fps),
        person_votes=np.concatenate(votes) if votes else np.zeros((0, 3), np.int32),
    )


def sample_views(
    rig: Any,
    sizes: np.ndarray,
    maps: Sequence[np.ndarray | None],
    xyz: np.ndarray,
    V: np.ndarray,
    eps_e: float,
    only_visible: bool = True,
) -> tuple[np.ndarray, np.ndarray]:
    """One frame's confidence maps sampled at its points' projections, camera by camera.

    Parameters
    ----------
    rig : CameraRig
        C cameras.
    sizes : (C, 2) int ndarray
        Image sizes (W, H) the projections refer to.
    maps : sequence of C (h, w, K) float ndarrays or None
        Each camera's L2D (None: a camera not needed; its rows stay 0). At least one is given.
    xyz : (n, 3) float ndarray
    V : (n, C) float ndarray
        Visibility.
    eps_e : float
        With ``only_visible``, cameras with ``V <= eps_e`` are not sampled (their rows stay 0).
    only_visible : bool
        Sample only where ``V > eps_e`` (every pooling but ``average`` needs no more).

    Returns
    -------
    L : (C, n, K) float32 ndarray
        Bilinear samples (:func:`~pointtraj.semantics.sampling.sample_confidences`); 0 where a
        point projects outside the image or is not sampled.
    in_image : (C, n) bool ndarray
        Whether each point projects inside each image, in front of the camera.
    """
    K = next(m.shape[2] for m in maps if m is not None)
    n, C = len(xyz), len(maps)
    proj = rig.project(xyz)
    in_image = np.asarray(proj.in_image, dtype=bool)  # (C, n)
    L = np.zeros((C, n, K), dtype=np.float32)
    for c, L2D in enumerate(maps):
        if L2D is None:
            continue
        use = in_image[c] & (V[:, c] > eps_e) if only_visible else in_image[c]
        if use.all():
            L[c] = sample_confidences(L2D, proj.pixels[c], tuple(sizes[c]))
        elif use.any():  # unused rows sample to 0 as NaN pixels
            px = np.where(use[:, None], proj.pixels[c], np.nan)  # (n, 2)
            L[c] = sample_confidences(L2D, px, tuple(sizes[c]))
    return L, in_image


@dataclass(frozen=True)
class _FrameJob:
    """What every frame task of :func:`build_semantic_map` shares (sent once to each worker)."""

    capture: Any  # a CaptureLike (pickled once to each worker; a Capture reads its own files)
    trajectories: Trajectories
    recognizer: Recognizer | RecognizerSpec
    rig: Any
    names: tuple[str, ...]
    config: SemanticsConfig
    K: int
    capture_dir: str | None
    person_stride: int = 0


def _pool_frame(job: _FrameJob, t: int) -> dict[str, np.ndarray] | None:
    """One frame: recognise the cameras it needs, sample and pool its points (a task).

    Returns
    -------
    dict of str to (N, K) float32 ndarray, or None
        Per pooling, the pooled confidences of the frame's N points, in the order of
        ``trajectories.frame(t)`` (NaN rows: no usable camera); None if nothing is pooled.
        Where the recogniser gives person masks (on the frames of ``person_stride``), also
        ``"_people"``: (E, 3) int32 rows (point of the frame, camera, person id) of the
        point-frames (``V > eps_e``, inside the image) that fall in a person mask.
    """
    config, K, names, rig = job.config, job.K, job.names, job.rig
    capture = job.capture
    recognizer = job.recognizer
    if isinstance(recognizer, RecognizerSpec):
        recognizer = recognizer.cached()
    fs = job.trajectories.frame(int(t))
    N, C = len(fs.track_id), len(names)
    if N == 0:
        return None
    pools, eps = config.poolings, config.eps_e
    V = fs.visibility  # (N, C)
    if config.visibility == "geometric":
        V = geometric_visibility(rig, fs.xyz, V, config)
    needed = np.ones(C, dtype=bool) if "average" in pools else (V > eps).any(axis=0)  # (C,)
    if not needed.any():
        return None
    needs_image = getattr(recognizer, "needs_image", True)
    # This frame's maps, one per camera (coarse: a few MB each); dropped after the frame.
    maps: list[np.ndarray | None] = [None] * C
    people: list[np.ndarray | None] = [None] * C
    with_people = job.person_stride > 0 and int(t) % job.person_stride == 0
    for c in np.flatnonzero(needed):
        image = capture.read(names[c], int(t)) if needs_image else None
        ctx = ImageContext(camera=names[c], frame=int(t), capture=job.capture_dir)
        if with_people:
            L2D, people[c] = recognizer.recognize_people(image, ctx)
        else:
            L2D = recognizer.recognize(image, ctx)
        if L2D.ndim != 3 or L2D.shape[2] != K:
            raise ValidationError(
                f"recogniser {recognizer.name!r} returned shape {L2D.shape} for camera "
                f"{names[c]!r} frame {t}; expected (h, w, {K})"
            )
        maps[c] = L2D
    sizes = np.asarray(rig.sizes)  # (C, 2) (W, H)
    out = {p: np.empty((N, K), np.float32) for p in pools}
    for start in range(0, N, config.chunk_size):
        sl = slice(start, min(N, start + config.chunk_size))
        pooled = _pool_chunk(fs.xyz[sl], V[sl], rig, sizes, maps, pools, eps, config)
        for p in pools:
            out[p][sl] = pooled[p]
    if any(m is not None for m in people):
        out["_people"] = _person_votes(rig, sizes, people, fs.xyz, V, eps)
    return out


def _person_votes(
    rig: Any,
    sizes: np.ndarray,
    people: list[np.ndarray | None],
    xyz: np.ndarray,
    V: np.ndarray,
    eps: float,
) -> np.ndarray:
    """The person masks under one frame's points: (E, 3) int32 rows (point, camera, person).

    ``people`` holds per camera an (h, w) int16 person-id map (-1: none) or None; a point
    votes in the cameras with ``V > eps`` where it projects inside the image, with the id of
    the cell it falls in (nearest cell, the sampling convention of
    :mod:`pointtraj.semantics.sampling`).
    """
    proj = rig.project(xyz)
    rows = []
    for c, ids in enumerate(people):
        if ids is None:
            continue
        use = np.flatnonzero(np.asarray(proj.in_image[c], bool) & (V[:, c] > eps))  # (n,)
        if not use.size:
            continue
        W, H = (int(v) for v in sizes[c])
        h, w = ids.shape
        px = proj.pixels[c][use]  # (n, 2)
        x = np.clip(np.rint((px[:, 0] + 0.5) * w / W - 0.5), 0, w - 1).astype(np.int64)
        y = np.clip(np.rint((px[:, 1] + 0.5) * h / H - 0.5), 0, h - 1).astype(np.int64)
        pid = ids[y, x]  # (n,)
        hit = pid >= 0
        rows.append(np.stack([use[hit], np.full(int(hit.sum()), c), pid[hit]], axis=1))
    return np.concatenate(rows).astype(np.int32) if rows else np.zeros((0, 3), np.int32)


def _pool_chunk(
    xyz: np.ndarray,
    V: np.ndarray,
    rig: Any,
    sizes: np.ndarray,
    maps: list[np.ndarray | None],
    pools: tuple[str, ...],
    eps: float,
    config: SemanticsConfig,
) -> dict[str, np.ndarray]:
    """Sample and pool one chunk of one frame's n points: per pooling, (n, K) float32."""
    L, in_image = sample_views(rig, sizes, maps, xyz, V, eps, only_visible="average" not in pools)
    nothing = None
    if config.background_vote > 0:
        cams = in_image & (V.T > eps)  # (C, n)
        blank = cams & (L.max(axis=2) < NOTHING_CONFIDENCE)  # (C, n) sees no class there
        n_cams = cams.sum(axis=0)
        nothing = (n_cams > 0) & (blank.sum(axis=0) >= config.background_vote * n_cams)  # (n,)
    out = {}
    for p in pools:
        pooled = pool_views(L, V, eps, p, in_image=in_image, camera_axis=0)  # (n, K)
        if nothing is not None:
            pooled[nothing] = 0.0
        out[p] = np.asarray(pooled, np.float32)
    return out
