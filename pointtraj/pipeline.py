"""``pointtraj run``: the whole method as one resumable pipeline described by a TOML file.

A pipeline file (``pipelines/*.toml``, format ``data_specs/pipeline.md``) names a capture and a
work folder and holds one table per stage, each parsed into the stage's typed config with the
paper's defaults; an unknown key anywhere is an error naming the file, the table and the key.

:func:`run_pipeline` runs the stages in order (capture → trajectories → semantics → affinity →
label → evaluate → render). A stage is skipped when it finished before with the same
parameters and the same inputs: each finished stage records in ``WORK/pipeline.json`` a key
hashed from its parameters and from the size and modification time of its input files (and of
the capture's files), so changing a parameter or re-running an upstream stage re-runs exactly
what depends on it. An interrupted reconstruction resumes at its last finished frame. Seconds
per stage go to ``WORK/timings.json``, which the report shows.

Table ``[executor]`` (:class:`~pointtraj.executor.ExecutorConfig`) says where the stages'
independent tasks run: one executor serves the whole run (opened when a stage first has tasks
for it, so an up-to-date run starts no cluster) and every stage gets it. It is not part of any stage's key: where a task
runs never changes what it writes.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from .affinity import AffinityConfig
from .errors import FileFormatError, ValidationError
from .evaluate.study import EvaluateConfig
from .executor import Executor, ExecutorConfig, LazyExecutor
from .reconstruct.config import ReconstructConfig
from .render.config import RenderConfig
from .segments import SegmentsConfig
from .stages import (
    LabelStageConfig,
    Progress,
    SemanticsStageConfig,
    SynthConfig,
)
from .workdir import WorkFolder

__all__ = [
    "STAGES",
    "ExampleConfig",
    "PipelineConfig",
    "PipelineResult",
    "load_pipeline",
    "run_pipeline",
    "demo_pipeline",
]

logger = logging.getLogger(__name__)

#: The stages in the order they run.
STAGES: tuple[str, ...] = (
    "capture",
    "trajectories",
    "semantics",
    "affinity",
    "label",
    "segments",
    "evaluate",
    "render",
)

_STATE_VERSION = 1


@dataclass(frozen=True)
class ExampleConfig:
    """A real example capture to fetch first (table ``[example]``; ``pointtraj examples list``).

    Attributes
    ----------
    name : str
        ``pose2sim`` or ``caliscope-board``.
    """

    name: str = "pose2sim"

    def __post_init__(self) -> None:
        from .examples import EXAMPLES

        if self.name not in EXAMPLES:
            raise ValidationError(
                f"example.name: unknown {self.name!r} (valid: {', '.join(sorted(EXAMPLES))})"
            )


@dataclass(frozen=True)
class PipelineConfig:
    """A pipeline: where the capture and the work folder are, and every stage's parameters.

    Attributes
    ----------
    capture : pathlib.Path
        The capture folder (written by ``[synth]`` or ``[example]`` when either is given).
    work : pathlib.Path
        The work folder.
    name : str
        A short name, shown in progress and the report.
    description : str
    trajectories : {"reconstruct", "ground_truth"}
        Reconstruct trajectories from the images (the method), or take a synthetic capture's
        ground-truth trajectories (to study the later stages alone).
    frames : str, optional
        Frames ``"A:B"`` to reconstruct (default: all).
    stages : tuple of str
        The stages to run (a subset of :data:`STAGES`, in any order; they run in pipeline
        order).
    synth : SynthConfig, optional
        Render a synthetic capture into ``capture`` first.
    example : ExampleConfig, optional
        Fetch a real example capture into ``capture`` first (if it is not there yet).
    reconstruct : ReconstructConfig
    semantics : SemanticsStageConfig
    affinity : AffinityConfig
    label : LabelStageConfig
    segments : SegmentsConfig
        Per-part poses and joint centres (``segments.npz``), after the labelling.
    evaluate : EvaluateConfig
    render : RenderConfig
    executor : ExecutorConfig
        Where the stages' tasks run (not part of any stage's key).
    source : pathlib.Path or None
        The pipeline file it was read from (not a key), for messages.
    """

    capture: Path
    work: Path
    name: str = ""
    description: str = ""
    trajectories: Literal["reconstruct", "ground_truth"] = "reconstruct"
    frames: str | None = None
    stages: tuple[str, ...] = STAGES
    synth: SynthConfig | None = None
    example: ExampleConfig | None = None
    reconstruct: ReconstructConfig = field(default_factory=ReconstructConfig)
    semantics: SemanticsStageConfig = field(default_factory=SemanticsStageConfig)
    affinity: AffinityConfig = field(default_factory=AffinityConfig)
    label: LabelStageConfig = field(default_factory=LabelStageConfig)
    segments: SegmentsConfig = field(default_factory=SegmentsConfig)
    evaluate: EvaluateConfig = field(default_factory=EvaluateConfig)
    render: RenderConfig = field(default_factory=RenderConfig)
    executor: ExecutorConfig = field(default_factory=ExecutorConfig)
    source: Path | None = field(
        default=None, compare=False, repr=False, metadata={"internal": True}
    )

    def __post_init__(self) -> None:
        unknown = [s for s in self.stages if s not in STAGES]
        if unknown:
            raise ValidationError(
                f"stages: unknown stage {unknown[0]!r} (valid: {', '.join(STAGES)})"
            )
        if self.synth is not None and self.example is not None:
            raise ValidationError("give [synth] or [example], not both")
        if self.trajectories not in ("reconstruct", "ground_truth"):
            raise ValidationError(
                f"trajectories: 'reconstruct' or 'ground_truth', got {self.trajectories!r}"
            )
        if self.label.pooling not in self.semantics.poolings:
            raise ValidationError(
                f"label.pooling {self.label.pooling!r} is not among semantics.poolings "
                f"({', '.join(self.semantics.poolings)})"
            )

    @property
    def frames_label(self) -> str:
        """How errors name ``frames``: with the pipeline file, when known."""
        return "frames" if self.source is None else f"{self.source}: frames"

    def with_paths(
        self, capture: str | os.PathLike | None = None, work: str | os.PathLike | None = None
    ) -> PipelineConfig:
        """A copy with the capture and/or work folder replaced."""
        changes: dict[str, Any] = {}
        if capture is not None:
            changes["capture"] = Path(capture)
        if work is not None:
            changes["work"] = Path(work)
        return dataclasses.replace(self, **changes)


def load_pipeline(path: str | os.PathLike, base: str | os.PathLike | None = None) -> PipelineConfig:
    """Read a pipeline TOML file.

    Parameters
    ----------
    path : path-like
    base : path-like, optional
        Folder that relative ``capture`` and ``work`` paths are taken from (default: the
        current working directory, as for any command-line path).

    Returns
    -------
    PipelineConfig

    Raises
    ------
    FileFormatError
        Naming the file and the key: invalid TOML, an unknown key, a wrong type, a missing
        ``capture``/``work``, or a value out of range.
    """
    from .config import from_mapping, load_toml

    path = Path(path)
    data = load_toml(path)
    try:
        config = from_mapping(PipelineConfig, data, where=path.name)
    except (ValueError, TypeError) as exc:
        raise FileFormatError(path, str(exc)) from None
    root = Path(base) if base is not None else Path.cwd()
    config = dataclasses.replace(config, source=path)
    return config.with_paths(root / config.capture, root / config.work)


def demo_pipeline(out: str | os.PathLike, frames: int | None = None) -> PipelineConfig:
    """The synthetic demo (``pointtraj demo``): ``pipelines/synthetic_demo.toml`` under ``out``.

    Parameters
    ----------
    out : path-like
        The demo folder: the capture goes to ``out/capture``, the work folder to ``out/work``.
    frames : int, optional
        Frames to render (default: the file's).

    Returns
    -------
    PipelineConfig
    """
    out = Path(out)
    synth = SynthConfig(preset="ring8", scene="dribble", frames=60, seed=0, points_per_part=300)
    if frames is not None:
        synth = dataclasses.replace(synth, frames=int(frames))
    return PipelineConfig(
        capture=out / "capture",
        work=out / "work",
        name="synthetic_demo",
        description=(
            f"{synth.frames} frames of a figure dribbling a ball, {synth.preset} rig, "
            "simulated recogniser"
        ),
        synth=synth,
    )


@dataclass
class PipelineResult:
    """What :func:`run_pipeline` did.

    Attributes
    ----------
    work : pathlib.Path
    ran : list of str
        Stages run now.
    skipped : list of str
        Stages found up to date.
    seconds : dict of str to float
        Wall time of each stage run now.
    outputs : dict of str to pathlib.Path
        The main files and folders made.
    """

    work: Path
    ran: list[str] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)
    seconds: dict[str, float] = field(default_factory=dict)
    outputs: dict[str, Path] = field(default_factory=dict)


def _stamp(path: Path) -> list[Any]:
    """``[name, size, mtime_ns]`` of a file, or ``[name, None]`` if it is missing."""
    try:
        st = path.stat()
    except OSError:
        return [str(path), None]
    return [str(path), st.st_size, st.st_mtime_ns]


def _capture_stamp(capture: Path) -> list[Any]:
    """Stamps of the capture's calibration, settings and frame sources (not every image)."""
    files = [capture / n for n in ("rig.toml", "capture.toml", "labels.toml")]
    files.append(capture / "gt" / "synth.toml")
    for sub in ("frames", "videos"):
        folder = capture / sub
        if folder.is_dir():
            files += sorted(folder.iterdir())
    return [_stamp(p) for p in files]


def _key(params: Any, inputs: Sequence[Any]) -> str:
    from .config import to_mapping

    blob = json.dumps(
        {
            "params": to_mapping(params) if dataclasses.is_dataclass(params) else params,
            "inputs": list(inputs),
        },
        sort_keys=True,
        default=str,
    )
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


@dataclass(frozen=True)
class _Stage:
    """One stage: its name, parameters, inputs, outputs and how to run it."""

    name: str
    params: Any
    inputs: Callable[[], list[Any]]
    outputs: list[Path]
    run: Callable[[Progress | None, Executor], Any]
    timing: str = ""  # key in timings.json (default: the stage name)


def _stage_plan(config: PipelineConfig, force_folder: bool = False) -> list[_Stage]:
    from . import stages
    from .synth.groundtruth import frame_file

    wf = WorkFolder(config.work)
    cap = Path(config.capture)
    plan: list[_Stage] = []
    if config.synth is not None:
        synth = config.synth
        plan.append(
            _Stage(
                "capture",
                synth,
                lambda: [],
                [cap / "gt" / "synth.toml", frame_file(cap, synth.frames - 1)],
                lambda p, ex: stages.synthesize(cap, synth, p, executor=ex),
                "synth",
            )
        )
    elif config.example is not None:
        example = config.example
        plan.append(
            _Stage(
                "capture",
                example,
                lambda: [],
                [cap / "rig.toml"],
                lambda p, ex: _fetch_example(example.name, cap),
                "fetch",
            )
        )
    if config.trajectories == "reconstruct":
        plan.append(
            _Stage(
                "trajectories",
                {"reconstruct": config.reconstruct, "frames": config.frames},
                lambda: _capture_stamp(cap),
                [wf.trajectories],
                lambda p, ex: _reconstruct(config, p, force_folder, ex),
                "reconstruct",
            )
        )
    else:
        plan.append(
            _Stage(
                "trajectories",
                {"ground_truth": True},
                lambda: _capture_stamp(cap),
                [wf.trajectories],
                lambda p, ex: stages.ground_truth_work(wf.path, cap),
                "ground_truth",
            )
        )
    plan += [
        _Stage(
            "semantics",
            config.semantics,
            lambda: _capture_stamp(cap) + [_stamp(wf.trajectories)],
            [wf.semantic_map],
            lambda p, ex: stages.semantics_work(
                wf.path, config.semantics, cap, progress=p, executor=ex
            ),
        ),
        _Stage(
            "affinity",
            config.affinity,
            lambda: [_stamp(wf.trajectories)],
            [wf.affinity],
            lambda p, ex: stages.affinity_work(wf.path, config.affinity, progress=p, executor=ex),
        ),
        _Stage(
            "label",
            config.label,
            lambda: [_stamp(wf.trajectories), _stamp(wf.semantic_map), _stamp(wf.affinity)],
            [wf.labels, wf.labels_csv],
            lambda p, ex: stages.label_work(wf.path, config.label, progress=p),
        ),
        _Stage(
            "segments",
            config.segments,
            lambda: [_stamp(wf.trajectories), _stamp(wf.labels), _stamp(cap / "labels.toml")],
            [wf.segments],
            lambda p, ex: stages.segments_work(wf.path, config.segments, progress=p),
        ),
        _Stage(
            "evaluate",
            config.evaluate,
            lambda: (
                _capture_stamp(cap)
                + [_stamp(p) for p in (wf.trajectories, wf.semantic_map, wf.affinity, wf.labels)]
                + [_key(config.semantics, []), _key(config.affinity, [])]
            ),
            [wf.report / "index.md", wf.report / "metrics.json"],
            lambda p, ex: _evaluate(config, p, ex),
        ),
        _Stage(
            "render",
            config.render,
            lambda: (
                _capture_stamp(cap)
                + [_stamp(wf.trajectories), _stamp(wf.labels), _stamp(wf.semantic_map)]
            ),
            [wf.renders / "legend.png"],
            lambda p, ex: _render(wf.path, config.render, p, ex),
        ),
    ]
    return [s for s in plan if s.name in config.stages]


def _evaluate(config: PipelineConfig, progress: Progress | None, executor: Executor) -> None:
    from .evaluate.study import evaluate_work

    evaluate_work(
        config.work,
        config.evaluate,
        config.capture,
        affinity_config=config.affinity,
        semantics_config=config.semantics,
        title=f"pointtraj report: {config.name or Path(config.work).name}",
        progress=progress,
        executor=executor,
    )


def _render(
    work: Path, config: RenderConfig, progress: Progress | None, executor: Executor
) -> None:
    from .render.stage import render_work

    render_work(work, config, progress=progress, executor=executor)


def _fetch_example(name: str, capture: Path) -> None:
    from .examples import fetch_example

    if (capture / "rig.toml").is_file():
        logger.info("example capture %s is already in %s", name, capture)
        return
    fetch_example(name, capture)


def _reconstruct(
    config: PipelineConfig, progress: Progress | None, force: bool, executor: Executor | None
) -> None:
    """Reconstruct, resuming an interrupted run of the same settings, else starting afresh."""
    from . import stages

    stages.reconstruct_work(
        config.work,
        config.capture,
        config.reconstruct,
        config.frames,
        on_change="restart",
        force=force,
        frames_label=config.frames_label,
        progress=progress,
        executor=executor,
    )


def _read_json(path: Path) -> dict[str, Any]:
    if not path.is_file():
        return {}
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError):
        logger.warning("%s is unreadable; starting its record afresh", path)
        return {}
    return data if isinstance(data, dict) else {}


