"""Where the work runs: in this process, on a local Dask cluster, or on a cluster by address.

Every stage that has independent pieces of work (frames, camera-frames, chunks of
trajectories) hands them to an :class:`Executor` instead of looping over them itself. There are
two kinds, behind one interface:

- :class:`SerialExecutor` runs each task here, in order: for the tests, for debugging (a
  breakpoint or a traceback lands in the task), and on a one-core machine;
- :class:`DaskExecutor` runs them on `Dask distributed <https://distributed.dask.org>`_: an
  embedded ``LocalCluster`` of worker processes, or an existing cluster by its scheduler's
  address (started by hand, by ``dask-jobqueue`` on SLURM/PBS, or on Kubernetes; see
  ``docs/scaling.md``).

A task is a module-level function and its arguments (so that it pickles). Tasks read their
inputs from files and write their outputs atomically (:mod:`pointtraj.atomic`), so a task that
a lost worker leaves half done is simply run again; on a cluster, the capture and the work
folder must be on a path that the client and every worker share. Results come back in the
order of the inputs, whatever the order of completion, so an executor never changes an output.

:func:`open_executor` makes one from an :class:`ExecutorConfig` (table ``[executor]`` of a
pipeline file; ``--workers`` and ``--scheduler`` on the command line).
"""

from __future__ import annotations

import logging
import os
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from typing import Any, Protocol, TypeVar

from .errors import PointtrajError, ValidationError

__all__ = [
    "DaskExecutor",
    "Executor",
    "ExecutorConfig",
    "SerialExecutor",
    "open_executor",
    "usable_cores",
]

logger = logging.getLogger(__name__)

R = TypeVar("R")


class Progress(Protocol):
    def __call__(self, label: str, done: int, total: int) -> None: ...


@dataclass(frozen=True)
class ExecutorConfig:
    """Where stages run (table ``[executor]``).

    Attributes
    ----------
    address : str
        A Dask scheduler's address (``"tcp://host:8786"``): run on that cluster. Empty: on this
        machine.
    workers : int
        Worker processes of the local cluster when ``address`` is empty. 0 (the default) uses
        every usable core and runs serially where there is only one; 1 runs serially in this
        process (no cluster).
    threads_per_worker : int
        Threads of each local worker (1: the stages' own numpy/OpenCV work is not shared
        between tasks, and each worker process is one core).
    memory_limit : str
        Each local worker's memory limit, as Dask takes it (``"auto"``: the machine's memory
        shared equally, ``"4GiB"``, ``"0"`` for none).
    dashboard : bool
        Serve the Dask dashboard of a local cluster (its link is logged).
    """

    address: str = ""
    workers: int = 0
    threads_per_worker: int = 1
    memory_limit: str = "auto"
    dashboard: bool = True

    def __post_init__(self) -> None:
        if self.workers < 0:
            raise ValidationError(f"executor workers must be >= 0, got {self.workers}")
        if self.threads_per_worker < 1:
            raise ValidationError(
                f"executor threads_per_worker must be >= 1, got {self.threads_per_worker}"
            )
        if self.address and "://" not in self.address:
            raise ValidationError(
                f"executor address {self.address!r} is not a scheduler address "
                "such as 'tcp://host:8786'"
            )

    @property
    def serial(self) -> bool:
        """Whether this configuration runs serially in this process."""
        if self.address:
            return False
        return (self.workers or usable_cores()) <= 1


