"""Every pipeline stage as a library function on a work folder.

Each function loads its inputs from the work folder (``data_specs/work_folder.md``), calls the
stage's algorithm, writes its outputs atomically and returns them. The ``pointtraj`` commands
and :func:`pointtraj.pipeline.run_pipeline` are thin callers of these.

============== ======================================= ==========================================
stage          reads                                   writes
============== ======================================= ==========================================
synth          (its config)                            the capture folder
reconstruct    the capture                             work.toml, clouds/, state/,
                                                       trajectories.npz
ground_truth   the capture's gt/                       work.toml, trajectories.npz
semantics      the capture's images, trajectories.npz  semantic_map.npz
affinity       trajectories.npz                        affinity.npz
label          semantic_map.npz, affinity.npz          labels.npz, labels.csv, clouds/ (label)
segments       trajectories.npz, labels.npz            segments.npz
============== ======================================= ==========================================

Progress is reported through an optional ``progress(label, done, total)`` callable.
"""

from __future__ import annotations

import dataclasses
import logging
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .affinity import AffinityConfig
from .errors import FileFormatError, ValidationError
from .instances import InstanceConfig
from .labeling import LabelingConfig
from .semantics.semantic_map import SemanticsConfig
from .workdir import WorkFolder, parse_frames

if TYPE_CHECKING:
    from .affinity import AffinityGraph
    from .executor import Executor
    from .labelfile import TrajectoryLabels
    from .reconstruct.config import ReconstructConfig
    from .segments import Segments, SegmentsConfig
    from .semantics.recognizers import RecognizerSpec
    from .semantics.semantic_map import SemanticMap
    from .synth.render import CaptureSummary
    from .trajectories import Trajectories

__all__ = [
    "Progress",
    "SynthConfig",
    "SemanticsStageConfig",
    "LabelStageConfig",
    "synthesize",
    "load_reconstruct_config",
    "reconstruct_work",
    "ground_truth_work",
    "semantics_work",
    "affinity_work",
    "label_work",
    "segments_work",
]

logger = logging.getLogger(__name__)

#: ``progress(label, done, total)``: ``done`` of ``total`` units of the step named ``label``.
Progress = Callable[[str, int, int], None]


@dataclass(frozen=True)
class SynthConfig:
    """A synthetic capture to render first (table ``[synth]`` of a pipeline).

    Attributes
    ----------
    preset : str
        Rig preset (``pointtraj synth --list``).
    scene : str
        Scene (``pointtraj synth --list``).
    frames : int
        Frames to render.
    seed : int
        Seeds textures, motion, ground-truth sampling and sensor noise.
    points_per_part : int
        Ground-truth surface points per labelled part.
    image_format : {"jpg", "png"}
    rig : str
        A rig file (any format ``pointtraj rig show`` reads) to render with instead of the
        preset: a synthetic twin of a real rig (:func:`pointtraj.synth.presets.twin_rig`), with
        the scene's subject where its optical axes meet, or at ``at``. Empty: the preset.
    at : (3,) tuple of float, optional
        With ``rig``: the subject's centre in the rig's coordinates (metres).
    up : str
        With ``rig``: the rig's up direction (``"auto"``, ``"+z"``, ``"-y"``, ...).
    fps : float, optional
        Frame rate (default: the preset's; 30 with ``rig``).
    scale : float, optional
        The scene's size against its human size (default: the preset's ``scene_scale``).
    rig_scale : float
        The rig's size against the preset's.
    """

    preset: str = "ring8"
    scene: str = "dribble"
    frames: int = 30
    seed: int = 0
    points_per_part: int = 300
    image_format: str = "jpg"
    rig: str = ""
    at: tuple[float, float, float] | None = None
    up: str = "auto"
    fps: float | None = None
    scale: float | None = None
    rig_scale: float = 1.0

    def __post_init__(self) -> None:
        from .synth.presets import PRESETS
        from .synth.scenes import SCENES

        if self.preset not in PRESETS:
            raise ValidationError(
                f"synth.preset: unknown {self.preset!r} (valid: {', '.join(sorted(PRESETS))})"
            )
        if self.scene not in SCENES:
            raise ValidationError(
                f"synth.scene: unknown {self.scene!r} (valid: {', '.join(sorted(SCENES))})"
            )
        if self.frames < 1 or self.points_per_part < 1:
            raise ValidationError("synth.frames and synth.points_per_part must be positive")
        if self.image_format not in ("jpg", "png"):
            raise ValidationError(f"synth.image_format: 'jpg' or 'png', got {self.image_format!r}")
        if self.at is not None and not self.rig:
            raise ValidationError(
                "synth.at places the subject in a rig file's frame; give synth.rig"
            )
        if self.fps is not None and not (self.fps > 0):
            raise ValidationError(f"synth.fps must be positive, got {self.fps!r}")
        if not ((self.scale is None or self.scale > 0) and self.rig_scale > 0):
            raise ValidationError("synth.scale and synth.rig_scale must be positive")