def _write_json(path: Path, data: dict[str, Any]) -> None:
    from .atomic import write_text_atomic

    write_text_atomic(path, json.dumps(data, indent=2, sort_keys=True) + "\n")


def run_pipeline(
    config: PipelineConfig,
    *,
    force: Sequence[str] = (),
    progress: Progress | None = None,
    on_stage: Callable[[str, str], None] | None = None,
    force_folder: bool = False,
    executor: Executor | None = None,
    on_executor: Callable[[Executor], None] | None = None,
) -> PipelineResult:
    """Run a pipeline's stages, skipping those that are up to date.

    Parameters
    ----------
    config : PipelineConfig
    force : sequence of str
        Stages to re-run even if up to date (``"all"`` for every stage).
    progress : Progress, optional
        Passed to every stage.
    on_stage : callable, optional
        ``on_stage(stage, event)`` with event ``"start"``, ``"skip"`` or ``"done"``.
    force_folder : bool
        Use a work folder that is non-empty and not pointtraj's (its removed files are logged).
    executor : Executor, optional
        Where the stages' tasks run (left open). Default: one opened from ``config.executor``
        when a stage first has tasks to run, and closed at the end.
    on_executor : callable, optional
        Called with the executor this call opens, once it is open (the command line shows where
        the work runs and the dashboard's link).

    Returns
    -------
    PipelineResult

    Raises
    ------
    PointtrajError
        From the stage that failed; the stages before it stay recorded as done.
    """
    bad = [s for s in force if s not in (*STAGES, "all")]
    if bad:
        raise ValidationError(f"force: unknown stage {bad[0]!r} (valid: all, {', '.join(STAGES)})")
    wf = WorkFolder(config.work)
    if config.synth is None and config.example is None and not Path(config.capture).is_dir():
        raise FileFormatError(config.capture, "capture folder does not exist")
    wf.claim(force_folder)
    lazy = None if executor is not None else LazyExecutor(config.executor, on_executor)
    try:
        with wf.lock("pointtraj run"):
            return _run_locked(
                config, wf, force, progress, on_stage, force_folder, executor or lazy
            )
    finally:
        if lazy is not None:
            lazy.close()


