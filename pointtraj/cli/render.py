"""``pointtraj render``: semantic trajectories as PNG frames and MP4s in ``WORK/renders/``."""

from __future__ import annotations

from pathlib import Path

import click

from .common import executor_options

__all__ = ["render", "parse_frame_range", "parse_size"]


def parse_frame_range(text: str) -> tuple[int | None, int | None]:
    """Parse ``A:B`` (B exclusive; either side may be empty or negative).

    Examples
    --------
    >>> parse_frame_range("10:20"), parse_frame_range(":-5")
    ((10, 20), (None, -5))
    """
    parts = text.split(":")
    if len(parts) != 2:
        raise click.BadParameter(f"expected A:B, got {text!r}", param_hint="--frames")
    try:
        a, b = (int(p) if p.strip() else None for p in parts)
    except ValueError:
        raise click.BadParameter(
            f"expected integers A:B, got {text!r}", param_hint="--frames"
        ) from None
    return a, b


def parse_size(text: str) -> tuple[int, int]:
    """Parse ``WxH``.

    Examples
    --------
    >>> parse_size("1280x1024")
    (1280, 1024)
    """
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise click.BadParameter(
            f"expected WIDTHxHEIGHT, got {text!r}", param_hint="--size"
        ) from None
    return w, h


@click.command("render")
@click.argument("work", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option(
    "--view",
    "views",
    multiple=True,
    metavar="NAME",
    help="'orbit' (a virtual camera circling the scene) or a rig camera; repeatable "
    "(default orbit).",
)
@click.option("--engine", type=click.Choice(["open3d", "opencv"]), help="Renderer of the views.")
@click.option("--tail", type=int, help="Past frames drawn as tails (default 10).")
@click.option("--frames", "frames_text", metavar="A:B", help="Frames A..B-1 (default all).")
@click.option("--stride", type=int, help="Render every N-th frame.")
@click.option("--size", "size_text", metavar="WxH", help="Orbit image size (default 1280x1024).")
@click.option("--point-size", type=float, help="Point size in pixels in the views.")
@click.option(
    "--colors",
    type=click.Choice(["auto", "labels", "semantic_map", "grey"]),
    help="Colour source (default auto: labels.npz, else semantic_map.npz argmax).",
)
@click.option(
    "--color-by",
    type=click.Choice(["label", "instance"]),
    help="Colour by class (default) or by person (labels.npz instance, one colour per person).",
)
@click.option("--fps", type=float, help="MP4 frame rate (default the capture's, real time).")
@click.option(
    "--up",
    help="World up direction for the floor grid and the orbit: auto (capture.toml's, else "
    "detected from the cameras), +x, -x, +y, -y, +z or -z.",
)
@click.option(
    "--overlay-camera",
    "overlay_cameras",
    multiple=True,
    metavar="NAME",
    help="Camera whose images get overlays; repeatable (default the camera views, else the "
    "first camera).",
)
@click.option("--no-overlays", is_flag=True, help="No overlays on the camera images.")
@click.option("--no-video", is_flag=True, help="PNG frames only.")
@click.option("--force", is_flag=True, help="Re-render frames that are already there.")
@click.option(
    "--config",
    "config_path",
    type=click.Path(exists=True, dir_okay=False, path_type=Path),
    help="TOML file with a [render] table of RenderConfig fields.",
)
@executor_options
def render(
    work: Path,
    views: tuple[str, ...],
    frames_text: str | None,
    size_text: str | None,
    overlay_cameras: tuple[str, ...],
    no_overlays: bool,
    no_video: bool,
    force: bool,
    config_path: Path | None,
    workers: int | None,
    scheduler: str | None,
    **options,
) -> None:
    """Draw WORK's trajectories coloured by label, with tails, into WORK/renders/.

    Writes PNG frames and an MP4 per view (renders/views/), overlays on the input camera
    images (renders/overlays/) and renders/legend.png. Frames already rendered with the same
    settings are kept, so a rerun resumes.
    """
    from ..render import RenderConfig, render_work
    from .common import cli_errors, config_from, executor_config, open_cli_executor, progress_bars

    options.update(
        views=views or None,
        frames=parse_frame_range(frames_text) if frames_text is not None else None,
        size=parse_size(size_text) if size_text is not None else None,
        overlay_cameras=overlay_cameras or None,
        overlays=False if no_overlays else None,
        video=False if no_video else None,
    )
    cfg = config_from(RenderConfig, config_path, "render", options)
    with (
        cli_errors(work),
        open_cli_executor(executor_config(workers, scheduler)) as ex,
        progress_bars() as bars,
    ):
        result = render_work(work, cfg, force=force, progress=bars, executor=ex)
    f = result.frames
    click.echo(
        f"{result.num_trajectories} trajectories coloured by {result.color_source} "
        f"({len(result.classes)} classes in the legend), frames {f.start}:{f.stop}"
        + (f" step {f.step}" if f.step != 1 else "")
    )
    for out in result.outputs:
        per = f", {out.render_seconds / out.rendered:.2f} s/frame" if out.rendered else ""
        video = f" + {out.video.name}" if out.video is not None else ""
        click.echo(
            f"{out.kind:7s} {out.name:8s} {out.size[0]}x{out.size[1]}: {out.rendered} rendered, "
            f"{out.skipped} kept{per} -> {out.folder}/{video}"
        )
    click.echo(f"legend  -> {result.legend}")
    click.echo(
        f"{result.rendered} images rendered ({cfg.engine} views), {result.skipped} kept, "
        f"in {result.seconds:.1f} s"
    )