@dataclass(frozen=True)
class SemanticsStageConfig(SemanticsConfig):
    """The semantic-map stage (table ``[semantics]``): the recogniser and the pooling settings.

    Attributes
    ----------
    recognizer : str
        Recogniser name (``pointtraj.semantics.recognizers.RECOGNIZERS``).
    options : dict
        Recogniser options (e.g. ``{noise = "high"}`` for ``simulated``). The simulated
        recogniser gets the capture folder automatically.
    poolings : tuple of str
        As :class:`SemanticsConfig`, but every method by default, for the report.
    """

    recognizer: str = "simulated"
    options: dict[str, Any] = field(default_factory=dict)
    # The paper's view and average pooling first (the report compares them), then the average
    # over the visible cameras only, ours and the other baselines.
    poolings: tuple[str, ...] = (
        "view",
        "average",
        "average_visible",
        "view_soft",
        "max",
        "product",
    )

    def semantics_config(self) -> SemanticsConfig:
        """The plain :class:`SemanticsConfig` part."""
        names = {f.name for f in dataclasses.fields(SemanticsConfig)}
        return SemanticsConfig(**{k: getattr(self, k) for k in names})


@dataclass(frozen=True)
class LabelStageConfig(LabelingConfig):
    """The labelling stage (table ``[label]``): :class:`LabelingConfig` plus what to label.

    Attributes
    ----------
    pooling : str
        Which L3D of ``semantic_map.npz`` to label (its poolings; the paper's is ``view``).
    write_clouds : bool
        Rewrite ``clouds/<frame>.ply`` with a ``label`` attribute (and ``instance``).
    instances : InstanceConfig
        People as instances (table ``[label.instances]``, :mod:`pointtraj.instances`).
    """

    pooling: str = "view"
    write_clouds: bool = True
    instances: InstanceConfig = field(default_factory=InstanceConfig)

    def labeling_config(self) -> LabelingConfig:
        """The plain :class:`LabelingConfig` part."""
        names = {f.name for f in dataclasses.fields(LabelingConfig)}
        return LabelingConfig(**{k: getattr(self, k) for k in names})


def _report(progress: Progress | None, label: str, done: int, total: int) -> None:
    if progress is not None:
        progress(label, done, total)


