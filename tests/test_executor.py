"""Where stages run: the ``[executor]`` table, and the stages on real Dask clusters.

The cluster tests compare every output with the serial run of the same tiny pipeline
(``tiny_reference``): an executor must never change what a stage writes. One starts a
``LocalCluster`` of two worker processes; the others start ``dask scheduler`` and two
``dask worker`` commands as separate processes, as a user does on a cluster, and kill one
worker in the middle of a run.
"""

from __future__ import annotations

import dataclasses
import os
import platform
import shutil
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from pointtraj.cli import main
from pointtraj.errors import FileFormatError, PointtrajError, ValidationError
from pointtraj.executor import ExecutorConfig, SerialExecutor, open_executor
from pointtraj.pipeline import load_pipeline, run_pipeline
from pointtraj.stages import affinity_work, semantics_work, synthesize

ROOT = Path(__file__).resolve().parents[1]

#: The arrays of these stage outputs must be equal, NaN for NaN.
NPZ_OUTPUTS = ("trajectories.npz", "semantic_map.npz", "affinity.npz", "labels.npz")


def _assert_same_npz(a: Path, b: Path) -> None:
    with np.load(a) as za, np.load(b) as zb:
        assert sorted(za.files) == sorted(zb.files), a.name
        for key in za.files:
            x, y = za[key], zb[key]
            nan = x.dtype.kind in "fc"
            assert np.array_equal(x, y, equal_nan=nan), f"{a.name}: {key} differs"


def _assert_same_files(a: Path, b: Path, pattern: str) -> None:
    names = sorted(p.relative_to(a) for p in a.glob(pattern) if not p.name.startswith("."))
    assert names, f"no {pattern} under {a}"
    assert names == sorted(p.relative_to(b) for p in b.glob(pattern) if not p.name.startswith("."))
    for name in names:
        assert (a / name).read_bytes() == (b / name).read_bytes(), f"{name} differs"


def _assert_same_run(reference: Path, root: Path) -> None:
    """The capture and every stage output of ``root`` are those of the serial ``reference``."""
    for name in NPZ_OUTPUTS:
        _assert_same_npz(reference / "work" / name, root / "work" / name)
    _assert_same_files(reference / "cap", root / "cap", "frames/*/*.jpg")
    _assert_same_files(reference / "cap", root / "cap", "gt/**/*.npz")
    _assert_same_files(reference / "work", root / "work", "renders/**/*.png")
    _assert_same_files(reference / "work", root / "work", "renders/**/*.mp4")


def _fresh_copy(reference: Path, dest: Path) -> Path:
    """``dest`` with the reference's pipeline file only (everything is made anew)."""
    dest.mkdir()
    shutil.copy(reference / "pipe.toml", dest / "pipe.toml")
    return dest / "pipe.toml"


# -- configuration -------------------------------------------------------------------------------
def test_executor_table_is_typed_and_checked(tmp_path, tiny_reference):
    config = load_pipeline(tiny_reference / "pipe.toml", base=tiny_reference)
    assert config.executor == ExecutorConfig(workers=1)
    pipe = tmp_path / "pipe.toml"
    text = (tiny_reference / "pipe.toml").read_text(encoding="utf-8")
    pipe.write_text(text.replace("workers = 1", "workerz = 1"), encoding="utf-8")
    with pytest.raises(FileFormatError, match=r"pipe.toml: .*unknown key 'workerz'"):
        load_pipeline(pipe)
    pipe.write_text(text.replace("workers = 1", "workers = -2"), encoding="utf-8")
    with pytest.raises(FileFormatError, match="executor workers must be >= 0, got -2"):
        load_pipeline(pipe)
    pipe.write_text(text.replace("workers = 1", 'address = "localhost:8786"'), encoding="utf-8")
    with pytest.raises(FileFormatError, match="is not a scheduler address"):
        load_pipeline(pipe)


def test_the_executor_is_not_part_of_any_stage_key(tiny_reference):
    """A finished run is up to date whatever the executor, and starts no cluster for it."""
    # (in place: the stage keys stamp the inputs' paths; an up-to-date run writes nothing)
    config = load_pipeline(tiny_reference / "pipe.toml", base=tiny_reference)
    config = dataclasses.replace(config, executor=ExecutorConfig(workers=2))
    opened = []
    result = run_pipeline(config, on_executor=opened.append)
    assert result.ran == [] and len(result.skipped) == 8
    assert opened == []  # nothing to run: no cluster started


