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

A task is a module-level function and its arguments (so that it pickles); what every task of a
map shares (a trajectory store, a rig, settings) goes once to each worker as the ``context`` of
:meth:`Executor.map`, and what is costly to make (a recogniser's model, an offscreen renderer) is
made once per worker process by :func:`worker_cache`. Tasks read their
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
import threading
import warnings
from collections import OrderedDict, deque
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from typing import Any, Protocol, TypeVar

from .errors import PointtrajError, ValidationError

__all__ = [
    "DaskExecutor",
    "Executor",
    "ExecutorConfig",
    "LazyExecutor",
    "SerialExecutor",
    "keep_arrays_on_heap",
    "open_executor",
    "trim_heap",
    "usable_cores",
    "worker_cache",
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
    wait_workers : float
        Seconds to wait for the scheduler at ``address`` to answer, and then to have a worker.
    """

    address: str = ""
    workers: int = 0
    threads_per_worker: int = 1
    memory_limit: str = "auto"
    dashboard: bool = True
    wait_workers: float = 60.0

    def __post_init__(self) -> None:
        if self.workers < 0:
            raise ValidationError(f"executor workers must be >= 0, got {self.workers}")
        if self.threads_per_worker < 1:
            raise ValidationError(
                f"executor threads_per_worker must be >= 1, got {self.threads_per_worker}"
            )
        if not self.wait_workers > 0:
            raise ValidationError(f"executor wait_workers must be > 0, got {self.wait_workers}")
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

    @property
    def local(self) -> bool:
        """Whether tasks run in this process (their arguments are then not pickled)."""
        return True

    def map(
        self,
        fn: Callable[..., R],
        items: Iterable[Any],
        *,
        label: str = "",
        progress: Progress | None = None,
        total: int | None = None,
        max_pending: int | None = None,
        context: Any = None,
    ) -> Iterator[R]:
        """``fn(item)`` (or ``fn(context, item)``) for each item, in the order of ``items``.

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
        context : object, optional
            Given, each task is ``fn(context, item)``: the context is sent once to each worker
            (not with every task) and must not be changed by the tasks.

        Yields
        ------
        object
            Each task's result.
        """
        raise NotImplementedError

    @property
    def description(self) -> str:
        """What this executor is, in words (with the dashboard's link where there is one)."""
        return "serial, in this process"

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

    def map(
        self, fn, items, *, label="", progress=None, total=None, max_pending=None, context=None
    ):
        items, total = _count(items, total)
        for done, item in enumerate(items, 1):
            result = fn(item) if context is None else fn(context, item)
            if progress is not None:
                progress(label, done, total or done)
            yield result

    def __repr__(self) -> str:
        return "SerialExecutor()"


class DaskExecutor(Executor):
    """Runs tasks on a Dask distributed cluster through a ``Client``.

    A task that fails raises its own exception here (a :class:`PointtrajError` with its
    message); a task whose worker dies is run again on another (Dask's ``allowed-failures``).

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

    @property
    def local(self) -> bool:
        return False

    @property
    def description(self) -> str:
        info = self.client.scheduler_info().get("workers", {})
        threads = sum(w.get("nthreads", 1) for w in info.values())
        where = "local Dask cluster" if self.cluster is not None else "Dask cluster at "
        if self.cluster is None:
            where += str(self.client.scheduler.address)
        text = f"{where}, {len(info)} workers, {threads} threads"
        link = self.client.dashboard_link if _has_dashboard(self.client) else ""
        return f"{text}; dashboard {link}" if link else text

    def map(
        self, fn, items, *, label="", progress=None, total=None, max_pending=None, context=None
    ):
        from concurrent.futures import CancelledError

        from distributed import KilledWorker

        items, total = _count(items, total)
        limit = max_pending or 2 * self.workers
        shared = None

        def send_context() -> Any:
            # once to every worker (a worker that joins later fetches it from a peer)
            # (in a list: a tuple or dict context is one object, not one per element)
            [future] = self.client.scatter([context], broadcast=True, hash=False)
            return future

        def submit(item: Any) -> Any:
            # pure=False: every call is a new task, even with equal arguments
            args = (item,) if shared is None else (shared, item)
            return self.client.submit(fn, *args, pure=False, key=_key(fn, label))

        if context is not None:
            shared = send_context()
        pending: deque[tuple[Any, Any]] = deque()  # (item, future), in input order
        done = resent = 0
        it = iter(items)
        exhausted = False
        try:
            while True:
                while not exhausted and len(pending) < limit:
                    try:
                        item = next(it)
                    except StopIteration:
                        exhausted = True
                        break
                    pending.append((item, submit(item)))
                if not pending:
                    return
                item, future = pending.popleft()
                try:
                    result = future.result()
                except KilledWorker as exc:
                    raise PointtrajError(
                        f"{label or 'a task'}: every worker that ran one of its tasks died "
                        f"({exc}); out of memory? Give the workers more (--memory-limit of "
                        "`dask worker`, [executor] memory_limit) or run fewer per machine"
                    ) from None
                except CancelledError as exc:
                    # Scattered data is not recomputed: the scheduler cancels the tasks that
                    # need the context when the workers holding it die (its extra copies may
                    # have been dropped by Dask's memory manager). Tasks are idempotent: send
                    # the context again and resubmit this task and the pending ones.
                    if resent >= _MAX_RESENDS:
                        raise PointtrajError(
                            f"{label or 'a task'}: the scheduler cancelled its tasks "
                            f"{resent + 1} times ({exc}); were workers lost, or the run "
                            "cancelled from another client?"
                        ) from None
                    resent += 1
                    logger.warning(
                        "%s: the scheduler cancelled a task (%s), most likely because the "
                        "workers holding its inputs were lost; resubmitting it and the %d "
                        "pending ones",
                        label or "a task",
                        exc,
                        len(pending),
                    )
                    again = [item, *(i for i, _ in pending)]
                    for _, f in pending:
                        f.cancel()
                    if shared is not None:
                        shared.release()
                        shared = send_context()
                    pending = deque((i, submit(i)) for i in again)
                    continue
                finally:
                    future.release()
                done += 1
                if progress is not None:
                    progress(label, done, total or done)
                yield result
        finally:
            for _, f in pending:  # an error, or the caller stopped early
                f.cancel()
            if shared is not None:
                shared.release()

    def close(self) -> None:
        self.client.close()
        if self.cluster is not None:
            self.cluster.close()

    def __repr__(self) -> str:
        return f"DaskExecutor({self.client.scheduler.address}, {self.workers} workers)"


class LazyExecutor(Executor):
    """The executor of a configuration, opened when first asked for work (then kept).

    A pipeline whose stages are up to date, or that fails before its first task, starts no
    cluster.

    Parameters
    ----------
    config : ExecutorConfig
    on_open : callable, optional
        Called with the executor once it is open.
    """

    def __init__(
        self, config: ExecutorConfig, on_open: Callable[[Executor], None] | None = None
    ) -> None:
        self.config = config
        self.on_open = on_open
        self._executor: Executor | None = None

    @property
    def executor(self) -> Executor:
        """The open executor (opened now if it is not yet)."""
        if self._executor is None:
            self._executor = open_executor(self.config)
            if self.on_open is not None:
                self.on_open(self._executor)
        return self._executor

    @property
    def workers(self) -> int:  # type: ignore[override]
        return self.executor.workers

    @property
    def local(self) -> bool:
        return self.executor.local

    @property
    def description(self) -> str:
        return self.executor.description

    def map(self, fn, items, **kwargs):
        return self.executor.map(fn, items, **kwargs)

    def close(self) -> None:
        if self._executor is not None:
            self._executor.close()
            self._executor = None

    def __repr__(self) -> str:
        return f"LazyExecutor({self._executor or self.config!r})"


#: Times a map sends its tasks again after the scheduler cancelled them (lost inputs).
_MAX_RESENDS = 3


def _key(fn: Callable[..., Any], label: str) -> str:
    """A task key that the dashboard shows as the task's name (unique per task)."""
    import uuid

    name = getattr(fn, "__name__", None) or getattr(getattr(fn, "func", None), "__name__", "task")
    return f"{label or name}-{uuid.uuid4().hex}".replace(" ", "_")


def _has_dashboard(client: Any) -> bool:
    try:
        return bool(client.scheduler_info().get("services", {}).get("dashboard"))
    except Exception:  # a scheduler that does not say: no link
        return False


_CACHE: OrderedDict[Any, Any] = OrderedDict()
_CACHE_LOCK = threading.Lock()
_CACHE_SIZE = 4


def worker_cache(key: Any, make: Callable[[], R]) -> R:
    """``make()``, made once per process and key, for what a task would be slow to remake.

    A recogniser's model, an offscreen renderer or a synthetic scene is made on a worker's
    first task and reused by its later tasks (the process's last few keys are kept).

    Parameters
    ----------
    key : hashable
        What determines the object (its settings).
    make : callable
        Makes it.

    Returns
    -------
    object
    """
    with _CACHE_LOCK:
        if key in _CACHE:
            _CACHE.move_to_end(key)
            return _CACHE[key]
    value = make()
    with _CACHE_LOCK:
        _CACHE[key] = value
        while len(_CACHE) > _CACHE_SIZE:
            _CACHE.popitem(last=False)
    return value


def _one_thread_opencv(worker: Any) -> None:
    """OpenCV on one thread in a one-thread worker (the worker process is the core)."""
    if getattr(worker, "state", worker).nthreads == 1:
        import cv2

        cv2.setNumThreads(1)


#: glibc's ``mallopt`` parameters (``malloc.h``).
_M_TRIM_THRESHOLD, _M_MMAP_MAX, _M_ARENA_MAX = -1, -4, -8
#: Free memory at the top of the heap that glibc keeps for the next large array rather than
#: giving it back to the OS: a few of paper69's largest per-frame temporaries.
HEAP_TRIM_THRESHOLD = 1 << 30


def keep_arrays_on_heap() -> bool:
    """Large numpy arrays from glibc's heap, reused, rather than mapped afresh each time.

    glibc maps every allocation above its mmap threshold (at most 32 MiB, lower under Dask's
    ``MALLOC_TRIM_THRESHOLD_``) with its own ``mmap`` and unmaps it when freed, so the kernel
    zeroes and faults in every page of each such temporary again. The tracker's (C, N) arrays
    are far above it (69 cameras x 75,000 points: 41 MB a float64 array). This turns mapping
    off (``M_MMAP_MAX = 0``: glibc still maps where the heap cannot grow) and keeps up to
    :data:`HEAP_TRIM_THRESHOLD` of free memory at the heap's top. Threads started later
    allocate from the same heap (``M_ARENA_MAX = 1``): a Dask worker runs its tasks in a
    thread, and a thread's own arena holds at most 64 MiB, above which glibc maps anyway. On
    paper69 frames 0-5 the kernel's share fell from 34.5 to 7.6 CPU-s and the page faults from
    1.0 M to 0.19 M, for a peak RSS of 2.50 against 2.54 GB (``docs/reconstruction.md``,
    "Large arrays from the heap, projections in blocks").

    It is process-wide: the command line sets it at start, and so does every Dask worker
    (the executor's worker plugin), which also undoes the ``MALLOC_TRIM_THRESHOLD_`` that a
    Dask nanny gives its worker. In a process where another thread has allocated already,
    glibc no longer reads the arena limit: local clusters start their workers with
    ``MALLOC_ARENA_MAX=1`` in the environment, and workers started by hand need it there too
    (``docs/scaling.md``), or arrays above 64 MiB in their tasks are still mapped. A program
    that calls the library may call this once. The heap keeps what it frees, so the process's
    resident memory stays near its peak; a worker gives it back after a task when it is above
    :data:`WORKER_TRIM_SHARE` of its memory limit.

    Returns
    -------
    bool
        Whether it was set: False where the C library has no ``mallopt`` (not glibc).
    """
    import ctypes

    mallopt = _glibc("mallopt", [ctypes.c_int, ctypes.c_int])
    if mallopt is None:
        return False
    done = [mallopt(_M_ARENA_MAX, 1), mallopt(_M_MMAP_MAX, 0)]
    return mallopt(_M_TRIM_THRESHOLD, HEAP_TRIM_THRESHOLD) == 1 and all(d == 1 for d in done)


#: A worker gives its free heap memory back to the OS after a task when its resident memory is
#: above this share of its Dask memory limit (Dask pauses a worker at 0.8 of it by default,
#: and a heap that keeps what it freed would otherwise stay there).
WORKER_TRIM_SHARE = 0.5


def trim_heap() -> bool:
    """Give the heap's free memory back to the OS (glibc's ``malloc_trim(0)``).

    Returns
    -------
    bool
        Whether any memory was released; False where the C library is not glibc.
    """
    import ctypes

    malloc_trim = _glibc("malloc_trim", [ctypes.c_size_t])
    return malloc_trim is not None and malloc_trim(0) == 1


def _glibc(name: str, argtypes: list) -> Callable[..., int] | None:
    """glibc's function ``name`` (returning an int) through ctypes; None elsewhere."""
    import ctypes
    import ctypes.util
    import platform

    if platform.libc_ver()[0] != "glibc":
        return None
    try:
        fn = getattr(ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6"), name)
    except (OSError, AttributeError):
        return None
    fn.argtypes, fn.restype = argtypes, ctypes.c_int
    return fn


def _trim_if_high(worker: Any) -> None:
    """:func:`trim_heap` on a Dask worker whose resident memory is above
    :data:`WORKER_TRIM_SHARE` of its memory limit (nothing without a limit)."""
    limit = getattr(getattr(worker, "memory_manager", None), "memory_limit", None)
    if not limit:
        return
    import psutil

    if psutil.Process().memory_info().rss > WORKER_TRIM_SHARE * limit:
        trim_heap()


def _worker_setup_plugin() -> Any:
    """A Dask worker plugin running :func:`_one_thread_opencv` and :func:`keep_arrays_on_heap`
    on every worker, also later ones, and :func:`_trim_if_high` after each task."""
    from distributed.diagnostics.plugin import WorkerPlugin

    class PointtrajWorkerSetup(WorkerPlugin):
        name = "pointtraj-worker-setup"
        idempotent = True

        def setup(self, worker: Any) -> None:
            self.worker = worker
            _one_thread_opencv(worker)
            if keep_arrays_on_heap():
                logger.info("worker %s: large arrays from glibc's heap", worker.address)
                if os.environ.get("MALLOC_ARENA_MAX") != "1":
                    logger.info(
                        "worker %s: without MALLOC_ARENA_MAX=1 in its environment, the tasks' "
                        "arrays above 64 MiB are still mapped afresh (docs/scaling.md)",
                        worker.address,
                    )

        def transition(self, key: Any, start: str, finish: str, **kwargs: Any) -> None:
            if start == "executing":  # a task ended: its freed memory stays on the heap
                _trim_if_high(self.worker)

    return PointtrajWorkerSetup()


_SPAWN_ENVIRON = "distributed.nanny.pre-spawn-environ"


def _worker_environ() -> dict[str, Any]:
    """Dask's environment for new worker processes, without ``MALLOC_TRIM_THRESHOLD_``.

    Dask sets it to 64 KiB to give memory back to the OS sooner; glibc then maps and unmaps
    every large numpy temporary afresh, and the stages' vectorised steps took twice the CPU
    (semantics on paper69: 3.2 CPU-s a frame on a worker against 1.3 serially; 1.5 without
    it). The thread limits (``OMP_NUM_THREADS=1``, ...) stay. ``MALLOC_ARENA_MAX=1`` is
    added: the tasks run in a thread, and glibc reads the arena limit only before a
    process's second thread allocates, so :func:`keep_arrays_on_heap` cannot set it in a
    running worker.
    """
    import dask

    environ = dict(dask.config.get(_SPAWN_ENVIRON, default={}) or {})
    environ.pop("MALLOC_TRIM_THRESHOLD_", None)
    environ["MALLOC_ARENA_MAX"] = "1"  # see keep_arrays_on_heap
    return environ


def _dask_log_level() -> int:
    """Dask's log level: warnings, or its INFO when pointtraj's own INFO is on (``-v``)."""
    return (
        logging.INFO
        if logging.getLogger("pointtraj").getEffectiveLevel() <= logging.INFO
        else (logging.WARNING)
    )


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
        If the scheduler at ``config.address`` cannot be reached, or has no workers within
        ``config.wait_workers`` seconds.
    """
    config = config or ExecutorConfig()
    if config.serial:
        logger.info("executor: serial, in this process")
        return SerialExecutor()
    from distributed import Client, LocalCluster

    for name in ("distributed", "bokeh", "tornado"):
        logging.getLogger(name).setLevel(_dask_log_level())
    if config.address:
        try:
            client = Client(config.address, timeout=f"{config.wait_workers}s")
        except (OSError, TimeoutError) as exc:
            raise PointtrajError(
                f"cannot reach the Dask scheduler at {config.address} ({exc}); start one with "
                "`dask scheduler` and workers with `dask worker ADDRESS` (docs/scaling.md)"
            ) from None
        try:
            client.wait_for_workers(1, timeout=config.wait_workers)
        except TimeoutError:
            client.close()
            raise PointtrajError(
                f"the Dask scheduler at {config.address} has no workers after "
                f"{config.wait_workers:g} s; start some with `dask worker {config.address}`"
            ) from None
        executor = DaskExecutor(client)
    else:
        import dask

        workers = config.workers or usable_cores()
        with dask.config.set({_SPAWN_ENVIRON: _worker_environ()}), warnings.catch_warnings():
            # without a dashboard the scheduler's small HTTP server takes any free port
            warnings.filterwarnings("ignore", message="Port .* is already in use")
            cluster = LocalCluster(
                n_workers=workers,
                threads_per_worker=config.threads_per_worker,
                processes=True,
                memory_limit=config.memory_limit,
                dashboard_address=":0" if config.dashboard else None,
                silence_logs=_dask_log_level(),
            )
        executor = DaskExecutor(Client(cluster), cluster)
    executor.client.register_plugin(_worker_setup_plugin())
    logger.info("executor: %s", executor.description)
    return executor