def synthesize(
    capture: str | os.PathLike,
    config: SynthConfig,
    progress: Progress | None = None,
    *,
    executor: Executor | None = None,
) -> CaptureSummary:
    """Render (or resume rendering) a synthetic capture into ``capture``.

    On a Dask ``executor`` each frame is a task (the files are the same as rendered here).

    Returns
    -------
    CaptureSummary
    """
    from .synth.render import render_capture

    done = [0]

    def on_frame(t: int, rendered: bool) -> None:
        done[0] += 1
        _report(progress, "synth", done[0], config.frames)

    rig = None
    preset = config.preset
    if config.rig:
        from .rigio import load_rig
        from .synth.presets import twin_rig

        rig, how = twin_rig(load_rig(config.rig), at=config.at, up=config.up)
        preset = f"twin of {Path(config.rig).name}"
        logger.info("synthetic twin of %s: %s", config.rig, how)
    return render_capture(
        capture,
        rig=rig,
        fps=config.fps,
        preset=preset,
        scene=config.scene,
        frames=config.frames,
        seed=config.seed,
        points_per_part=config.points_per_part,
        image_format=config.image_format,
        scale=config.scale,
        rig_scale=config.rig_scale,
        on_frame=on_frame,
        executor=executor,
    )


def load_reconstruct_config(path: str | os.PathLike | None) -> ReconstructConfig:
    """A :class:`ReconstructConfig` from a TOML file (table ``[reconstruct]`` or top level).

    Parameters
    ----------
    path : path-like or None
        The file; None gives the defaults. A file with a ``[reconstruct]`` table is read from
        that table. A pipeline file (a ``capture`` or ``work`` key) without one leaves
        reconstruction to its defaults, as every other command's ``--config`` does. Any other
        file is read whole (``ReconstructConfig`` keys at the top level).

    Returns
    -------
    ReconstructConfig

    Raises
    ------
    FileFormatError
        If the file is missing or invalid TOML, or has an unknown key or a bad value (naming
        the file and the key).
    """
    from .config import from_mapping, load_toml
    from .reconstruct.config import ReconstructConfig

    if path is None:
        return ReconstructConfig()
    data = load_toml(path)
    if isinstance(data.get("reconstruct"), dict):
        table = data["reconstruct"]
    elif "capture" in data or "work" in data:  # a pipeline file's keys: the defaults
        table = {}
    else:
        table = data
    try:
        return from_mapping(ReconstructConfig, table, where="[reconstruct]")
    except ValueError as exc:
        raise FileFormatError(path, str(exc)) from None


def reconstruct_work(
    work: str | os.PathLike,
    capture: str | os.PathLike,
    config: ReconstructConfig | None = None,
    frames: str | range | None = None,
    *,
    restart: bool = False,
    on_change: str = "refuse",
    force: bool = False,
    frames_label: str = "frames",
    progress: Progress | None = None,
    executor: Executor | None = None,
) -> Trajectories:
    """Reconstruct the capture's trajectories into the work folder, resuming an interrupted run.

    Parameters
    ----------
    work, capture : path-like
    config : ReconstructConfig, optional
    frames : str or range, optional
        ``"A:B"`` or a range (default: all frames).
    restart : bool
        Discard a previous run's per-frame state and clouds instead of resuming it.
    on_change : {"refuse", "restart"}
        What to do when the folder holds a run of another capture, frame range or parameter
        set: refuse (the command line's default), or restart (``pointtraj run``'s).
    force : bool
        Use (and clear) a non-empty folder that pointtraj did not make.
    frames_label : str
        How errors about ``frames`` name it (``"--frames"``, ``"pipe.toml: frames"``).
    progress : Progress, optional
    executor : Executor, optional
        Runs the temporal chunks of a long frame range (``chunk_frames``; default serially).
        The output does not depend on it.

    Returns
    -------
    Trajectories

    Raises
    ------
    ValidationError
        If the folder holds another run and neither ``restart`` nor ``on_change="restart"``.
    WorkFolderError
        If another run holds the folder, or it is not a pointtraj work folder and not ``force``.

    Notes
    -----
    A restart removes only the files pointtraj wrote (:meth:`WorkFolder.remove_outputs`).
    """
    from .reconstruct.config import ReconstructConfig
    from .reconstruct.stage import reconstruct_capture
    from .session import Capture

    if on_change not in ("refuse", "restart"):
        raise ValidationError(f"on_change: 'refuse' or 'restart', got {on_change!r}")
    cfg = config or ReconstructConfig()
    wf = WorkFolder(work)
    cap = Capture.open(capture)
    rng = (
        frames
        if isinstance(frames, range)
        else parse_frames(frames, int(cap.num_frames), where=frames_label)
    )
    foreign = not wf.is_pointtraj()
    wf.claim(force)
    with wf.lock("pointtraj reconstruct"):
        has_run = wf.state.is_dir() or wf.clouds.is_dir() or (wf.path / "chunks").is_dir()
        restart = restart or (foreign and has_run)  # taken over with force: nothing to resume
        if has_run and not restart:
            wanted = {"reconstruct_run": None, "reconstruct": None} | wf.run_document(
                capture, rng, cfg
            )
            have = wf.run_identity()
            if isinstance(have.get("reconstruct"), dict):  # work.toml of an older version:
                have["reconstruct"].setdefault("cloud_visibility", "full")  # its clouds' form
            if have != wanted:
                if on_change == "refuse":
                    raise ValidationError(
                        f"{wf.path} holds a reconstruction of another capture, frame range or "
                        "parameter set; pass --restart (restart=True) or use another work folder"
                    )
                logger.info(
                    "%s: capture, frames or parameters changed; reconstructing afresh", wf.path
                )
                restart = True
        if restart:
            wf.remove_outputs(["state", "clouds", "chunks"], force=force)
        wf.write_toml(capture, rng, cfg)
        done = [0]

        def on_frame(rec: Any) -> None:
            done[0] += 1
            _report(progress, "reconstruct", done[0], len(rng))

        return reconstruct_capture(cap, wf.path, rng, cfg, on_frame=on_frame, executor=executor)


