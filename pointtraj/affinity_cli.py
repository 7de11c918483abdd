"""``pointtraj affinity`` and ``pointtraj label``: the affinity graph and the joint labelling."""

from __future__ import annotations

import logging
from pathlib import Path

import click

from .errors import PointtrajError

__all__ = ["affinity", "label"]

logger = logging.getLogger(__name__)


def _config_from(cls, path: Path | None, table: str, overrides: dict):
    """Build config dataclass ``cls`` from ``[table]`` of a TOML file plus CLI overrides."""
    from .config import from_mapping, load_toml

    data: dict = {}
    if path is not None:
        try:
            doc = load_toml(path)
        except PointtrajError as exc:  # unreadable or invalid TOML: one line, no traceback
            raise click.UsageError(str(exc)) from None
        data = dict(doc.get(table, {}))
    data.update({k: v for k, v in overrides.items() if v is not None})
    try:
        return from_mapping(cls, data, where=f"{path or 'options'} [{table}]")
    except ValueError as exc:
        raise click.UsageError(str(exc)) from None


@click.command("affinity")
@click.argument("work", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--epsilon", type=float, help="ε, radius of the rigid-fit neighbourhood (m).")
@click.option("--epsilon-a", "epsilon_a", type=float, help="ε_a, affinity radius (m).")
@click.option("--tau", type=float, help="τ of A = exp(-(e/τ)^2) (m).")
@click.option("--max-neighbors", type=int, help="Connections drawn per trajectory (drop-out).")
@click.option("--mode", type=click.Choice(["step", "accumulated"]), help="Error definition.")
@click.option("--seed", type=int, help="Seed of the random sampling.")
@click.option(
    "--config",
    "config_path",
    type=click.Path(exists=True, dir_okay=False, path_type=Path),
    help="TOML file with an [affinity] table of AffinityConfig fields (a pipeline file works).",
)
def affinity(work: Path, config_path: Path | None, **options) -> None:
    """Compute WORK/affinity.npz from WORK/trajectories.npz (paper Section 4.2)."""
    from .affinity import AffinityConfig
    from .cli_common import cli_errors, progress_bars
    from .stages import affinity_work

    cfg = _config_from(AffinityConfig, config_path, "affinity", options)
    with cli_errors(work), progress_bars() as bars:
        graph = affinity_work(work, cfg, progress=bars)
    click.echo(
        f"{graph.num_edges} affinity edges over {graph.num_nodes} trajectories "
        f"-> {work / 'affinity.npz'}"
    )


@click.command("label")
@click.argument("work", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--pooling", help="Which L3D of semantic_map.npz to use [default: view].")
@click.option("--lambda", "smoothness", type=float, help="λ, weight of the affinity term.")
@click.option("--data-cost", type=click.Choice(["neglog", "paper"]), help="Data cost.")
@click.option(
    "--method", type=click.Choice(["restricted", "full"]), help="Expansion moves [restricted]."
)
@click.option("--no-clouds", is_flag=True, help="Do not rewrite WORK/clouds/*.ply.")
@click.option(
    "--config",
    "config_path",
    type=click.Path(exists=True, dir_okay=False, path_type=Path),
    help="TOML file with a [label] table of LabelingConfig fields (a pipeline file works).",
)
def label(work: Path, no_clouds: bool, config_path: Path | None, **options) -> None:
    """Label every trajectory by alpha-expansion: WORK/labels.npz, labels.csv, clouds/*.ply."""
    from .cli_common import cli_errors, progress_bars
    from .stages import LabelStageConfig, label_work

    if no_clouds:
        options["write_clouds"] = False
    cfg = _config_from(LabelStageConfig, config_path, "label", options)
    with cli_errors(work), progress_bars() as bars:
        res = label_work(work, cfg, progress=bars)
    changed = int((res.labels != res.argmax).sum())
    click.echo(
        f"labelled {len(res)} trajectories ({changed} changed from argmax L3D), energy "
        f"{res.energy[0]:.6g} -> {res.energy[-1]:.6g} -> {work / 'labels.npz'}"
    )
