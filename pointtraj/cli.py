"""The ``pointtraj`` command: a click group with one subcommand per stage.

Subcommands live beside the library code they call (``pointtraj/<stage>/cli.py`` or
``pointtraj/<module>_cli.py``) and are imported only when invoked, so ``pointtraj --help`` stays
fast. Register a new one in :data:`COMMANDS`.
"""

from __future__ import annotations

import importlib
import logging

import click

from . import __version__

__all__ = ["main", "COMMANDS"]

#: Subcommand name -> "module:attribute" of its click command.
COMMANDS: dict[str, str] = {
    "rig": "pointtraj.rig_cli:rig",
    "synth": "pointtraj.synth.cli:synth",
    "affinity": "pointtraj.affinity_cli:affinity",
    "label": "pointtraj.affinity_cli:label",
    "demo": "pointtraj.pipeline_cli:demo",
    "run": "pointtraj.pipeline_cli:run",
    "semantics": "pointtraj.semantics.cli:semantics",
    "gt-trajectories": "pointtraj.semantics.cli:gt_trajectories",
    "models": "pointtraj.models_cli:models",
    "reconstruct": "pointtraj.reconstruct.cli:reconstruct",
    "calibrate": "pointtraj.calibrate_cli:calibrate",
    "examples": "pointtraj.examples_cli:examples",
    "render": "pointtraj.render_cli:render",
    "evaluate": "pointtraj.evaluate.cli:evaluate",
}


class LazyGroup(click.Group):
    """A click group whose subcommands are imported on first use."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted(set(super().list_commands(ctx)) | set(COMMANDS))

    def invoke(self, ctx: click.Context):
        """Run the subcommand; an error of pointtraj's or of the OS that it let through still
        reaches the user as one line (:func:`pointtraj.cli_common.cli_errors`)."""
        from .cli_common import cli_errors

        with cli_errors():
            return super().invoke(ctx)

    def get_command(self, ctx: click.Context, name: str) -> click.Command | None:
        if name in COMMANDS:
            module, attr = COMMANDS[name].split(":")
            return getattr(importlib.import_module(module), attr)
        return super().get_command(ctx, name)


@click.group(cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="pointtraj")
@click.option("-v", "--verbose", count=True, help="More log output (-v info, -vv debug).")
def main(verbose: int) -> None:
    """Dense 3D semantic trajectories from synchronised multi-camera video."""
    level = logging.WARNING - 10 * min(verbose, 2)
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
    logging.getLogger("pointtraj").setLevel(level)