def ground_truth_work(
    work: str | os.PathLike,
    capture: str | os.PathLike,
    min_visible: int = 2,
    *,
    force: bool = False,
) -> Trajectories:
    """Write the synthetic capture's ground-truth trajectories as the work folder's store.

    Parameters
    ----------
    work, capture : path-like
    min_visible : int
        Keep point-frames seen by at least this many cameras.
    force : bool
        Use a non-empty folder that pointtraj did not make.

    Returns
    -------
    Trajectories
    """
    from .synth.groundtruth import load_ground_truth

    wf = WorkFolder(work)
    wf.check_capture(capture)
    wf.claim(force)
    with wf.lock("pointtraj gt-trajectories"):
        trajectories = load_ground_truth(capture).to_trajectories(min_visible=min_visible)
        wf.write_toml(capture)
        trajectories.save(wf.trajectories)
    logger.info("wrote %d ground-truth trajectories to %s", len(trajectories), wf.trajectories)
    return trajectories


def stage_recognizer_spec(config: SemanticsStageConfig, capture: Any) -> RecognizerSpec:
    """How to make the recogniser of a semantics stage for an open capture.

    Its class set is the capture's ``labels.toml`` (or the default label set, with a warning);
    the simulated recogniser gets the capture's folder.

    Raises
    ------
    ValidationError
        On an unknown recogniser.
    """
    from .semantics.recognizers import RecognizerSpec

    labels = None if capture.labels_path is None else os.fspath(capture.labels_path)
    if labels is None:
        logger.warning("%s has no labels.toml; using the default label set", capture.path)
    options = dict(config.options)
    if config.recognizer == "simulated":
        options.setdefault("capture", str(Path(capture.path).resolve()))
    return RecognizerSpec(config.recognizer, labels, options)


def make_stage_recognizer(config: SemanticsStageConfig, capture: Any):
    """The recogniser of a semantics stage for an open capture (:func:`stage_recognizer_spec`).

    Raises
    ------
    ValidationError
        On an unknown recogniser or an option it does not take.
    """
    return stage_recognizer_spec(config, capture).make()