def _run_locked(
    config: PipelineConfig,
    wf: WorkFolder,
    force: Sequence[str],
    progress: Progress | None,
    on_stage: Callable[[str, str], None] | None,
    force_folder: bool,
    executor: Executor,
) -> PipelineResult:
    """:func:`run_pipeline` inside the work folder's lock."""
    state = _read_json(wf.pipeline_state)
    if state.get("version") != _STATE_VERSION:
        state = {"version": _STATE_VERSION, "stages": {}}
    timings = _read_json(wf.timings)
    result = PipelineResult(work=wf.path)
    for stage in _stage_plan(config, force_folder):
        key = _key(stage.params, stage.inputs())
        done = state["stages"].get(stage.name, {})
        fresh = (
            done.get("key") == key
            and all(p.exists() for p in stage.outputs)
            and "all" not in force
            and stage.name not in force
        )
        if fresh:
            result.skipped.append(stage.name)
            logger.info("%s: up to date", stage.name)
            if on_stage is not None:
                on_stage(stage.name, "skip")
            continue
        if on_stage is not None:
            on_stage(stage.name, "start")
        state["stages"].pop(stage.name, None)
        _write_json(wf.pipeline_state, state)
        t0 = time.perf_counter()
        stage.run(progress, executor)
        seconds = time.perf_counter() - t0
        state["stages"][stage.name] = {
            "key": key,
            "seconds": round(seconds, 3),
            "finished": time.strftime("%Y-%m-%dT%H:%M:%S"),
        }
        _write_json(wf.pipeline_state, state)
        timings[stage.timing or stage.name] = round(seconds, 3)
        _write_json(wf.timings, timings)
        result.ran.append(stage.name)
        result.seconds[stage.name] = seconds
        if on_stage is not None:
            on_stage(stage.name, "done")
    for name, path in (
        ("capture", Path(config.capture)),
        ("trajectories", wf.trajectories),
        ("semantic_map", wf.semantic_map),
        ("affinity", wf.affinity),
        ("labels", wf.labels),
        ("clouds", wf.clouds),
        ("report", wf.report / "index.md"),
        ("renders", wf.renders),
    ):
        if path.exists():
            result.outputs[name] = path
    return result
