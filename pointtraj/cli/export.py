"""``pointtraj export FORMAT WORK``: a finished work folder in another tool's format."""

from __future__ import annotations

import click

__all__ = ["export"]


@click.group("export")
def export() -> None:
    """Write a finished work folder in another tool's format (one subcommand per format)."""