def semantics_work(
    work: str | os.PathLike,
    config: SemanticsStageConfig | None = None,
    capture: str | os.PathLike | None = None,
    *,
    progress: Progress | None = None,
    executor: Executor | None = None,
) -> SemanticMap:
    """Build ``semantic_map.npz``: recognise every image, view-pool, average over time.

    Parameters
    ----------
    work : path-like
        Holds ``trajectories.npz``.
    config : SemanticsStageConfig, optional
    capture : path-like, optional
        Default: the capture ``work.toml`` records.
    progress : Progress, optional
    executor : Executor, optional
        Where the camera images are recognised, sampled and pooled, frame by frame (default:
        serially, here). On a Dask cluster each worker loads the recogniser once and reads the
        images from the capture's folder, which must be on a path every worker shares.

    Returns
    -------
    SemanticMap
    """
    from .scale import scale_lengths, work_scene_scale
    from .semantics.semantic_map import build_semantic_map
    from .session import Capture
    from .trajectories import Trajectories

    cfg = config or SemanticsStageConfig()
    wf = WorkFolder(work)
    with wf.lock("pointtraj semantics"):
        cap = Capture.open(wf.require_capture(capture))
        spec = stage_recognizer_spec(cfg, cap)
        local = executor is None or executor.local
        recognizer = spec.make() if local else spec  # a worker makes its own, once
        trajectories = Trajectories.load(wf.trajectories)
        trajectories.check_cameras(cap, wf.trajectories)
        smap = build_semantic_map(
            cap,
            trajectories,
            recognizer,
            config=scale_lengths(cfg.semantics_config(), work_scene_scale(wf), "[semantics]"),
            progress=progress,
            executor=executor,
        )
        # The options as given (not the capture, which the simulated recogniser gets anew).
        smap.recognizer_options = {
            k: v for k, v in cfg.options.items() if isinstance(v, str | int | float | bool)
        }
        smap.save(wf.semantic_map)
    return smap


def affinity_work(
    work: str | os.PathLike,
    config: AffinityConfig | None = None,
    *,
    progress: Progress | None = None,
    executor: Executor | None = None,
) -> AffinityGraph:
    """Compute ``affinity.npz`` from ``trajectories.npz`` (paper Section 4.2).

    The local rigid fits and the pair errors run on ``executor`` (default: serially, here) by
    chunks of trajectories' point-frames and of pairs; the graph is the same on any executor.

    Returns
    -------
    AffinityGraph
    """
    from .affinity import compute_affinity, save_affinity
    from .scale import scale_lengths, work_scene_scale
    from .trajectories import Trajectories

    wf = WorkFolder(work)
    with wf.lock("pointtraj affinity"):
        trajectories = Trajectories.load(wf.trajectories)
        graph = compute_affinity(
            trajectories,
            scale_lengths(config or AffinityConfig(), work_scene_scale(wf), "[affinity]"),
            progress=None if progress is None else lambda s, d, n: progress("affinity", d, n),
            executor=executor,
        )
        save_affinity(graph, wf.affinity)
    return graph


def _check_capture_classes(wf: WorkFolder, path: Path, class_names: tuple[str, ...]) -> None:
    """Refuse ``path``'s classes if they are not those of the recorded capture's labels.toml.

    Raises
    ------
    FileFormatError
        Naming labels.toml and ``path`` (:func:`pointtraj.labelset.check_class_names`).
    """
    from .labelset import LabelSet, check_class_names

    capture = wf.capture_path()
    labels_toml = None if capture is None else capture / "labels.toml"
    if labels_toml is not None and labels_toml.is_file():
        check_class_names(labels_toml, LabelSet.load(labels_toml).names, path, class_names)