def usable_cores() -> int:
    """The cores this process may run on (its CPU affinity where the OS reports one)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # macOS, Windows
        return os.cpu_count() or 1


class Executor:
    """Runs independent tasks and gives their results back in input order.

    Attributes
    ----------
    workers : int
        How many tasks can run at once (1 for the serial executor).
    """

    workers: int = 1

    def map(
        self,
        fn: Callable[..., R],
        items: Iterable[Any],
        *,
        label: str = "",
        progress: Progress | None = None,
        total: int | None = None,
        max_pending: int | None = None,
    ) -> Iterator[R]:
        """``fn(item)`` for each item, yielded in the order of ``items``.

        At most ``max_pending`` tasks are submitted and not yet consumed (default: twice the
        workers), so neither the inputs nor the results of a long stage pile up in memory.

        Parameters
        ----------
        fn : callable
            A module-level function (it is pickled to the workers).
        items : iterable
            Its arguments, one per task (use :func:`functools.partial` for fixed ones).
        label : str
            What the tasks do, for ``progress`` and the log.
        progress : callable, optional
            ``progress(label, done, total)`` after each task.
        total : int, optional
            The number of items, when ``items`` has no ``len``.
        max_pending : int, optional

        Yields
        ------
        object
            Each task's result.
        """
        raise NotImplementedError

    def close(self) -> None:
        """Release the workers (a no-op for the serial executor)."""

    def __enter__(self) -> Executor:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _count(items: Iterable[Any], total: int | None) -> tuple[Iterable[Any], int | None]:
    if total is None and hasattr(items, "__len__"):
        total = len(items)  # type: ignore[arg-type]
    return items, total


class SerialExecutor(Executor):
    """Runs each task in this process, in order."""

    workers = 1

    def map(self, fn, items, *, label="", progress=None, total=None, max_pending=None):
        items, total = _count(items, total)
        for done, item in enumerate(items, 1):
            result = fn(item)
            if progress is not None:
                progress(label, done, total or done)
            yield result

    def __repr__(self) -> str:
        return "SerialExecutor()"


class DaskExecutor(Executor):
    """Runs tasks on a Dask distributed cluster through a ``Client``.

    Parameters
    ----------
    client : distributed.Client
    cluster : distributed.LocalCluster, optional
        A cluster this executor started, closed with it.
    """

    def __init__(self, client: Any, cluster: Any = None) -> None:
        self.client = client
        self.cluster = cluster

    @property
    def workers(self) -> int:  # type: ignore[override]
        info = self.client.scheduler_info()
        return max(1, sum(w.get("nthreads", 1) for w in info.get("workers", {}).values()))

    def map(self, fn, items, *, label="", progress=None, total=None, max_pending=None):
        items, total = _count(items, total)
        limit = max_pending or 2 * self.workers
        pending: deque[Any] = deque()
        done = 0
        it = iter(items)
        exhausted = False
        while True:
            while not exhausted and len(pending) < limit:
                try:
                    item = next(it)
                except StopIteration:
                    exhausted = True
                    break
                # pure=False: every call is a new task, even with equal arguments
                pending.append(self.client.submit(fn, item, pure=False))
            if not pending:
                return
            future = pending.popleft()
            try:
                result = future.result()
            except Exception:
                for f in pending:
                    f.cancel()
                raise
            finally:
                future.release()
            done += 1
            if progress is not None:
                progress(label, done, total or done)
            yield result

    def close(self) -> None:
        self.client.close()
        if self.cluster is not None:
            self.cluster.close()

    def __repr__(self) -> str:
        return f"DaskExecutor({self.client.scheduler.address}, {self.workers} workers)"


def open_executor(config: ExecutorConfig | None = None) -> Executor:
    """The executor a configuration asks for (close it, or use it in a ``with`` block).

    Parameters
    ----------
    config : ExecutorConfig, optional
        Default: a local cluster on every usable core, serial on one core.

    Returns
    -------
    Executor

    Raises
    ------
    PointtrajError
        If the scheduler at ``config.address`` cannot be reached.
    """
    config = config or ExecutorConfig()
    if config.serial:
        logger.info("executor: serial, in this process")
        return SerialExecutor()
    from distributed import Client, LocalCluster

    if config.address:
        try:
            client = Client(config.address, timeout="30s")
        except (OSError, TimeoutError) as exc:
            raise PointtrajError(
                f"cannot reach the Dask scheduler at {config.address} ({exc}); start one with "
                "`dask scheduler` and workers with `dask worker ADDRESS` (docs/scaling.md)"
            ) from None
        executor = DaskExecutor(client)
        logger.info(
            "executor: Dask cluster at %s, %d worker threads; dashboard %s",
            config.address,
            executor.workers,
            client.dashboard_link,
        )
        return executor
    workers = config.workers or usable_cores()
    cluster = LocalCluster(
        n_workers=workers,
        threads_per_worker=config.threads_per_worker,
        processes=True,
        memory_limit=config.memory_limit,
        dashboard_address=":0" if config.dashboard else None,
        silence_logs=logging.WARNING,
    )
    client = Client(cluster)
    logger.info(
        "executor: local Dask cluster, %d workers x %d threads%s",
        workers,
        config.threads_per_worker,
        f"; dashboard {client.dashboard_link}" if config.dashboard else "",
    )
    return DaskExecutor(client, cluster)
