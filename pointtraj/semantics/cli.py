"""``pointtraj semantics`` (build the 3D semantic map) and ``pointtraj gt-trajectories``."""

from __future__ import annotations

import logging
import tomllib
from pathlib import Path
from typing import Any

import click

from ..errors import PointtrajError

__all__ = ["semantics", "gt_trajectories", "write_gt_trajectories"]

logger = logging.getLogger(__name__)


def _read_work_capture(work: Path) -> Path | None:
    """The capture path recorded in ``WORK/work.toml`` (None when there is no work.toml)."""
    from ..config import load_toml
    from ..errors import FileFormatError

    path = work / "work.toml"
    if not path.is_file():
        return None
    data = load_toml(path)
    capture = data.get("capture")
    if not isinstance(capture, str) or not capture:
        raise FileFormatError(path, "capture: expected the capture folder as a string")
    return Path(capture)


def write_gt_trajectories(capture: Path, work: Path, min_visible: int = 2) -> Path:
    """Write a synthetic capture's ground truth as ``WORK/trajectories.npz``
    (:func:`pointtraj.stages.ground_truth_work`).

    Returns
    -------
    pathlib.Path
        The written ``trajectories.npz``.
    """
    from ..stages import ground_truth_work
    from ..workdir import WorkFolder

    ground_truth_work(work, capture, min_visible)
    return WorkFolder(work).trajectories


def _parse_options(options: tuple[str, ...]) -> dict[str, Any]:
    """``KEY=VALUE`` pairs, each VALUE read as a TOML value (bare words are strings)."""
    parsed: dict[str, Any] = {}
    for item in options:
        key, sep, value = item.partition("=")
        key = key.strip().replace("-", "_")
        if not sep or not key:
            raise click.UsageError(f"--option {item!r}: expected KEY=VALUE")
        try:
            parsed[key] = tomllib.loads(f"v = {value}")["v"]
        except tomllib.TOMLDecodeError:
            parsed[key] = value
    return parsed


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
    try:
        out = write_gt_trajectories(capture, work, min_visible)
    except (PointtrajError, ImportError) as exc:
        raise click.ClickException(str(exc)) from None
    click.echo(f"wrote {out}")


@click.command("semantics")
@click.argument("work", type=click.Path(file_okay=False, path_type=Path))
@click.option(
    "--recognizer",
    "-r",
    "recognizer_name",
    required=True,
    help="Recogniser name (simulated, precomputed, onnx-segmentation, onnx-detection, "
    "body-parts, object-detector).",
)
@click.option(
    "--capture",
    type=click.Path(exists=True, file_okay=False, path_type=Path),
    help="Capture folder (default: the one recorded in WORK/work.toml).",
)
@click.option(
    "--option",
    "-o",
    "options",
    multiple=True,
    metavar="KEY=VALUE",
    help="Recogniser option, e.g. -o noise=high or -o directory=maps (repeatable).",
)
@click.option(
    "--pooling",
    "poolings",
    multiple=True,
    help="Pooling method(s); the first is the map's default [default: view, average].",
)
@click.option("--eps-e", type=float, default=None, help="Visibility threshold ε_e [default: 0.1].")
@click.option(
    "--background-vote",
    type=float,
    default=None,
    help="Pool a point-frame as nothing when at least this fraction of its cameras see no class "
    "there (silhouette consistency; 0.5 suits real recognisers on sparse rigs) [default: 0, off].",
)
@click.option(
    "--from-ground-truth",
    is_flag=True,
    help="If WORK has no trajectories.npz, create it from the capture's gt/ first.",
)
def semantics(
    work: Path,
    recognizer_name: str,
    capture: Path | None,
    options: tuple[str, ...],
    poolings: tuple[str, ...],
    eps_e: float | None,
    background_vote: float | None,
    from_ground_truth: bool,
) -> None:
    """Build WORK/semantic_map.npz: recognise every image, view-pool, average over time."""
    from ..cli_common import cli_errors
    from ..stages import SemanticsStageConfig, semantics_work
    from .semantic_map import SemanticsConfig

    with cli_errors():
        capture = capture or _read_work_capture(work)
        if capture is None:
            raise click.UsageError(f"{work}: no work.toml recording the capture; pass --capture")
        traj_path = work / "trajectories.npz"
        if not traj_path.is_file():
            if not from_ground_truth:
                raise click.ClickException(
                    f"{traj_path}: no such file (reconstruct first, or pass --from-ground-truth "
                    "for a synthetic capture)"
                )
            write_gt_trajectories(capture, work)
        config = SemanticsStageConfig(
            recognizer=recognizer_name,
            options=_parse_options(options),
            poolings=tuple(poolings) or SemanticsConfig().poolings,
            **({"eps_e": eps_e} if eps_e is not None else {}),
            **({"background_vote": background_vote} if background_vote is not None else {}),
        )
        smap = semantics_work(work, config, capture, progress=lambda *a: None)
        out = work / "semantic_map.npz"
    p = smap.poolings[0]
    seen = int((smap.count[p] > 0).sum())
    click.echo(
        f"wrote {out}: {smap.num_trajectories} trajectories ({seen} with a pooled frame), "
        f"{len(smap.class_names)} classes, poolings {', '.join(smap.poolings)}"
    )
