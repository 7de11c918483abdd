"""``pointtraj export FORMAT WORK``: a finished work folder in another tool's format."""

from __future__ import annotations

from pathlib import Path

import click

__all__ = ["export", "rerun", "c3d", "trc"]


@click.group("export")
def export() -> None:
    """Write a finished work folder in another tool's format (one subcommand per format)."""


@export.command("rerun")
@click.argument("work", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option(
    "-o",
    "--out",
    type=click.Path(dir_okay=False, path_type=Path),
    help="The .rrd recording (default WORK/export/recording.rrd).",
)
@click.option(
    "--tail", type=int, help="Past frames in each trajectory's line strip (default 10; 0: none)."
)
@click.option("--images/--no-images", default=None, help="Log the camera images (default: yes).")
@click.option("--image-scale", type=float, help="Scale of the logged images (default 0.5).")
@click.option("--jpeg-quality", type=int, help="JPEG quality of the images (default 85).")
@click.option(
    "--confidences/--no-confidences",
    default=None,
    help="Log the semantic map's per-class confidences per point (default: yes).",
)
@click.option("--pooling", help="The semantic map's pooling (default: that of labels.npz).")
@click.option("--frames", "frames_text", metavar="A:B", help="Frames A..B-1 (default all).")
def rerun(work: Path, out: Path | None, frames_text: str | None, **options) -> None:
    """Write WORK as a Rerun recording: points by label and person, trajectories, cameras.

    Open it with `rerun WORK/export/recording.rrd` (pip install 'pointtraj[export]').
    """
    from ..export.rerun import RerunConfig, export_rerun
    from .common import cli_errors, config_from, progress_bars
    from .render import parse_frame_range

    cfg = config_from(RerunConfig, None, "rerun", options)
    with cli_errors(work), progress_bars() as bars:
        frames = None if frames_text is None else slice(*parse_frame_range(frames_text))
        result = export_rerun(work, out, cfg, frames=frames, progress=bars)
    f = result.frames
    click.echo(
        f"{len(f)} frames ({f.start}:{f.stop}), {result.points} point-frames coloured by "
        f"{result.color_source}"
        + (f", {result.people} people" if result.people else "")
        + f", {result.strips} line strips, {result.cameras} cameras, {result.images} images "
        f"in {result.seconds:.1f} s -> {result.path} ({result.path.stat().st_size / 2**20:.1f} MiB)"
    )


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