def test_serial_executor_keeps_order_and_passes_the_context():
    ex = open_executor(ExecutorConfig(workers=1))
    assert isinstance(ex, SerialExecutor) and ex.local
    seen = []
    out = list(ex.map(divmod, [7, 9, 11], context=100, progress=lambda *a: seen.append(a)))
    assert out == [(14, 2), (11, 1), (9, 1)]
    assert seen == [("", 1, 3), ("", 2, 3), ("", 3, 3)]


def test_commands_take_workers_and_scheduler():
    runner = CliRunner()
    for command in ("run", "demo", "semantics", "affinity", "render", "synth", "evaluate"):
        res = runner.invoke(main, [command, "--help"])
        assert res.exit_code == 0, res.output
        assert "--workers" in res.output and "--scheduler" in res.output, command
    res = runner.invoke(main, ["affinity", ".", "--scheduler", "localhost"])
    assert res.exit_code == 2 and "is not a scheduler address" in res.output


# -- a local cluster of two worker processes ------------------------------------------------------
@pytest.fixture(scope="module")
def local_cluster():
    with open_executor(ExecutorConfig(workers=2, dashboard=False)) as ex:
        assert not ex.local and ex.workers == 2
        yield ex


def test_stages_on_a_local_cluster_match_serial(tmp_path, tiny_reference, local_cluster):
    """Synthesis, semantics, affinity and render on two workers write what serial wrote."""
    config = load_pipeline(tiny_reference / "pipe.toml", base=tiny_reference)
    synthesize(tmp_path / "cap", config.synth, executor=local_cluster)
    _assert_same_files(tiny_reference / "cap", tmp_path / "cap", "frames/*/*.jpg")
    _assert_same_files(tiny_reference / "cap", tmp_path / "cap", "gt/**/*.npz")

    work = tmp_path / "work"
    shutil.copytree(tiny_reference / "work", work, symlinks=True)
    for name in ("semantic_map.npz", "affinity.npz"):
        (work / name).unlink()
    shutil.rmtree(work / "renders")
    semantics_work(work, config.semantics, tiny_reference / "cap", executor=local_cluster)
    affinity_work(work, config.affinity, executor=local_cluster)
    from pointtraj.render.stage import render_work

    render_work(work, config.render, executor=local_cluster)
    for name in ("semantic_map.npz", "affinity.npz"):
        _assert_same_npz(tiny_reference / "work" / name, work / name)
    _assert_same_files(tiny_reference / "work", work, "renders/**/*.png")
    _assert_same_files(tiny_reference / "work", work, "renders/**/*.mp4")


def test_the_report_on_a_local_cluster_matches_serial(tmp_path, tiny_reference, local_cluster):
    """The evaluation (3D error and predictive validity's recognition frame by frame on two
    workers) writes the serial figures."""
    from pointtraj.evaluate.study import evaluate_work

    metrics = []
    for name, ex in (("serial", None), ("cluster", local_cluster)):
        work = tmp_path / name
        shutil.copytree(tiny_reference / "work", work, symlinks=True)
        shutil.rmtree(work / "report", ignore_errors=True)
        m = evaluate_work(work, capture=tiny_reference / "cap", executor=ex)
        metrics.append({k: v for k, v in m.items() if not k.startswith("timing")})
    assert metrics[0]["validity.support.point_frames"] > 0
    assert np.isfinite(metrics[0]["gt.error_m.median"])
    assert metrics[0].keys() == metrics[1].keys()
    for k, v in metrics[0].items():
        assert v == metrics[1][k] or (v != v and metrics[1][k] != metrics[1][k]), k


def test_the_3d_error_on_a_local_cluster_matches_serial(tiny_reference, local_cluster):
    """The evaluation's 3D error, frame by frame on two workers, is the serial one."""
    from pointtraj.evaluate.groundtruth import surface_errors
    from pointtraj.session import Capture
    from pointtraj.trajectories import Trajectories

    cap = tiny_reference / "cap"
    traj = Trajectories.load(tiny_reference / "work" / "trajectories.npz")
    rig = Capture.open(cap).rig.subset(traj.camera_names)
    ticks = []
    serial = surface_errors(cap, rig, traj, progress=ticks.append)
    assert sum(ticks) == traj.num_frames and len(serial) == len(traj.xyz)
    assert np.isfinite(serial).mean() > 0.9
    on_cluster = surface_errors(cap, rig, traj, executor=local_cluster)
    assert np.array_equal(serial, on_cluster, equal_nan=True)


