"""What every ``pointtraj`` command shares: config loading, one-line errors and progress bars.

Library code reports progress through a ``progress(label, done, total)`` callable and raises
:class:`~pointtraj.errors.PointtrajError`; the commands turn both into what a terminal user
expects with :func:`cli_errors` and :class:`ProgressBars`. A command's ``--config`` TOML table
plus its options become the stage's typed config through :func:`config_from`.

The root group (:mod:`pointtraj.cli`) runs every command inside :func:`cli_errors`, so a
command needs it only to name a default path for OS errors without a file name.
"""

from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import click

from ..errors import PointtrajError, os_error_message

if TYPE_CHECKING:
    from ..executor import Executor, ExecutorConfig

__all__ = [
    "ProgressBars",
    "cli_errors",
    "config_from",
    "executor_config",
    "executor_options",
    "open_cli_executor",
    "progress_bars",
]

T = TypeVar("T")
F = TypeVar("F")


def config_from(
    cls: type[T],
    path: Path | None,
    table: str,
    overrides: Mapping[str, Any] | None = None,
    required: Mapping[str, str] | None = None,
) -> T:
    """Config dataclass ``cls`` from table ``[table]`` of a TOML file plus command-line options.

    Parameters
    ----------
    cls : type
        A config dataclass (:func:`pointtraj.config.from_mapping` builds it).
    path : pathlib.Path or None
        The ``--config`` file (a pipeline file works); None: options and defaults only.
    table : str
        The table read from it (a missing table is empty).
    overrides : mapping, optional
        Option name -> value; None values (options not given) are left out.
    required : mapping, optional
        Key -> the option that gives it: keys that the file's table or the options must set
        (their defaults are no choice for the user to leave to the command).

    Returns
    -------
    cls

    Raises
    ------
    click.UsageError
        If the file is unreadable or invalid TOML, a key or value is wrong, or a ``required``
        key is set by neither (one line).
    """
    from ..config import from_mapping, load_toml

    data: dict[str, Any] = {}
    if path is not None:
        try:
            doc = load_toml(path)
        except PointtrajError as exc:  # unreadable or invalid TOML: one line, no traceback
            raise click.UsageError(str(exc)) from None
        section = doc.get(table, {})
        if not isinstance(section, dict):
            raise click.UsageError(f"{path}: [{table}] must be a table, got {section!r}")
        data = dict(section)
    data.update({k: v for k, v in (overrides or {}).items() if v is not None})
    for key, option in (required or {}).items():
        if key not in data:
            where = f"{path} has no [{table}] {key}" if path is not None else "no --config"
            raise click.UsageError(f"give the {key} with {option} ({where})")
    try:
        return from_mapping(cls, data, where=f"{path or 'options'} [{table}]")
    except ValueError as exc:
        raise click.UsageError(str(exc)) from None


class ProgressBars:
    """A ``progress(label, done, total)`` callable that shows one click progress bar per step.

    A new label closes the previous bar and opens a new one; :meth:`close` ends the last.
    """

    def __init__(self) -> None:
        self._bar = None
        self._label: str | None = None
        self._done = 0

    def __call__(self, label: str, done: int, total: int) -> None:
        if label != self._label or self._bar is None:
            self.close()
            self._bar = click.progressbar(
                length=max(int(total), 1), label=f"  {label}", show_pos=True, file=sys.stderr
            )
            self._bar.__enter__()
            self._label, self._done = label, 0
        step = int(done) - self._done
        if step > 0:
            self._bar.update(step)
            self._done = int(done)

    def close(self) -> None:
        """Finish the bar on screen, if any."""
        if self._bar is not None:
            self._bar.__exit__(None, None, None)
        self._bar, self._label = None, None


@contextlib.contextmanager
def progress_bars() -> Iterator[ProgressBars]:
    """A :class:`ProgressBars` closed on exit."""
    bars = ProgressBars()
    try:
        yield bars
    finally:
        bars.close()


@contextlib.contextmanager
def cli_errors(default_path: str | os.PathLike = ".") -> Iterator[None]:
    """Turn pointtraj's errors and OS errors into one-line click errors (exit code 1).

    ``default_path`` is named for an OS error that carries no file name."""
    try:
        yield
    except PointtrajError as exc:
        raise click.ClickException(str(exc)) from None
    except OSError as exc:
        raise click.ClickException(os_error_message(exc, default_path)) from None


def executor_options(command: F) -> F:
    """Add ``--workers`` and ``--scheduler`` (where the stage's tasks run) to a command."""
    command = click.option(
        "--scheduler",
        metavar="ADDRESS",
        default=None,
        envvar="POINTTRAJ_SCHEDULER",
        show_envvar=True,
        help="Run the tasks on the Dask cluster of this scheduler (tcp://host:8786); the "
        "capture and the work folder must be on a path that every worker shares.",
    )(command)
    return click.option(
        "--workers",
        type=click.IntRange(0),
        default=None,
        envvar="POINTTRAJ_WORKERS",
        show_envvar=True,
        help="Worker processes of the local Dask cluster (1: serial in this process; 0: one per "
        "core, serial on one core) [default: 0, or the pipeline file's [executor]].",
    )(command)


def executor_config(
    workers: int | None, scheduler: str | None, base: ExecutorConfig | None = None
) -> ExecutorConfig:
    """``base`` (default: the defaults) with ``--workers`` / ``--scheduler`` where given.

    Raises
    ------
    click.UsageError
        On a bad value (one line).
    """
    import dataclasses

    from ..executor import ExecutorConfig

    changes: dict[str, Any] = {}
    if workers is not None:
        changes["workers"] = workers
        changes["address"] = ""  # --workers means this machine
    if scheduler is not None:
        changes["address"] = scheduler
    try:
        return dataclasses.replace(base or ExecutorConfig(), **changes)
    except ValueError as exc:
        raise click.UsageError(str(exc)) from None


@contextlib.contextmanager
def open_cli_executor(config: ExecutorConfig) -> Iterator[Executor]:
    """An executor opened when the command first has tasks for it (a command that fails before
    starts no cluster); where it runs, and the Dask dashboard's link, are shown on stderr."""
    from ..executor import LazyExecutor

    def on_open(executor: Executor) -> None:
        click.echo(f"executor: {executor.description}", err=True)

    with LazyExecutor(config, on_open) as executor:
        yield executor
