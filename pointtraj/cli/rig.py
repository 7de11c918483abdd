"""``pointtraj rig``: convert and inspect camera rig files."""

from __future__ import annotations

import click
import numpy as np

__all__ = ["rig"]

_FORMATS = ("toml", "caliscope", "colmap", "panoptic", "qualisys")


@click.group()
def rig() -> None:
    """Convert and inspect camera rigs (rig.toml, caliscope, COLMAP, Panoptic, Qualisys)."""


@rig.command("convert")
@click.argument("src", type=click.Path(exists=True))
@click.argument("dst", type=click.Path())
@click.option(
    "--from", "src_fmt", type=click.Choice(_FORMATS), help="Input format (default: detect)."
)
@click.option(
    "--to",
    "dst_fmt",
    type=click.Choice(_FORMATS),
    help="Output format (default: from DST's name; a name without extension is a COLMAP folder).",
)
def convert(src: str, dst: str, src_fmt: str | None, dst_fmt: str | None) -> None:
    """Read the rig SRC and write it to DST in another format."""
    from ..rigio import load_rig, save_rig

    cams = load_rig(src, fmt=src_fmt)
    save_rig(cams, dst, fmt=dst_fmt)
    click.echo(f"wrote {len(cams)} cameras to {dst}")


@rig.command("show")
@click.argument("path", type=click.Path(exists=True))
@click.option(
    "--from", "src_fmt", type=click.Choice(_FORMATS), help="Input format (default: detect)."
)
def show(path: str, src_fmt: str | None) -> None:
    """Print a summary of the rig in PATH: one line per camera."""
    from ..geometry import detect_up
    from ..rig_analysis import format_length
    from ..rigio import detect_format, load_rig

    fmt = src_fmt or detect_format(path)
    cams = load_rig(path, fmt=fmt)
    click.echo(f"{path}: {fmt}, {len(cams)} cameras")
    click.echo(
        f"{'name':<16} {'size':>11} {'fx':>9} {'fy':>9} {'cx':>8} {'cy':>8} "
        f"{'k1':>8} {'centre (m)':>26} {'fov_x':>6}"
    )
    for cam in cams:
        fov = np.degrees(2 * np.arctan2(cam.width / 2, cam.K[0, 0]))
        centre = "(" + ", ".join(f"{v:7.3f}" for v in cam.C) + ")"
        click.echo(
            f"{cam.name:<16} {cam.width:>5}x{cam.height:<5} {cam.K[0, 0]:9.2f} {cam.K[1, 1]:9.2f} "
            f"{cam.K[0, 2]:8.2f} {cam.K[1, 2]:8.2f} {cam.dist[0]:8.4f} {centre:>26} {fov:6.1f}"
        )
    if len(cams) > 1:
        gaps = np.linalg.norm(cams.C[:, None] - cams.C[None], axis=-1)
        np.fill_diagonal(gaps, np.inf)
        click.echo(
            f"baselines: nearest neighbour {format_length(np.min(gaps))}, "
            f"largest {format_length(np.max(np.where(np.isinf(gaps), 0, gaps)))}"
        )
    up, how = detect_up(cams)
    click.echo(f"up ({', '.join(f'{round(float(v), 3) + 0.0:+.3f}' for v in up)}): {how}")


@rig.command("info")
@click.argument("path", type=click.Path(exists=True))
@click.option("--voxel", type=float, default=0.05, show_default=True, help="Voxel size in metres.")
@click.option(
    "--radius", type=float, default=1.5, show_default=True, help="Capture cylinder radius (m)."
)
@click.option(
    "--height", type=float, default=2.5, show_default=True, help="Capture cylinder height (m)."
)
@click.option(
    "--out",
    type=click.Path(file_okay=False),
    help="Folder for the top-view coverage picture (rig_coverage.png).",
)
def info(path: str, voxel: float, radius: float, height: float, out: str | None) -> None:
    """Coverage of the capture volume by the rig in PATH: camera counts and pixel density."""
    from pathlib import Path

    from ..rig_analysis import CaptureVolume, analyze_rig, plot_coverage
    from ..rigio import load_rig

    cams = load_rig(path)
    coverage = analyze_rig(cams, CaptureVolume(radius=radius, height=height), voxel)
    click.echo(f"{path}: {len(cams)} cameras")
    click.echo(coverage.report())
    if len(cams) > 1:  # the volume the reconstruction matches camera pairs in
        from ..reconstruct.connectivity import common_view
        from ..scale import scene_scale

        click.echo(common_view(cams).summary())
        click.echo(scene_scale(cams, log=False).summary())
        for line in _reconstruction_choices(cams):
            click.echo(line)
    if out is not None:
        png = Path(out) / "rig_coverage.png"
        png.parent.mkdir(parents=True, exist_ok=True)
        plot_coverage(coverage, png, cams)
        click.echo(f"wrote {png}")


def _reconstruction_choices(cams) -> list[str]:
    """What the reconstruction's defaults choose for this rig: the lines that
    ``ReconstructConfig.for_rig`` logs (INFO, and a WARNING for what it leaves off)."""
    import logging

    from ..reconstruct.config import ReconstructConfig

    return [
        ("reconstruction: " if level < logging.WARNING else "reconstruction, warning: ") + message
        for level, message in ReconstructConfig().rig_notes(cams)
    ]
