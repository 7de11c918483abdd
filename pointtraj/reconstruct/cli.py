"""``pointtraj reconstruct CAPTURE --out WORK``: dense 3D trajectories from a capture."""

from __future__ import annotations

import logging
from pathlib import Path

import click

__all__ = ["reconstruct", "load_reconstruct_config"]

logger = logging.getLogger(__name__)


def load_reconstruct_config(path: str | Path | None):
    """A :class:`ReconstructConfig` from a TOML file (table ``[reconstruct]`` or top level).

    Unknown keys are an error naming the file and the key.
    """
    from ..config import from_mapping, load_toml
    from ..errors import FileFormatError
    from .track import ReconstructConfig

    if path is None:
        return ReconstructConfig()
    data = load_toml(path)
    table = data.get("reconstruct", data) if isinstance(data.get("reconstruct"), dict) else data
    try:
        return from_mapping(ReconstructConfig, table, where="[reconstruct]")
    except ValueError as exc:
        raise FileFormatError(path, str(exc)) from None


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
    help="TOML with a [reconstruct] table (see ReconstructConfig).",
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
def reconstruct(
    capture: Path,
    work: Path,
    frames: str | None,
    config_path: Path | None,
    restart: bool,
    force_folder: bool,
) -> None:
    """Reconstruct dense 3D trajectories of CAPTURE into the work folder --out.

    Writes WORK/work.toml, WORK/clouds/<frame>.ply per frame, WORK/state/ (resume points) and
    WORK/trajectories.npz. A restart removes only the files pointtraj wrote there.
    """
    from ..cli_common import cli_errors, progress_bars
    from ..stages import reconstruct_work

    with cli_errors(work), progress_bars() as bars:
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
        )
    first = int(traj.first_frame.min()) if traj.num_trajectories else 0
    click.echo(
        f"{traj.num_trajectories} trajectories, {traj.num_point_frames} point-frames over "
        f"frames {first}:{traj.num_frames} (median length {_median(traj.lengths):.0f}) -> {work}"
    )


def _median(a) -> float:
    import numpy as np

    return float(np.median(a)) if len(a) else 0.0