def test_tasks_whose_scattered_context_is_lost_are_sent_again(local_cluster, caplog):
    """Scattered data is not recomputed: when the workers holding a map's context die, the
    scheduler cancels the tasks that need it. The map sends the context again and resubmits
    them. The loss is made here by cancelling the scattered key on the scheduler after the
    first result, as its last holder's death does."""
    import operator

    from distributed import Future

    client = local_cluster.client
    lost = []

    def lose_the_context(label: str, done: int, total: int) -> None:
        if done == 1 and not lost:
            keys = [k for k in client.who_has() if str(k).startswith("int-")]
            assert len(keys) == 1  # the context, scattered once
            client.cancel([Future(keys[0], client)], force=True)
            lost.extend(keys)

    with caplog.at_level("WARNING", logger="pointtraj.executor"):
        out = list(
            local_cluster.map(
                operator.add, range(6), label="add", context=100, progress=lose_the_context,
                max_pending=1,
            )
        )  # fmt: skip
    assert lost and out == [100, 101, 102, 103, 104, 105]
    assert "resubmitting it" in caplog.text
    deadline = time.monotonic() + 30  # the context sent again is released at the end
    while [k for k in client.who_has() if str(k).startswith("int-")]:
        assert time.monotonic() < deadline, "the context sent again was not released"
        time.sleep(0.1)


def test_a_task_error_comes_back_as_itself(tmp_path, tiny_reference, local_cluster):
    """A bad input found inside a task raises the same error, message and all, as serial."""
    shutil.copytree(tiny_reference / "cap", tmp_path / "cap")
    work = tmp_path / "work"
    shutil.copytree(tiny_reference / "work", work, symlinks=True)
    config = load_pipeline(tiny_reference / "pipe.toml", base=tiny_reference)
    # the simulated recogniser reads the ground-truth label maps: a truncated one
    image = sorted((tmp_path / "cap" / "gt" / "labels").glob("*/000001.*"))[0]
    image.write_bytes(image.read_bytes()[:100])
    bad_option = dataclasses.replace(config.semantics, options={"noize": "low"})
    cases = (
        (config.semantics, FileFormatError, str(image)),
        (bad_option, ValidationError, "noize"),
    )
    for semantics, error, named in cases:
        messages = []
        for executor in (None, local_cluster):
            with pytest.raises(error) as info:
                semantics_work(work, semantics, tmp_path / "cap", executor=executor)
            messages.append(str(info.value))
        assert messages[0] == messages[1] and named in messages[0]


def test_a_command_on_a_local_cluster_names_it_and_its_dashboard(tmp_path, tiny_reference):
    work = tmp_path / "work"
    shutil.copytree(tiny_reference / "work", work, symlinks=True)
    (work / "affinity.npz").unlink()
    pipe = str(tiny_reference / "pipe.toml")  # its [affinity] table
    res = CliRunner().invoke(main, ["affinity", str(work), "--config", pipe, "--workers", "2"])
    assert res.exit_code == 0, res.output
    assert "executor: local Dask cluster, 2 workers, 2 threads; dashboard http://" in res.output
    _assert_same_npz(tiny_reference / "work" / "affinity.npz", work / "affinity.npz")


# -- large arrays from glibc's heap ---------------------------------------------------------------
_FAULTS = """
import resource, sys, numpy as np
from pointtraj.executor import keep_arrays_on_heap
done = keep_arrays_on_heap() if sys.argv[1] == "keep" else None
a = np.ones(int(sys.argv[2]))
f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(20):
    b = a * 2.0  # a temporary, freed at the next
print(done, resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0)
"""


def _temporaries_faults(how: str, size: int, trim: bool) -> tuple[str, int]:
    env = {k: v for k, v in os.environ.items() if k != "MALLOC_TRIM_THRESHOLD_"}
    if trim:
        env["MALLOC_TRIM_THRESHOLD_"] = "65536"  # what a Dask nanny gives its worker
    out = subprocess.run(
        [sys.executable, "-c", _FAULTS, how, str(size)],
        env=env,
        capture_output=True,
        text=True,
        check=True,
    ).stdout.split()
    return out[0], int(out[1])


