"""``pointtraj run CONFIG.toml`` and ``pointtraj demo``: every stage, end to end."""

from __future__ import annotations

import logging
import sys
from pathlib import Path

import click

from .errors import PointtrajError, os_error_message

__all__ = ["run", "demo", "ProgressBars"]

logger = logging.getLogger(__name__)


class ProgressBars:
    """A ``progress(label, done, total)`` callable that shows one click progress bar per step.

    A new label closes the previous bar and opens a new one; :meth:`close` ends the last.
    """

    def __init__(self) -> None:
        self._bar = None
        self._label: str | None = None
        self._done = 0

    def __call__(self, label: str, done: int, total: int) -> None:
        if label != self._label or self._bar is None:
            self.close()
            self._bar = click.progressbar(
                length=max(int(total), 1), label=f"  {label}", show_pos=True, file=sys.stderr
            )
            self._bar.__enter__()
            self._label, self._done = label, 0
        step = int(done) - self._done
        if step > 0:
            self._bar.update(step)
            self._done = int(done)

    def close(self) -> None:
        """Finish the bar on screen, if any."""
        if self._bar is not None:
            self._bar.__exit__(None, None, None)
        self._bar, self._label = None, None


def _announce(stage: str, event: str) -> None:
    if event == "skip":
        click.echo(f"{stage}: up to date", err=True)
    elif event == "start":
        click.echo(f"{stage} ...", err=True)


def run_and_report(config, force: tuple[str, ...] = ()):
    """Run a pipeline with progress bars; turn library errors into one-line CLI errors."""
    from .pipeline import run_pipeline

    bars = ProgressBars()

    def on_stage(stage: str, event: str) -> None:
        bars.close()
        _announce(stage, event)

    try:
        return run_pipeline(config, force=force, progress=bars, on_stage=on_stage)
    except PointtrajError as exc:
        raise click.ClickException(str(exc)) from None
    except OSError as exc:
        raise click.ClickException(os_error_message(exc, config.work)) from None
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
def run(config_path: Path, work: Path | None, capture: Path | None, force: tuple[str, ...]) -> None:
    """Run the pipeline described by CONFIG (a pipelines/*.toml file), skipping what is done.

    Relative paths in CONFIG are taken from the current folder. An interrupted run resumes.
    """
    from .pipeline import load_pipeline

    try:
        config = load_pipeline(config_path).with_paths(capture, work)
    except PointtrajError as exc:
        raise click.ClickException(str(exc)) from None
    click.echo(f"pipeline {config.name or config_path.stem}: work folder {config.work}", err=True)
    result = run_and_report(config, force)
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
def demo(out: Path, frames: int | None, force: tuple[str, ...]) -> None:
    """Run the synthetic demo end to end: render a capture, reconstruct, label, evaluate.

    The same as `pointtraj run pipelines/synthetic_demo.toml` with its folders under --out.
    """
    from .pipeline import demo_pipeline

    config = demo_pipeline(out, frames=frames)
    click.echo(f"pointtraj demo: {config.description}", err=True)
    result = run_and_report(config, force)
    for line in _summary(result):
        click.echo(line)
    _headline(result)


def _headline(result) -> None:
    """Print the report's main figures, if the evaluate stage wrote them."""
    import json

    from .evaluate.study import headline

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
