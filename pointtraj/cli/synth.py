"""``pointtraj synth``: render a synthetic capture with ground truth (``stages.synthesize``)."""

from __future__ import annotations

from pathlib import Path

import click

from .common import executor_options

__all__ = ["synth"]


def _summary_lines(summary) -> list[str]:
    t = summary.timings
    lines = [
        f"capture   {summary.path}",
        f"cameras   {summary.cameras}",
        f"frames    {summary.frames} ({summary.rendered} rendered, {summary.skipped} already done)",
        f"images    {summary.images}",
        f"GT points {summary.gt_points}",
    ]
    if summary.rendered:
        per = summary.rendered
        lines.append(
            f"time      {summary.seconds_per_frame:.2f} s/frame (ray casting "
            f"{t.cast / per:.2f}, shading {t.shade / per:.2f}, writing "
            f"{t.extra.get('write', 0.0) / per:.2f})"
        )
    return lines


@click.command("synth")
@click.option(
    "--preset", default="tiny4", show_default=True, help="Camera rig preset (see --list)."
)
@click.option("--scene", default="dribble", show_default=True, help="Scene to render (see --list).")
@click.option("--frames", type=int, default=10, show_default=True, help="Number of frames.")
@click.option(
    "--out",
    type=click.Path(file_okay=False, path_type=Path),
    help="Capture folder to write (resumes if it holds the same capture).  [required]",
)
@click.option("--seed", type=int, default=0, show_default=True, help="Random seed.")
@click.option(
    "--points-per-part",
    type=int,
    default=300,
    show_default=True,
    help="Ground-truth surface points per labelled part.",
)
@click.option(
    "--image-format",
    type=click.Choice(["jpg", "png"]),
    default="jpg",
    show_default=True,
    help="Frame image format.",
)
@click.option(
    "--rig",
    "rig_file",
    type=click.Path(exists=True, path_type=Path),
    help="Render with the cameras of this rig file instead of a preset (a synthetic twin of "
    "a real rig: the subject where the optical axes meet, or at --at).",
)
@click.option(
    "--at",
    help="With --rig: the subject's centre in the rig's coordinates, metres (X,Y,Z).",
)
@click.option(
    "--up",
    default="auto",
    show_default=True,
    help="With --rig: the rig's up axis (auto, +z, -y, ...).",
)
@click.option("--fps", type=float, help="Frame rate [default: the preset's; 30 with --rig].")
@click.option(
    "--scale",
    type=float,
    default=None,
    help="The scene's size against its human size: geometry, motion, texture and ground truth "
    "(default: the preset's, 0.004 for narrow7 and 1 for the others).",
)
@click.option(
    "--rig-scale",
    type=float,
    default=1.0,
    show_default=True,
    help="The rig's size against the preset's (camera centres about its target).",
)
@click.option("--list", "list_", is_flag=True, help="List presets and scenes, then exit.")
@executor_options
def synth(
    preset: str,
    scene: str,
    frames: int,
    out: Path | None,
    seed: int,
    points_per_part: int,
    image_format: str,
    rig_file: Path | None,
    at: str | None,
    up: str,
    fps: float | None,
    scale: float | None,
    rig_scale: float,
    list_: bool,
    workers: int | None,
    scheduler: str | None,
) -> None:
    """Render a synthetic multi-camera capture with ground-truth trajectories."""
    from ..stages import SynthConfig, synthesize
    from ..synth.presets import PRESETS
    from ..synth.scenes import SCENES
    from .common import executor_config, open_cli_executor, progress_bars

    if list_:
        for name, p in sorted(PRESETS.items()):
            click.echo(f"preset {name:12s} {p.description}")
        for name, s in sorted(SCENES.items()):
            click.echo(f"scene  {name:12s} {s.description}")
        return
    if out is None:
        raise click.UsageError("Missing option '--out'.")
    if preset not in PRESETS:
        raise click.BadParameter(
            f"unknown preset {preset!r}; choose one of {', '.join(sorted(PRESETS))}",
            param_hint="--preset",
        )
    if scene not in SCENES:
        raise click.BadParameter(
            f"unknown scene {scene!r}; choose one of {', '.join(sorted(SCENES))}",
            param_hint="--scene",
        )
    if frames < 1:
        raise click.BadParameter(f"must be at least 1, got {frames}", param_hint="--frames")
    if points_per_part < 1:
        raise click.BadParameter(
            f"must be at least 1, got {points_per_part}", param_hint="--points-per-part"
        )
    position = None
    if at is not None:
        try:
            position = tuple(float(v) for v in at.split(","))
        except ValueError:
            position = ()
        if len(position) != 3:
            raise click.BadParameter(f"expected X,Y,Z, got {at!r}", param_hint="--at")
        if rig_file is None:
            raise click.UsageError("--at places the subject in a rig file's frame; give --rig")
    for name, value in (("--scale", scale), ("--rig-scale", rig_scale)):
        if value is not None and not value > 0:
            raise click.BadParameter(f"must be positive, got {value}", param_hint=name)
    config = SynthConfig(
        preset=preset,
        scene=scene,
        frames=frames,
        seed=seed,
        points_per_part=points_per_part,
        image_format=image_format,
        rig=str(rig_file) if rig_file is not None else "",
        at=position,
        up=up,
        fps=fps,
        scale=scale,
        rig_scale=rig_scale,
    )
    label = f"rendering {scene} ({preset if rig_file is None else 'twin of ' + rig_file.name})"
    with open_cli_executor(executor_config(workers, scheduler)) as ex, progress_bars() as bars:
        summary = synthesize(
            out, config, lambda _, done, total: bars(label, done, total), executor=ex
        )
    for line in _summary_lines(summary):
        click.echo(line)
