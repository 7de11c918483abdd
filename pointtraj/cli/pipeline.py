"""``pointtraj run CONFIG.toml`` and ``pointtraj demo``: every stage, end to end."""

from __future__ import annotations

from pathlib import Path

import click

from .common import ProgressBars, cli_errors, executor_config, executor_options

__all__ = ["run", "demo"]


def _announce(stage: str, event: str) -> None:
    if event == "skip":
        click.echo(f"{stage}: up to date", err=True)
    elif event == "start":
        click.echo(f"{stage} ...", err=True)


def run_and_report(config, force: tuple[str, ...] = (), force_folder: bool = False):
    """Run a pipeline with progress bars; turn library errors into one-line CLI errors.

    Where the tasks run (and the Dask dashboard's link) is shown when the executor opens."""
    from ..pipeline import run_pipeline

    bars = ProgressBars()

    def on_stage(stage: str, event: str) -> None:
        bars.close()
        _announce(stage, event)

    def on_executor(executor) -> None:
        bars.close()
        click.echo(f"executor: {executor.description}", err=True)

    try:
        with cli_errors(config.work):
            return run_pipeline(
                config,
                force=force,
                progress=bars,
                on_stage=on_stage,
                force_folder=force_folder,
                on_executor=on_executor,
            )
    finally:
        bars.close()


def _summary(result) -> list[str]:
    lines = []
    if result.ran:
        lines.append("ran: " + ", ".join(f"{s} ({result.seconds[s]:.1f} s)" for s in result.ran))
    if result.skipped:
        lines.append("up to date: " + ", ".join(result.skipped))
    for name, path in result.outputs.items():
        lines.append(f"{name:13s} {path}")
    return lines


@click.command("run")
@click.argument("config_path", metavar="CONFIG", type=click.Path(dir_okay=False, path_type=Path))
@click.option(
    "--work",
    type=click.Path(file_okay=False, path_type=Path),
    help="Work folder (overrides the file's `work`).",
)
@click.option(
    "--capture",
    type=click.Path(file_okay=False, path_type=Path),
    help="Capture folder (overrides the file's `capture`).",
)
@click.option(
    "--force",
    multiple=True,
    metavar="STAGE",
    help="Re-run this stage even if it is up to date (repeatable; `all` for every stage).",
)
@click.option(
    "--force-folder",
    is_flag=True,
    help="Use the work folder even if it is a non-empty folder that pointtraj did not make (the "
    "files removed are logged).",
)
@executor_options
def run(
    config_path: Path,
    work: Path | None,
    capture: Path | None,
    force: tuple[str, ...],
    force_folder: bool,
    workers: int | None,
    scheduler: str | None,
) -> None:
    """Run the pipeline described by CONFIG (a pipelines/*.toml file), skipping what is done.

    Relative paths in CONFIG are taken from the current folder. An interrupted run resumes.
    """
    import dataclasses

    from ..pipeline import load_pipeline

    config = load_pipeline(config_path).with_paths(capture, work)
    config = dataclasses.replace(
        config, executor=executor_config(workers, scheduler, config.executor)
    )
    click.echo(f"pipeline {config.name or config_path.stem}: work folder {config.work}", err=True)
    result = run_and_report(config, force, force_folder)
    for line in _summary(result):
        click.echo(line)
    _headline(result)


@click.command("demo")
@click.option(
    "--out",
    type=click.Path(file_okay=False, path_type=Path),
    default=Path("pointtraj-demo"),
    show_default=True,
    help="Folder for everything the demo makes (capture/ and work/).",
)
@click.option("--frames", type=click.IntRange(2), default=None, help="Frames to render.")
@click.option(
    "--force",
    multiple=True,
    metavar="STAGE",
    help="Re-run this stage even if it is up to date (repeatable; `all` for every stage).",
)
@executor_options
def demo(
    out: Path,
    frames: int | None,
    force: tuple[str, ...],
    workers: int | None,
    scheduler: str | None,
) -> None:
    """Run the synthetic demo end to end: render a capture, reconstruct, label, evaluate.

    The same as `pointtraj run pipelines/synthetic_demo.toml` with its folders under --out.
    """
    import dataclasses

    from ..pipeline import demo_pipeline

    config = demo_pipeline(out, frames=frames)
    config = dataclasses.replace(config, executor=executor_config(workers, scheduler))
    click.echo(f"pointtraj demo: {config.description}", err=True)
    result = run_and_report(config, force)
    for line in _summary(result):
        click.echo(line)
    _headline(result)


def _headline(result) -> None:
    """Print the report's main figures and its health block, if the evaluate stage wrote
    them."""
    import json

    from ..evaluate.health import health_lines
    from ..evaluate.study import headline

    path = result.outputs.get("report")
    if path is None or not (path.parent / "metrics.json").is_file():
        return
    metrics = json.loads((path.parent / "metrics.json").read_text(encoding="utf-8"))
    click.echo("")
    for line in headline(metrics):
        click.echo(line)
    click.echo(f"report: {path}")
    renders = result.outputs.get("renders")
    if renders is not None:
        click.echo(f"renders: {renders}")
    for line in health_lines(metrics):  # last: what went wrong, if anything
        click.echo(line)
