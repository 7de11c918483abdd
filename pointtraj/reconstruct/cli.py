"""``pointtraj reconstruct CAPTURE --out WORK``: dense 3D trajectories from a capture."""

from __future__ import annotations

import logging
import sys
import tomllib
from pathlib import Path

import click

from ..errors import PointtrajError, os_error_message
from ..workdir import parse_frames

__all__ = ["reconstruct", "parse_frames", "load_reconstruct_config"]

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


def _work_toml(capture_path: Path, frames: range, config) -> str:
    from ..config import to_mapping

    lines = [
        "# pointtraj work folder (see data_specs/work_folder.md)",
        f'capture = "{_toml_escape(str(capture_path))}"',
        "",
        "[reconstruct_run]",
        f"frames = [{frames.start}, {frames.stop}]",
        "",
    ]
    lines += _toml_tables("reconstruct", to_mapping(config))
    return "\n".join(lines) + "\n"


def _toml_escape(s: str) -> str:
    return s.replace("\\", "\\\\").replace('"', '\\"')


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int | float):
        return repr(v)
    if isinstance(v, str):
        return f'"{_toml_escape(v)}"'
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {v!r} to TOML")


def _toml_tables(name: str, mapping: dict) -> list[str]:
    lines = [f"[{name}]"]
    subs = []
    for k, v in mapping.items():
        if isinstance(v, dict):
            subs.append((k, v))
        else:
            lines.append(f"{k} = {_toml_value(v)}")
    lines.append("")
    for k, v in subs:
        lines += _toml_tables(f"{name}.{k}", v)
    return lines


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
@click.option("--restart", is_flag=True, help="Ignore and overwrite a previous run's state.")
def reconstruct(
    capture: Path, work: Path, frames: str | None, config_path: Path | None, restart: bool
) -> None:
    """Reconstruct dense 3D trajectories of CAPTURE into the work folder --out.

    Writes WORK/work.toml, WORK/clouds/<frame>.ply per frame, WORK/state/ (resume points) and
    WORK/trajectories.npz.
    """
    import shutil

    from ..atomic import write_text_atomic
    from ..session import Capture
    from .track import reconstruct_capture

    try:
        cfg = load_reconstruct_config(config_path)
        cap = Capture.open(capture)
        rng = parse_frames(frames, int(cap.num_frames), where="--frames")
        text = _work_toml(capture.resolve(), rng, cfg)
        toml_path = work / "work.toml"
        if toml_path.is_file() and (work / "state").is_dir() and not restart:
            old = toml_path.read_text(encoding="utf-8")
            if _run_identity(old) != _run_identity(text):
                raise click.ClickException(
                    f"{work} holds a run with another capture, frames or parameters; "
                    "use --restart to overwrite it or another --out"
                )
        if restart:
            for sub in ("state", "clouds"):
                if (work / sub).is_dir():
                    shutil.rmtree(work / sub)
        work.mkdir(parents=True, exist_ok=True)
        write_text_atomic(toml_path, text)
        with click.progressbar(
            length=len(rng), label="reconstruct", show_pos=True, file=sys.stderr
        ) as bar:
            traj = reconstruct_capture(cap, work, rng, cfg, on_frame=lambda rec: bar.update(1))
    except PointtrajError as exc:
        raise click.ClickException(str(exc)) from None
    except OSError as exc:
        raise click.ClickException(os_error_message(exc, work)) from None
    lengths = traj.lengths
    click.echo(
        f"{traj.num_trajectories} trajectories, {traj.num_point_frames} point-frames over "
        f"{len(rng)} frames (median length {float(_median(lengths)):.0f}) -> {work}"
    )


def _median(a) -> float:
    import numpy as np

    return float(np.median(a)) if len(a) else 0.0


def _run_identity(text: str) -> dict:
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError:
        return {}
    return {k: data.get(k) for k in ("capture", "reconstruct_run", "reconstruct")}
