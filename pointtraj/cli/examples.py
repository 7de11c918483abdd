"""``pointtraj examples``: lay out real example captures (``fetch``) and list them (``list``)."""

from __future__ import annotations

import click

__all__ = ["examples"]


@click.group()
def examples() -> None:
    """Real example captures, laid out as pointtraj capture folders."""


@examples.command("list")
def list_examples() -> None:
    """List the example captures with their source and licence."""
    from ..examples import EXAMPLES

    for spec in EXAMPLES.values():
        click.echo(f"{spec.name}: {spec.description}")
        click.echo(f"    source: {spec.source}; licence: {spec.licence}")


@examples.command("fetch")
@click.argument("name")
@click.option(
    "--out",
    "-o",
    required=True,
    type=click.Path(file_okay=False),
    help="Capture folder to write (new or empty).",
)
@click.option(
    "--force", is_flag=True, help="Replace OUT if it holds an example capture written before."
)
@click.option(
    "--wheel",
    type=click.Path(exists=True, dir_okay=False),
    help="pose2sim, pose2sim-multi: use this downloaded pose2sim-0.10.49 wheel instead of pip "
    "download.",
)
@click.option(
    "--source",
    type=click.Path(exists=True, file_okay=False),
    help="caliscope-board: the caliscope_board_4cam folder (default: shared/data).",
)
@click.option(
    "--copy", is_flag=True, help="caliscope-board: copy the videos instead of symlinking them."
)
def fetch(
    name: str, out: str, force: bool, wheel: str | None, source: str | None, copy: bool
) -> None:
    """Lay out example NAME as a capture in OUT (see `pointtraj examples list`)."""
    from ..examples import EXAMPLES, fetch_example

    if name not in EXAMPLES:
        raise click.UsageError(
            f"unknown example {name!r}; valid names: {', '.join(sorted(EXAMPLES))}"
        )
    pose2sim = name.startswith("pose2sim")
    if not pose2sim and wheel is not None:
        raise click.UsageError("--wheel applies to the pose2sim examples only")
    if name != "caliscope-board" and (source is not None or copy):
        raise click.UsageError("--source and --copy apply to the caliscope-board example only")
    options = {"wheel": wheel} if pose2sim else {"source": source, "link": not copy}
    result = fetch_example(name, out, overwrite=force, **options)
    counts = ", ".join(f"{k}={v}" for k, v in result.num_frames.items())
    click.echo(f"{result.name}: {result.path} ({len(result.camera_names)} cameras, {counts})")
    click.echo(f"fps: {result.fps:.3f}")
    for cam, mapping in result.corrections.items():
        click.echo(f"calibration adapted for {cam}: {mapping.describe()}")
    for note in result.notes:
        click.echo(f"- {note}")