def _instances(wf: WorkFolder, cfg: InstanceConfig, labels, smap, graph) -> np.ndarray | None:
    """A person id per trajectory (:func:`pointtraj.instances.assign_instances`), or None."""
    from .instances import assign_instances, person_classes
    from .labelset import LabelSet

    if not cfg.enabled:
        return None
    capture = wf.capture_path()
    toml = None if capture is None else capture / "labels.toml"
    kinds = LabelSet.load(toml).kinds if toml is not None and toml.is_file() else None
    people = person_classes(smap.class_names, kinds)
    instance = assign_instances(
        labels, people, graph.row, graph.col, graph.weight, smap.person_votes, cfg
    )
    logger.info(
        "instances: %d people (%d trajectories on them; person masks: %s)",
        int(instance.max(initial=-1)) + 1,
        int((instance >= 0).sum()),
        f"{len(smap.person_votes)} votes" if len(smap.person_votes) else "none",
    )
    return instance


def label_work(
    work: str | os.PathLike,
    config: LabelStageConfig | None = None,
    *,
    progress: Progress | None = None,
) -> TrajectoryLabels:
    """Label every trajectory by alpha-expansion (paper Section 4.3).

    Writes ``labels.npz`` and ``labels.csv`` and, with ``config.write_clouds``, rewrites the
    existing ``clouds/<frame>.ply`` with a ``label`` attribute.

    Returns
    -------
    TrajectoryLabels

    Raises
    ------
    FileFormatError
        If an input is missing, or the inputs disagree on the number of trajectories.
    """
    cfg = config or LabelStageConfig()
    wf = WorkFolder(work)
    with wf.lock("pointtraj label"):
        return _label_locked(wf, cfg, progress)


def _label_locked(
    wf: WorkFolder, cfg: LabelStageConfig, progress: Progress | None
) -> TrajectoryLabels:
    """:func:`label_work` inside the work folder's lock."""
    from .affinity import load_affinity
    from .atomic import write_text_atomic
    from .labelfile import TrajectoryLabels, save_labels
    from .labeling import argmax_labels, label_trajectories
    from .semantics.semantic_map import SemanticMap
    from .trajectories import Trajectories

    trajectories = Trajectories.load(wf.trajectories)
    if not wf.semantic_map.is_file():
        raise FileFormatError(wf.semantic_map, "no such file (run `pointtraj semantics` first)")
    smap = SemanticMap.load(wf.semantic_map)
    _check_capture_classes(wf, wf.semantic_map, smap.class_names)
    if cfg.pooling not in smap.L3D:
        raise FileFormatError(
            wf.semantic_map,
            f"no L3D for pooling {cfg.pooling!r} (has: {', '.join(smap.poolings)})",
        )
    l3d = np.asarray(smap.L3D[cfg.pooling], np.float64)
    if not wf.affinity.is_file():
        raise FileFormatError(wf.affinity, "no such file (run `pointtraj affinity` first)")
    graph = load_affinity(wf.affinity)
    M = trajectories.num_trajectories
    if l3d.shape[0] != M:
        raise FileFormatError(
            wf.semantic_map, f"has {l3d.shape[0]} trajectories, trajectories.npz {M}"
        )
    if graph.num_nodes != M:
        raise FileFormatError(wf.affinity, f"has {graph.num_nodes} nodes, trajectories.npz {M}")
    K = l3d.shape[1]
    lab_cfg = cfg.labeling_config()
    steps = [0]

    def on_move(n: int = 1) -> None:
        steps[0] += n
        _report(progress, "label", steps[0], (K + (lab_cfg.background > 0)) * lab_cfg.max_sweeps)

    res = label_trajectories(
        l3d,
        graph.row,
        graph.col,
        graph.weight,
        lab_cfg,
        support=smap.count[cfg.pooling],
        progress=on_move,
    )
    s = np.nansum(l3d, axis=1)
    picked = np.where(res.labels >= 0, l3d[np.arange(M), np.maximum(res.labels, 0)], 0.0)
    conf = np.where(s > 0, picked / np.where(s > 0, s, 1.0), 0.0)
    result = TrajectoryLabels(
        labels=res.labels,
        confidence=conf,
        argmax=argmax_labels(l3d, lab_cfg.background),
        class_names=smap.class_names,
        energy=np.asarray(res.energy, np.float64),
        pooling=cfg.pooling,
        params=dataclasses.asdict(lab_cfg),
        instance=_instances(wf, cfg.instances, res.labels, smap, graph),
    )
    # The clouds and labels.npz are one unit: the clouds first, labels.npz last. While the
    # clouds are rewritten a pending mark says so; a run killed then leaves it behind, and the
    # next run (and any reader of the clouds) knows they mix two labellings.
    if cfg.write_clouds and wf.clouds.is_dir():
        frames = sorted(int(p.stem) for p in wf.clouds.glob("*.ply") if p.stem.isdigit())
        frames = [t for t in frames if t < trajectories.num_frames]
        write_text_atomic(wf.labels_pending, f"{len(frames)} clouds being relabelled\n")
        # the clouds keep the visibility form the reconstruction wrote them in
        form = (wf.run_identity().get("reconstruct") or {}).get("cloud_visibility", "full")
        for i, t in enumerate(frames):
            trajectories.write_frame_ply(
                t,
                wf.cloud(t),
                visibility_form=form,
                labels=result.labels,
                instances=result.instance,
            )
            _report(progress, "label: clouds", i + 1, len(frames))
    save_labels(result, wf.labels, trajectories.first_frame, trajectories.lengths)
    wf.labels_pending.unlink(missing_ok=True)
    logger.info(
        "labelled %d trajectories (%d unlabelled, %d changed from the argmax), energy %.6g -> "
        "%.6g in %.1f s",
        M,
        int((result.labels < 0).sum()),
        int((result.labels != result.argmax).sum()),
        res.energy[0],
        res.energy[-1],
        res.seconds,
    )
    return result


