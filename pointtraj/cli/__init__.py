"""The ``pointtraj`` command: a click group with one subcommand per stage.

Each subcommand is a module of this package (``pointtraj/cli/<group>.py``), imported only when
invoked so that ``pointtraj --help`` stays fast; what they share is in :mod:`pointtraj.cli.common`.
Register a new one in :data:`COMMANDS`.
"""

from __future__ import annotations

import importlib
import logging

import click

from .. import __version__

__all__ = ["main", "COMMANDS"]

#: Subcommand name -> "module:attribute" of its click command.
COMMANDS: dict[str, str] = {
    "rig": "pointtraj.cli.rig:rig",
    "synth": "pointtraj.cli.synth:synth",
    "affinity": "pointtraj.cli.affinity:affinity",
    "label": "pointtraj.cli.label:label",
    "demo": "pointtraj.cli.pipeline:demo",
    "run": "pointtraj.cli.pipeline:run",
    "semantics": "pointtraj.cli.semantics:semantics",
    "gt-trajectories": "pointtraj.cli.reconstruct:gt_trajectories",
    "models": "pointtraj.cli.models:models",
    "reconstruct": "pointtraj.cli.reconstruct:reconstruct",
    "calibrate": "pointtraj.cli.calibrate:calibrate",
    "examples": "pointtraj.cli.examples:examples",
    "render": "pointtraj.cli.render:render",
    "evaluate": "pointtraj.cli.evaluate:evaluate",
    "export": "pointtraj.cli.export:export",
    "capture": "pointtraj.cli.capture:capture",
    "segments": "pointtraj.cli.segments:segments",
}


class LazyGroup(click.Group):
    """A click group whose subcommands are imported on first use."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted(set(super().list_commands(ctx)) | set(COMMANDS))

    def invoke(self, ctx: click.Context):
        """Run the subcommand; an error of pointtraj's or of the OS that it let through still
        reaches the user as one line (:func:`pointtraj.cli.common.cli_errors`)."""
        from .common import cli_errors

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
    before = set(logging.getLogger().handlers)
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
    logging.getLogger("pointtraj").setLevel(level)
    for handler in set(logging.getLogger().handlers) - before:  # the console's, not a host's
        handler.addFilter(_not_health_warning)
    from ..executor import keep_arrays_on_heap

    keep_arrays_on_heap()  # as every worker: large temporaries reused (docs/scaling.md)


def _not_health_warning(record: logging.LogRecord) -> bool:
    """Drop the report's health warnings from the console log: the commands that run the
    evaluation (``run``, ``demo``, ``evaluate``) list them at the end, where they are read."""
    return not getattr(record, "health_warning", False)
