"""``pointtraj affinity WORK``: the affinity graph (``WORK/affinity.npz``)."""

from __future__ import annotations

from pathlib import Path

import click

from .common import executor_options

__all__ = ["affinity"]


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
@executor_options
def affinity(
    work: Path, config_path: Path | None, workers: int | None, scheduler: str | None, **options
) -> None:
    """Compute WORK/affinity.npz from WORK/trajectories.npz (paper Section 4.2)."""
    from ..affinity import AffinityConfig
    from ..stages import affinity_work
    from .common import cli_errors, config_from, executor_config, open_cli_executor, progress_bars

    cfg = config_from(AffinityConfig, config_path, "affinity", options)
    with (
        cli_errors(work),
        open_cli_executor(executor_config(workers, scheduler)) as ex,
        progress_bars() as bars,
    ):
        graph = affinity_work(work, cfg, progress=bars, executor=ex)
    click.echo(
        f"{graph.num_edges} affinity edges over {graph.num_nodes} trajectories "
        f"-> {work / 'affinity.npz'}"
    )