@pytest.mark.skipif(platform.libc_ver()[0] != "glibc", reason="mallopt is glibc's")
def test_large_temporaries_are_reused_from_the_heap():
    """glibc maps a 64 MiB temporary afresh each time (above its largest mmap threshold), and
    under Dask's MALLOC_TRIM_THRESHOLD_ an 8 MiB one as well: each faults its pages in again
    (about 500 a time here). keep_arrays_on_heap makes them reuse the heap's memory."""
    big, small = 8 << 20, 1 << 20  # float64 elements: 64 MiB and 8 MiB
    done, kept = _temporaries_faults("keep", big, trim=False)
    _, mapped = _temporaries_faults("plain", big, trim=False)
    assert done == "True" and mapped > 20 * 200 and kept * 10 < mapped
    _, trimmed = _temporaries_faults("plain", small, trim=True)
    _, undone = _temporaries_faults("keep", small, trim=True)
    assert trimmed > 20 * 200 and undone * 10 < trimmed


@pytest.mark.skipif(platform.libc_ver()[0] != "glibc", reason="mallopt is glibc's")
def test_workers_of_a_cluster_started_elsewhere_get_the_heap_back():
    """A worker under a nanny with Dask's own environment (as ``dask worker`` starts them) has
    MALLOC_TRIM_THRESHOLD_; the plugin that every executor registers keeps its arrays on the
    heap."""
    from distributed import Client, LocalCluster

    from pointtraj.executor import _worker_setup_plugin

    def faults() -> int:
        import resource

        import numpy

        a = numpy.ones(1 << 20)
        f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
        for _ in range(50):
            a = a * 1.0
        return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0

    with warnings.catch_warnings():  # the scheduler's small HTTP server takes any free port
        warnings.filterwarnings("ignore", message="Port .* is already in use")
        cluster = LocalCluster(n_workers=1, threads_per_worker=1, dashboard_address=":0")
    with cluster, Client(cluster) as client:
        env = client.run(lambda: os.environ.get("MALLOC_TRIM_THRESHOLD_"))
        assert list(env.values()) == ["65536"]
        trimmed = list(client.run(faults).values())[0]
        assert trimmed > 50 * 200
        client.register_plugin(_worker_setup_plugin())
        assert list(client.run(faults).values())[0] * 10 < trimmed


# -- a scheduler and two workers started as commands ----------------------------------------------
def _dask_command() -> list[str] | None:
    exe = Path(sys.executable).parent / "dask"
    if exe.is_file():
        return [str(exe)]
    found = shutil.which("dask")
    return [found] if found else None


@pytest.fixture
def dask_processes(tmp_path):
    """``dask scheduler`` and two ``dask worker ADDRESS`` processes on localhost (random ports):
    yields (address, worker processes); every process is stopped afterwards."""
    dask = _dask_command()
    if dask is None:
        pytest.skip("the `dask` command (distributed's CLI) is not installed")
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), env.get("PYTHONPATH")]))
    procs: list[subprocess.Popen] = []
    log = tmp_path / "dask-logs"
    log.mkdir()

    def start(args: list[str], name: str) -> subprocess.Popen:
        out = open(log / f"{name}.log", "w")  # the child holds it; closed here
        proc = subprocess.Popen(
            [*dask, *args], cwd=tmp_path, env=env, stdout=out, stderr=subprocess.STDOUT
        )
        out.close()
        procs.append(proc)
        return proc

    try:
        file = tmp_path / "scheduler.json"
        start(
            ["scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
             "--scheduler-file", str(file)],
            "scheduler",
        )  # fmt: skip
        deadline = time.monotonic() + 60
        while not file.is_file() or not file.read_text().strip():
            if time.monotonic() > deadline or procs[0].poll() is not None:
                pytest.fail("dask scheduler did not start:\n" + (log / "scheduler.log").read_text())
            time.sleep(0.1)
        import json

        address = json.loads(file.read_text())["address"]
        workers = [
            start(
                [
                    "worker",
                    address,
                    "--nthreads",
                    "1",
                    "--no-nanny",
                    "--no-dashboard",
                    "--memory-limit",
                    "0",
                    "--name",
                    f"w{k}",
                    "--local-directory",
                    str(tmp_path / f"w{k}"),
                ],
                f"worker{k}",
            )  # fmt: skip
            for k in range(2)
        ]
        from distributed import Client

        with Client(address, timeout="30s") as client:
            client.wait_for_workers(2, timeout=60)
        yield address, workers
    finally:  # the workers first (while the scheduler answers them), then the scheduler
        for batch in (procs[1:], procs[:1]):
            for proc in batch:
                if proc.poll() is None:
                    proc.terminate()
            for proc in batch:
                try:
                    proc.wait(timeout=5)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait()


