"""``pointtraj semantics WORK``: the 3D semantic map (``WORK/semantic_map.npz``)."""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

import click

from .common import executor_options

__all__ = ["semantics"]


def _parse_options(options: tuple[str, ...]) -> dict[str, Any]:
    """``KEY=VALUE`` pairs, each VALUE read as a TOML value (bare words are strings)."""
    parsed: dict[str, Any] = {}
    for item in options:
        key, sep, value = item.partition("=")
        key = key.strip().replace("-", "_")
        if not sep or not key:
            raise click.UsageError(f"--option {item!r}: expected KEY=VALUE")
        try:
            parsed[key] = tomllib.loads(f"v = {value}")["v"]
        except tomllib.TOMLDecodeError:
            parsed[key] = value
    return parsed


@click.command("semantics")
@click.argument("work", type=click.Path(file_okay=False, path_type=Path))
@click.option(
    "--recognizer",
    "-r",
    "recognizer_name",
    default=None,
    help="Recogniser name (simulated, precomputed, onnx-segmentation, onnx-detection, "
    "body-parts, object-detector, combined); required unless --config names one.",
)
@click.option(
    "--config",
    "config_path",
    type=click.Path(exists=True, dir_okay=False, path_type=Path),
    default=None,
    help="TOML with a [semantics] table (SemanticsStageConfig; a pipeline file works); the "
    "options given here override it, and -o options are added to its options.",
)
@click.option(
    "--capture",
    type=click.Path(exists=True, file_okay=False, path_type=Path),
    help="Capture folder (default: the one recorded in WORK/work.toml).",
)
@click.option(
    "--option",
    "-o",
    "options",
    multiple=True,
    metavar="KEY=VALUE",
    help="Recogniser option, e.g. -o noise=high or -o directory=maps (repeatable).",
)
@click.option(
    "--pooling",
    "poolings",
    multiple=True,
    help="Pooling method(s); the first is the map's default [default: view, average; with "
    "--config, the file's, or every pooling as `pointtraj run` uses them].",
)
@click.option("--eps-e", type=float, default=None, help="Visibility threshold ε_e [default: 0.1].")
@click.option(
    "--background-vote",
    type=float,
    default=None,
    help="Pool a point-frame as nothing when at least this fraction of its cameras see no class "
    "there (silhouette consistency; 0.5 suits real recognisers on sparse rigs) [default: 0, off].",
)
@click.option(
    "--from-ground-truth",
    is_flag=True,
    help="If WORK has no trajectories.npz, create it from the capture's gt/ first.",
)
@executor_options
def semantics(
    work: Path,
    recognizer_name: str | None,
    config_path: Path | None,
    capture: Path | None,
    options: tuple[str, ...],
    poolings: tuple[str, ...],
    eps_e: float | None,
    background_vote: float | None,
    from_ground_truth: bool,
    workers: int | None,
    scheduler: str | None,
) -> None:
    """Build WORK/semantic_map.npz: recognise every image, view-pool, average over time."""
    import dataclasses

    from ..semantics.semantic_map import SemanticsConfig
    from ..stages import SemanticsStageConfig, ground_truth_work, semantics_work
    from ..workdir import WorkFolder
    from .common import config_from, executor_config, open_cli_executor, progress_bars

    overrides = {
        "recognizer": recognizer_name,
        # without a file, the two poolings of the paper (a file's table, or every pooling)
        "poolings": tuple(poolings) or (None if config_path else SemanticsConfig().poolings),
        "eps_e": eps_e,
        "background_vote": background_vote,
    }
    config = config_from(
        SemanticsStageConfig,
        config_path,
        "semantics",
        overrides,
        required={"recognizer": "--recognizer / -r"},
    )
    if options:
        config = dataclasses.replace(config, options={**config.options, **_parse_options(options)})
    wf = WorkFolder(work)
    capture = capture or wf.capture_path()
    if capture is None:
        raise click.UsageError(f"{work}: no work.toml recording the capture; pass --capture")
    if not wf.trajectories.is_file():
        if not from_ground_truth:
            raise click.ClickException(
                f"{wf.trajectories}: no such file (reconstruct first, or pass "
                "--from-ground-truth for a synthetic capture)"
            )
        ground_truth_work(work, capture)
    with open_cli_executor(executor_config(workers, scheduler)) as ex, progress_bars() as bars:
        smap = semantics_work(work, config, capture, progress=bars, executor=ex)
    p = smap.poolings[0]
    seen = int((smap.count[p] > 0).sum())
    click.echo(
        f"wrote {wf.semantic_map}: {smap.num_trajectories} trajectories ({seen} with a pooled "
        f"frame), {len(smap.class_names)} classes, poolings {', '.join(smap.poolings)}"
    )
