"""``pointtraj evaluate WORK``: the report of a work folder (``WORK/report/``)."""

from __future__ import annotations

from pathlib import Path

import click

from .common import executor_options

__all__ = ["evaluate"]


@click.command("evaluate")
@click.argument("work", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option(
    "--capture",
    type=click.Path(exists=True, file_okay=False, path_type=Path),
    help="The capture (default: the one WORK/work.toml records).",
)
@click.option("--validity-tracks", type=int, help="Trajectories sampled for predictive validity.")
@click.option("--validity-frames", type=int, help="Frames used for predictive validity.")
@click.option("--seed", type=int, help="Seed of the random sampling.")
@click.option(
    "--config",
    "config_path",
    type=click.Path(exists=True, dir_okay=False, path_type=Path),
    help="TOML file with an [evaluate] table of EvaluateConfig fields (a pipeline file works; "
    "its [semantics] table then names the recogniser of the validity study).",
)
@executor_options
def evaluate(
    work: Path,
    capture: Path | None,
    config_path: Path | None,
    workers: int | None,
    scheduler: str | None,
    **options,
) -> None:
    """Write WORK/report/: index.md, PNG plots and metrics.json, beside the paper's figures.

    Runs the paper's three studies (temporal consistency, affinity effectiveness, predictive
    validity on held-out cameras) and, on synthetic captures, the ground-truth metrics.
    """
    from ..config import load_toml
    from ..evaluate.health import health_lines
    from ..evaluate.study import EvaluateConfig, evaluate_work, headline
    from ..stages import SemanticsStageConfig
    from .common import (
        cli_errors,
        config_from,
        executor_config,
        open_cli_executor,
        progress_bars,
    )

    cfg = config_from(EvaluateConfig, config_path, "evaluate", options)
    semantics = None
    if config_path is not None and "semantics" in load_toml(config_path):  # read: it is valid
        semantics = config_from(SemanticsStageConfig, config_path, "semantics")
    with (
        cli_errors(work),
        open_cli_executor(executor_config(workers, scheduler)) as ex,
        progress_bars() as bars,
    ):
        metrics = evaluate_work(
            work, cfg, capture, semantics_config=semantics, progress=bars, executor=ex
        )
    for line in headline(metrics):
        click.echo(line)
    click.echo(f"report: {work / 'report' / 'index.md'}")
    for line in health_lines(metrics):
        click.echo(line)
