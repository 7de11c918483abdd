"""``pointtraj semantics`` (build the 3D semantic map) and ``pointtraj gt-trajectories``."""

from __future__ import annotations

import json
import logging
import tomllib
from pathlib import Path
from typing import Any

import click

from ..errors import PointtrajError, os_error_message

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
    """Write ``WORK/trajectories.npz`` (and ``work.toml``) from a synthetic capture's ground truth.

    Parameters
    ----------
    capture : pathlib.Path
        Synthetic capture folder with ``gt/``.
    work : pathlib.Path
        Work folder (created if needed).
    min_visible : int
        Keep point-frames seen by at least this many cameras.

    Returns
    -------
    pathlib.Path
        The written ``trajectories.npz``.

    Raises
    ------
    PointtrajError
        If the ground truth cannot be read, or ``work.toml`` names another capture.
    """
    from ..atomic import write_text_atomic
    from ..synth.groundtruth import load_ground_truth

    capture = capture.resolve()
    recorded = _read_work_capture(work)
    if recorded is not None and recorded.resolve() != capture:
        raise PointtrajError(f"{work / 'work.toml'}: records capture {recorded}, not {capture}")
    gt = load_ground_truth(capture)
    trajectories = gt.to_trajectories(min_visible=min_visible)
    work.mkdir(parents=True, exist_ok=True)
    out = work / "trajectories.npz"
    trajectories.save(out)
    if recorded is None:
        write_text_atomic(work / "work.toml", f"capture = {json.dumps(str(capture))}\n")
    logger.info("wrote %d ground-truth trajectories to %s", len(trajectories), out)
    return out


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
    from ..labelset import LabelSet
    from ..session import Capture
    from ..trajectories import Trajectories
    from .recognizers import make_recognizer
    from .semantic_map import SemanticsConfig, build_semantic_map

    try:
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
        cap = Capture.open(capture)
        labels = LabelSet.load(cap.labels_path) if cap.labels_path else LabelSet.default()
        if cap.labels_path is None:
            logger.warning("%s has no labels.toml; using the default label set", capture)
        kwargs = _parse_options(options)
        if recognizer_name in ("simulated",):
            kwargs.setdefault("capture", str(Path(capture).resolve()))
        try:
            recognizer = make_recognizer(recognizer_name, labels, **kwargs)
        except TypeError as exc:  # an option the recogniser does not take
            raise click.UsageError(f"--recognizer {recognizer_name}: {exc}") from None
        trajectories = Trajectories.load(traj_path)
        trajectories.check_cameras(cap, traj_path)
        config = SemanticsConfig(
            **({"poolings": tuple(poolings)} if poolings else {}),
            **({"eps_e": eps_e} if eps_e is not None else {}),
            **({"background_vote": background_vote} if background_vote is not None else {}),
        )
        smap = build_semantic_map(cap, trajectories, recognizer, config=config, progress=True)
        out = work / "semantic_map.npz"
        smap.save(out)
    except PointtrajError as exc:
        raise click.ClickException(str(exc)) from None
    except OSError as exc:  # a read-only or full disk: name the file
        raise click.ClickException(os_error_message(exc, work)) from None
    p = smap.poolings[0]
    seen = int((smap.count[p] > 0).sum())
    click.echo(
        f"wrote {out}: {smap.num_trajectories} trajectories ({seen} with a pooled frame), "
        f"{len(smap.class_names)} classes, poolings {', '.join(smap.poolings)}"
    )