def _run_on(address: str, pipe: Path, progress=None):
    config = load_pipeline(pipe, base=pipe.parent)
    config = dataclasses.replace(config, executor=ExecutorConfig(address=address))
    described = []
    result = run_pipeline(config, progress=progress, on_executor=lambda ex: described.append(ex))
    assert len(described) == 1  # one executor for the whole run
    return result


@pytest.mark.slow
def test_a_scheduler_and_two_worker_commands_run_the_pipeline(
    tmp_path, tiny_reference, dask_processes
):
    address, _ = dask_processes
    pipe = _fresh_copy(tiny_reference, tmp_path / "run")
    result = _run_on(address, pipe)
    assert result.ran[-1] == "render"
    _assert_same_run(tiny_reference, tmp_path / "run")


@pytest.mark.slow
def test_a_run_survives_a_worker_killed_in_the_middle(tmp_path, tiny_reference, dask_processes):
    address, workers = dask_processes
    pipe = _fresh_copy(tiny_reference, tmp_path / "run")
    killed = []

    def kill_after_first_frame(label: str, done: int, total: int) -> None:
        # The synthetic capture's first frame is done, the others are on the workers.
        if label == "synth" and done == 1 and not killed:
            workers[0].send_signal(signal.SIGKILL)
            workers[0].wait(timeout=30)
            killed.append(done)

    result = _run_on(address, pipe, progress=kill_after_first_frame)
    assert killed and workers[0].returncode == -signal.SIGKILL
    assert result.ran[-1] == "render"
    _assert_same_run(tiny_reference, tmp_path / "run")


def test_a_scheduler_that_cannot_be_reached_is_named():
    with pytest.raises(
        PointtrajError, match=r"cannot reach the Dask scheduler at tcp://127.0.0.1:9"
    ):
        open_executor(ExecutorConfig(address="tcp://127.0.0.1:9", wait_workers=2))


def _big_temporary(mib: int) -> int:
    """Touch and free an array of ``mib`` MiB; the resident memory after it (bytes)."""
    import psutil

    a = np.ones(mib << 17)  # float64: mib MiB
    del a
    return psutil.Process().memory_info().rss


def _worker_rss() -> int:
    import psutil

    return psutil.Process().memory_info().rss


@pytest.mark.skipif(platform.libc_ver()[0] != "glibc", reason="malloc_trim is glibc's")
def test_a_worker_gives_its_heap_back_after_a_task_when_near_its_limit():
    """On a worker started as local clusters start them (``MALLOC_ARENA_MAX=1``), the heap
    keeps what a task freed (the resident memory stays at the task's peak); the worker plugin
    trims it after the task when it is above half the worker's memory limit, so that Dask's
    pause at 80 % is not reached by memory that nothing uses."""
    import dask
    from distributed import Client, LocalCluster

    from pointtraj.executor import (
        _SPAWN_ENVIRON,
        WORKER_TRIM_SHARE,
        _worker_environ,
        _worker_setup_plugin,
    )

    limit = 1 << 30
    with dask.config.set({_SPAWN_ENVIRON: _worker_environ()}), warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Port .* is already in use")
        warnings.filterwarnings("ignore", message="Unmanaged memory")
        cluster = LocalCluster(
            n_workers=1, threads_per_worker=1, dashboard_address=":0", memory_limit=limit
        )
    with cluster, Client(cluster) as client:
        client.register_plugin(_worker_setup_plugin())
        inside = client.submit(_big_temporary, 700, pure=False).result()
        after = list(client.run(_worker_rss).values())[0]
    assert inside > 700 << 20  # kept on the heap while the task ran
    assert after < WORKER_TRIM_SHARE * limit, (inside, after)
