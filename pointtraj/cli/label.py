"""``pointtraj label WORK``: the joint labelling (``labels.npz``, ``labels.csv``, clouds)."""

from __future__ import annotations

from pathlib import Path

import click

__all__ = ["label"]


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
    from ..stages import LabelStageConfig, label_work
    from .common import cli_errors, config_from, progress_bars

    if no_clouds:
        options["write_clouds"] = False
    cfg = config_from(LabelStageConfig, config_path, "label", options)
    with cli_errors(work), progress_bars() as bars:
        res = label_work(work, cfg, progress=bars)
    changed = int((res.labels != res.argmax).sum())
    people = ""
    if res.instance is not None:
        people = (
            f", {int(res.instance.max(initial=-1)) + 1} people "
            f"({int((res.instance >= 0).sum())} trajectories)"
        )
    click.echo(
        f"labelled {len(res)} trajectories ({changed} changed from argmax L3D){people}, energy "
        f"{res.energy[0]:.6g} -> {res.energy[-1]:.6g} -> {work / 'labels.npz'}"
    )
