"""``pointtraj export FORMAT WORK``: a finished work folder in another tool's format."""

from __future__ import annotations

from pathlib import Path

import click

__all__ = ["export", "c3d", "trc"]


@click.group("export")
def export() -> None:
    """Write a finished work folder in another tool's format (one subcommand per format)."""


# -- motion capture: joint centres and part centroids as markers (C3D, TRC) -------------------
def _mocap_command(fmt: str, suffix: str, reader: str):
    """The ``export c3d`` / ``export trc`` command: segments.npz's markers in one file."""

    @export.command(fmt)
    @click.argument("work", type=click.Path(exists=True, file_okay=False, path_type=Path))
    @click.option(
        "--out",
        type=click.Path(dir_okay=False, path_type=Path),
        help=f"File to write [default: WORK/segments.{suffix}].",
    )
    @click.option("--units", type=click.Choice(["mm", "m"]), default="mm", show_default=True)
    @click.option(
        "--up",
        type=click.Choice(["z", "y"]),
        default="z",
        show_default=True,
        help="Up axis in the file: pointtraj's z, or y (OpenSim).",
    )
    @click.option("--no-centroids", is_flag=True, help="Only the joint centres.")
    def command(work: Path, out: Path | None, units: str, up: str, no_centroids: bool) -> None:
        from ..export import mocap
        from ..segments import load_segments
        from ..workdir import WorkFolder
        from .common import cli_errors

        out = out or work / f"segments.{suffix}"
        with cli_errors(work):
            markers = mocap.segment_markers(
                load_segments(WorkFolder(work).segments), centroids=not no_centroids
            )
            getattr(mocap, f"save_{fmt}")(markers, out, units=units, up=up)
        T, K, _ = markers.xyz.shape
        click.echo(f"{K} markers x {T} frames at {markers.fps:g} Hz ({units}) -> {out}")

    command.__doc__ = f"Joint centres and part centroids of WORK/segments.npz as a {reader} file."
    command.help = command.__doc__
    return command


c3d = _mocap_command("c3d", "c3d", "C3D (motion-capture software, ezc3d)")
trc = _mocap_command("trc", "trc", "TRC (Pose2Sim, OpenSim)")
