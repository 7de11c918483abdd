"""The trajectories stage: ``pointtraj reconstruct CAPTURE --out WORK`` (dense 3D trajectories
from the images) and ``pointtraj gt-trajectories`` (a synthetic capture's ground truth instead)."""

from __future__ import annotations

from pathlib import Path

import click

from .common import executor_options

__all__ = ["reconstruct", "gt_trajectories"]


@click.command("reconstruct")
@click.argument("capture", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option(
    "--out",
    "work",
    required=True,
    type=click.Path(file_okay=False, path_type=Path),
    help="Work folder to write (created if needed; an interrupted run there resumes).",
)
@click.option("--frames", default=None, help="Frames A:B to process (B exclusive), default all.")
@click.option(
    "--config",
    "config_path",
    type=click.Path(exists=True, dir_okay=False, path_type=Path),
    default=None,
    help="TOML with a [reconstruct] table (see ReconstructConfig); a pipeline file works.",
)
@click.option(
    "--restart", is_flag=True, help="Discard a previous run's state and clouds instead of resuming."
)
@click.option(
    "--force-folder",
    is_flag=True,
    help="Use --out even if it is a non-empty folder that pointtraj did not make (the files "
    "removed are logged).",
)
@executor_options
def reconstruct(
    capture: Path,
    work: Path,
    frames: str | None,
    config_path: Path | None,
    restart: bool,
    force_folder: bool,
    workers: int | None,
    scheduler: str | None,
) -> None:
    """Reconstruct dense 3D trajectories of CAPTURE into the work folder --out.

    Writes WORK/work.toml, WORK/clouds/<frame>.ply per frame, WORK/state/ (resume points) and
    WORK/trajectories.npz. A restart removes only the files pointtraj wrote there. Captures
    longer than [reconstruct] chunk_frames are tracked in temporal chunks, one task each on the
    executor (--workers, --scheduler).
    """
    import numpy as np

    from ..stages import load_reconstruct_config, reconstruct_work
    from .common import cli_errors, executor_config, open_cli_executor, progress_bars

    with (
        cli_errors(work),
        open_cli_executor(executor_config(workers, scheduler)) as ex,
        progress_bars() as bars,
    ):
        cfg = load_reconstruct_config(config_path)
        traj = reconstruct_work(
            work,
            capture,
            cfg,
            frames,
            restart=restart,
            force=force_folder,
            frames_label="--frames",
            progress=bars,
            executor=ex,
        )
    # the frames holding points (a --frames range's, not the capture's num_frames)
    first = int(traj.first_frame.min()) if traj.num_trajectories else 0
    end = int(traj.last_frame.max()) + 1 if traj.num_trajectories else 0
    median = float(np.median(traj.lengths)) if len(traj.lengths) else 0.0
    click.echo(
        f"{traj.num_trajectories} trajectories, {traj.num_point_frames} point-frames over "
        f"frames {first}:{end} (median length {median:.0f}) -> {work}"
    )


@click.command("gt-trajectories")
@click.argument("capture", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option(
    "--out",
    "work",
    required=True,
    type=click.Path(file_okay=False, path_type=Path),
    help="Work folder to write trajectories.npz and work.toml into.",
)
@click.option(
    "--min-visible",
    default=2,
    show_default=True,
    type=click.IntRange(1),
    help="Keep point-frames seen by at least this many cameras.",
)
def gt_trajectories(capture: Path, work: Path, min_visible: int) -> None:
    """Write a synthetic CAPTURE's ground-truth trajectories into a work folder."""
    from ..stages import ground_truth_work
    from ..workdir import WorkFolder

    try:
        ground_truth_work(work, capture, min_visible)
    except ImportError as exc:
        raise click.ClickException(str(exc)) from None
    click.echo(f"wrote {WorkFolder(work).trajectories}")
