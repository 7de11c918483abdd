"""``pointtraj segments WORK``: per-part 6-DoF poses and joint centres (``segments.npz``)."""

from __future__ import annotations

from pathlib import Path

import click

__all__ = ["segments"]


@click.command("segments")
@click.argument("work", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--threshold", "ransac_threshold", type=float, help="RANSAC inlier distance (m).")
@click.option("--min-points", type=int, help="Fewest inliers for a part's pose in a frame.")
@click.option("--min-frames", type=int, help="Fewest frames with both poses for a joint.")
@click.option(
    "--min-rotation", "min_rotation_deg", type=float, help="Least RMS relative rotation (deg)."
)
@click.option(
    "--hinge-centres/--no-hinge-centres",
    default=None,
    help="Report a hinge's centre on its axis (default) or NaN.",
)
@click.option(
    "--config",
    "config_path",
    type=click.Path(exists=True, dir_okay=False, path_type=Path),
    help="TOML file with a [segments] table of SegmentsConfig fields (a pipeline file works).",
)
def segments(work: Path, config_path: Path | None, **options) -> None:
    """Fit each labelled part's pose per frame and the joint centres: WORK/segments.npz."""
    from ..segments import JOINT_STATUS, SegmentsConfig
    from ..stages import segments_work
    from .common import cli_errors, config_from, progress_bars

    cfg = config_from(SegmentsConfig, config_path, "segments", options)
    with cli_errors(work), progress_bars() as bars:
        res = segments_work(work, cfg, progress=bars)
    posed = int((res.inliers > 0).sum())
    click.echo(
        f"{res.num_segments} segments, {posed} of {res.rotation[..., 0, 0].size} "
        f"segment-frames posed -> {work / 'segments.npz'}"
    )
    for name, st, n, deg, err in zip(
        res.joint_labels(),
        res.joint_status,
        res.joint_frames,
        res.joint_rotation_deg,
        res.joint_uncertainty,
    ):
        click.echo(
            f"  {name:24s} {JOINT_STATUS[st]:12s} {n:5d} frames, rotation "
            + " / ".join(f"{d:.1f}" for d in deg)
            + f" deg, standard error {1000 * err:.1f} mm"
        )
