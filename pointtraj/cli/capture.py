"""``pointtraj capture``: make a capture folder from videos or image folders and a rig file."""

from __future__ import annotations

from pathlib import Path

import click

__all__ = ["capture"]

_FORMATS = ("toml", "caliscope", "colmap", "panoptic", "qualisys")


@click.command("capture")
@click.argument("out", type=click.Path(file_okay=False, path_type=Path))
@click.argument("media", nargs=-1, required=True, metavar="MEDIA...")
@click.option(
    "--rig",
    "rig_path",
    required=True,
    type=click.Path(exists=True, path_type=Path),
    help="Calibration: rig.toml, caliscope, COLMAP, Panoptic or Qualisys.",
)
@click.option(
    "--rig-format", type=click.Choice(_FORMATS), help="The rig's format (default: detect)."
)
@click.option(
    "--fps",
    type=float,
    help="Frame rate, written to capture.toml (default: the videos' headers, if plausible).",
)
@click.option(
    "--up",
    help="World up direction, written to capture.toml: +x, -x, +y, -y, +z, -z "
    "(default auto: detected from the cameras).",
)
@click.option(
    "--labels",
    help="A labels.toml to copy into the capture, or 'default' for the body-part set.",
)
@click.option("--link", is_flag=True, help="Symlink the videos and images instead of copying them.")
@click.option(
    "--drop-missing",
    is_flag=True,
    help="Leave rig cameras without media out of rig.toml (default: an error).",
)
@click.option("--description", default="", help="Written to capture.toml.")
def capture(
    out: Path,
    media: tuple[str, ...],
    rig_path: Path,
    rig_format: str | None,
    fps: float | None,
    up: str | None,
    labels: str | None,
    link: bool,
    drop_missing: bool,
    description: str,
) -> None:
    """Make the capture folder OUT from a rig file and each camera's video or image folder.

    MEDIA: per camera a video (camera = file name without extension), an image folder
    (camera = folder name; files in the order of the numbers in their names), NAME=PATH to
    name the camera, or a folder of such videos and folders. Sizes and frame counts are
    checked against the rig before anything is written.
    """
    from ..capture import make_capture, media_by_camera
    from ..rigio import load_rig

    rig = load_rig(rig_path, fmt=rig_format)
    made = make_capture(
        out,
        rig_path,
        media_by_camera(media, rig),
        rig_format=rig_format,
        fps=fps,
        up=up,
        labels=labels,
        mode="link" if link else "copy",
        strict=not drop_missing,
        description=description,
    )
    verb = "linked" if made.mode == "link" else "copied"
    click.echo(
        f"made {made.path}: {len(made.media)} cameras, {made.num_frames} frames at "
        f"{made.fps:.4g} fps ({made.fps_source}); rig from {made.rig_source}"
    )
    for m in made.media:
        what = "video " if m.kind == "video" else "images"
        click.echo(
            f"  {m.camera:<12} {what} {m.num_frames:>6} frames {m.size[0]:>5}x{m.size[1]:<5} "
            f"{verb} from {m.path}"
        )
    if made.dropped:
        click.echo(f"  left out (no media): {', '.join(made.dropped)}")
    up_text = ", ".join(f"{round(float(v), 2) + 0.0:+.2f}" for v in made.up)
    click.echo(f"up ({up_text}): {made.up_source}")
    click.echo("wrote " + ", ".join(p.name for p in made.files))