def segments_work(
    work: str | os.PathLike,
    config: SegmentsConfig | None = None,
    *,
    progress: Progress | None = None,
) -> Segments:
    """Fit every labelled body part's 6-DoF pose per frame and the joint centres between
    adjacent parts (:mod:`pointtraj.segments`); writes ``segments.npz``.

    The classes, their kinds and the joints come from the capture's ``labels.toml`` (the body
    joints of :data:`pointtraj.labelset.BODY_JOINTS` when it has no ``[[joints]]``); persons
    from ``labels.npz``'s optional ``instance`` (otherwise the labelled body is one person).

    Returns
    -------
    Segments

    Raises
    ------
    FileFormatError
        If ``trajectories.npz`` or ``labels.npz`` is missing or they disagree on the number of
        trajectories.
    """
    from .labelfile import load_labels
    from .labelset import LabelSet
    from .scale import scale_lengths, work_scene_scale
    from .segments import SegmentsConfig, compute_segments, save_segments
    from .trajectories import Trajectories

    wf = WorkFolder(work)
    with wf.lock("pointtraj segments"):
        trajectories = Trajectories.load(wf.trajectories)
        labels = load_labels(wf.labels)
        M = trajectories.num_trajectories
        if len(labels) != M:
            raise FileFormatError(
                wf.labels, f"has {len(labels)} trajectories, trajectories.npz {M}"
            )
        _check_capture_classes(wf, wf.labels, labels.class_names)
        capture = wf.capture_path()
        labels_toml = None if capture is None else capture / "labels.toml"
        if labels_toml is not None and labels_toml.is_file():
            labelset = LabelSet.load(labels_toml)
        else:
            names = labels.class_names
            labelset = LabelSet(names, np.zeros((len(names), 3), np.uint8))
        instance = getattr(labels, "instance", None)
        segments = compute_segments(
            trajectories,
            labels.labels,
            labelset,
            instance,
            scale_lengths(config or SegmentsConfig(), work_scene_scale(wf), "[segments]"),
            progress=None if progress is None else lambda d, n: progress("segments", d, n),
        )
        save_segments(segments, wf.segments)
    return segments
