"""Fault injection on the real CLI and pipeline: a full disk, kill -9 at every stage, two runs at
once, folders pointtraj did not make, stale temporaries, and writers that lie about success.

Every case checks the exit code, a one-line message, and that every earlier output is intact and
readable. The full-disk cases mount a small tmpfs and skip where that is not allowed (not root,
no mount namespace); the same failure is also injected by a writer patched to stop mid-file,
which runs everywhere.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import textwrap
import time
import uuid
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from pointtraj.atomic import TEMP_PREFIX, atomic_path, verify_file
from pointtraj.cli import main
from pointtraj.errors import WorkFolderError, WriteError
from pointtraj.labelfile import load_labels
from pointtraj.pipeline import load_pipeline, run_pipeline
from pointtraj.semantics.semantic_map import SemanticMap
from pointtraj.trajectories import Trajectories
from pointtraj.workdir import WorkFolder

#: The outputs whose content a resumed run must reproduce, and how to read each.
OUTPUTS = (
    "trajectories.npz",
    "semantic_map.npz",
    "affinity.npz",
    "labels.npz",
    "labels.csv",
    "clouds/000000.ply",
    "clouds/000002.ply",
    "report/metrics.json",
    "renders/legend.png",
)


def _one_line_error(output: str) -> str:
    """The single ``Error: ...`` line of a failed command (and no traceback)."""
    assert "Traceback" not in output, output
    lines = [ln for ln in output.strip().splitlines() if ln.startswith("Error")]
    assert len(lines) == 1, output
    return lines[0]


def _snapshot(work: Path) -> dict[str, bytes]:
    return {name: (work / name).read_bytes() for name in OUTPUTS if (work / name).is_file()}


def _assert_readable(work: Path) -> None:
    """Every output of the tiny pipeline loads with its own reader."""
    import cv2
    import open3d as o3d

    traj = Trajectories.load(work / "trajectories.npz")
    assert len(load_labels(work / "labels.npz")) == traj.num_trajectories
    assert SemanticMap.load(work / "semantic_map.npz").num_trajectories == traj.num_trajectories
    for ply in sorted((work / "clouds").glob("*.ply")):
        assert o3d.t.io.read_point_cloud(str(ply)).point.positions.shape[0] > 0, ply
    assert cv2.imread(str(work / "renders" / "legend.png")) is not None
    json.loads((work / "report" / "metrics.json").read_text(encoding="utf-8"))


def _metrics(work: Path) -> dict:
    data = json.loads((work / "report" / "metrics.json").read_text(encoding="utf-8"))
    return {k: v for k, v in data.items() if not k.startswith("timing.")}


@pytest.fixture(scope="module")
def reference(tiny_reference) -> Path:
    """A complete tiny pipeline run: its folder holds ``pipe.toml``, ``cap/`` and ``work/``."""
    return tiny_reference


def _copy(reference: Path, dest: Path) -> Path:
    """A copy of the reference run (capture and work) at ``dest``."""
    shutil.copytree(reference, dest, symlinks=True)
    cfg = dest / "pipe.toml"
    return cfg


def _run_cli(args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "pointtraj", *args],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=600,
    )


# -- verified writes ------------------------------------------------------------------------------
def _real_files(tmp_path: Path) -> dict[str, Path]:
    """One complete file per verified format, each made by the writer pointtraj uses."""
    import cv2
    import open3d as o3d

    from pointtraj.render import write_video

    img = np.random.default_rng(0).integers(0, 255, (64, 80, 3), dtype=np.uint8)
    files = {}
    pcd = o3d.t.geometry.PointCloud(o3d.core.Tensor(np.random.default_rng(1).random((50, 3))))
    pcd.point.track_id = o3d.core.Tensor(np.arange(50, dtype=np.int32)[:, None])
    files["ply"] = tmp_path / "a.ply"
    assert o3d.t.io.write_point_cloud(str(files["ply"]), pcd)
    for ext in ("png", "jpg"):
        files[ext] = tmp_path / f"a.{ext}"
        assert cv2.imwrite(str(files[ext]), img)
    files["npz"] = tmp_path / "a.npz"
    np.savez(files["npz"], a=np.arange(1000))
    files["mp4"] = tmp_path / "a.mp4"
    write_video(files["mp4"], [img, img, img], fps=10)
    return files


def test_every_verified_format_accepts_complete_files_and_rejects_truncated_ones(tmp_path):
    for ext, path in _real_files(tmp_path).items():
        assert verify_file(path) is None, ext
        data = path.read_bytes()
        for keep in (len(data) // 20, len(data) // 2, len(data) - 1):
            cut = tmp_path / f"cut.{ext}"
            cut.write_bytes(data[:keep])
            assert verify_file(cut) is not None, (ext, keep)
        empty = tmp_path / f"empty.{ext}"
        empty.write_bytes(b"")
        assert verify_file(empty) == "the writer produced an empty file"


def test_a_writer_that_claims_success_on_a_truncated_file_installs_nothing(tmp_path):
    """Open3D returned True after RPly write errors; the check must not believe it."""
    good = _real_files(tmp_path)["ply"]
    dest = tmp_path / "clouds" / "000001.ply"
    dest.parent.mkdir()
    shutil.copy(good, dest)
    before = dest.read_bytes()
    with pytest.raises(
        WriteError, match=r"000001\.ply: incomplete output: .*previous file is kept"
    ):
        with atomic_path(dest) as tmp:
            tmp.write_bytes(before[: len(before) // 2])
    assert dest.read_bytes() == before
    assert sorted(p.name for p in dest.parent.iterdir()) == ["000001.ply"]


def test_label_with_a_cloud_writer_that_stops_mid_file_keeps_every_output(
    reference, tmp_path, monkeypatch
):
    """The full-disk failure of ``pointtraj label``, injected without a mount: Open3D's writer
    is patched to write half of each file and report success, as it did on a full disk."""
    import open3d as o3d

    root = tmp_path / "r"
    _copy(reference, root)
    work = root / "work"
    before = _snapshot(work)
    real = o3d.t.io.write_point_cloud

    def half_writer(path, pcd, *args, **kwargs):
        assert real(path, pcd, *args, **kwargs)
        data = Path(path).read_bytes()
        Path(path).write_bytes(data[: len(data) // 2])
        return True

    monkeypatch.setattr(o3d.t.io, "write_point_cloud", half_writer)
    res = CliRunner().invoke(main, ["label", str(work)])
    assert res.exit_code == 1
    assert "000000.ply: incomplete output" in _one_line_error(res.output)
    monkeypatch.setattr(o3d.t.io, "write_point_cloud", real)
    assert _snapshot(work) == before
    _assert_readable(work)
    assert not list(work.rglob(TEMP_PREFIX + "*"))
    # The interrupted relabelling is known, and the next run redoes it.
    assert WorkFolder(work).labels_pending.exists()
    res = CliRunner().invoke(main, ["label", str(work)])
    assert res.exit_code == 0, res.output
    assert not WorkFolder(work).labels_pending.exists()
    assert _snapshot(work) == before


# -- a real full disk -----------------------------------------------------------------------------
@pytest.fixture
def small_disk(tmp_path):
    """A 3 MB tmpfs (skips where mounting is not allowed)."""
    mnt = tmp_path / "disk"
    mnt.mkdir()
    if shutil.which("mount") is None or os.geteuid() != 0:
        pytest.skip("mounting a tmpfs needs root")
    res = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", "size=3m", "tmpfs", str(mnt)], capture_output=True
    )
    if res.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {res.stderr.decode().strip()}")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", "-l", str(mnt)], check=False)


def _fill(disk: Path, leave: int) -> None:
    """Fill ``disk`` up to ``leave`` free bytes."""
    st = os.statvfs(disk)
    free = st.f_bavail * st.f_frsize
    with open(disk / f"filler-{uuid.uuid4().hex}", "wb") as f:
        f.write(b"\0" * max(free - leave, 0))


@pytest.mark.parametrize(
    "command, leave",
    [
        (["label"], 4096),  # the pending mark cannot be written
        (["label"], 8192),  # the first cloud cannot be written
        (["label"], 12288),  # the clouds are written, labels.npz is not
        (["affinity"], 0),
        (["evaluate"], 0),
        (["render"], 8192),
    ],
)
def test_a_full_disk_gives_one_line_and_keeps_every_output(reference, small_disk, command, leave):
    root = small_disk / "r"
    _copy(reference, root)
    work = root / "work"
    before = _snapshot(work)
    _fill(small_disk, leave)
    res = _run_cli([*command, str(work)], cwd=root)
    assert res.returncode == 1, res.stdout + res.stderr
    line = _one_line_error(res.stderr)
    assert "disk is full" in line or "disk is nearly full" in line, line
    assert str(work) in line
    for name, data in before.items():
        assert (work / name).read_bytes() == data, name
    _assert_readable(work)
    assert not [p for p in work.rglob(TEMP_PREFIX + "*")]


def test_a_full_disk_during_semantics_keeps_the_old_map(reference, small_disk):
    root = small_disk / "r"
    _copy(reference, root)
    work = root / "work"
    before = (work / "semantic_map.npz").read_bytes()
    _fill(small_disk, 0)
    res = _run_cli(["semantics", str(work), "-r", "simulated", "-o", "noise=low"], cwd=root)
    assert res.returncode == 1
    assert "semantic_map.npz" in _one_line_error(res.stderr)
    assert (work / "semantic_map.npz").read_bytes() == before


# -- ownership ------------------------------------------------------------------------------------
def test_a_folder_pointtraj_did_not_make_is_never_cleared(reference, tmp_path):
    root = tmp_path / "r"
    _copy(reference, root)
    foreign = root / "theirs"
    (foreign / "state").mkdir(parents=True)
    (foreign / "clouds").mkdir()
    (foreign / "state" / "notes.txt").write_text("mine")
    (foreign / "clouds" / "000000.ply").write_text("mine")
    res = _run_cli(["run", "pipe.toml", "--work", "theirs"], cwd=root)
    assert res.returncode == 1
    assert "not a pointtraj work folder" in _one_line_error(res.stderr)
    res = _run_cli(["reconstruct", "cap", "--out", "theirs", "--restart"], cwd=root)
    assert res.returncode == 1
    assert "--force-folder" in _one_line_error(res.stderr)
    assert (foreign / "state" / "notes.txt").read_text() == "mine"
    assert (foreign / "clouds" / "000000.ply").read_text() == "mine"
    # With --force-folder, only files named as pointtraj names them go, and the log says so.
    res = _run_cli(["-v", "reconstruct", "cap", "--out", "theirs", "--force-folder"], cwd=root)
    assert res.returncode == 0, res.stderr
    assert "--force-folder: removing 1 files" in res.stderr
    assert (foreign / "state" / "notes.txt").read_text() == "mine"
    assert Trajectories.load(foreign / "trajectories.npz").num_trajectories > 0


def test_a_restart_removes_only_the_files_pointtraj_wrote(reference, tmp_path):
    root = tmp_path / "r"
    _copy(reference, root)
    work = root / "work"
    (work / "clouds" / "annotated.ply").write_text("mine")
    (work / "state" / "000099.npz").write_text("mine, named like ours")
    res = _run_cli(["-v", "reconstruct", "cap", "--out", "work", "--restart"], cwd=root)
    assert res.returncode == 0, res.stderr
    assert "kept 2 files that pointtraj did not write" in res.stderr
    assert (work / "clouds" / "annotated.ply").read_text() == "mine"
    assert (work / "state" / "000099.npz").read_text() == "mine, named like ours"
    assert (work / "clouds" / "000002.ply").is_file()


def test_a_non_empty_folder_is_not_taken_as_a_work_folder(reference, tmp_path):
    home = tmp_path / "home"
    home.mkdir()
    (home / "thesis.tex").write_text("years of work")
    with pytest.raises(WorkFolderError, match="not a pointtraj work folder .*thesis.tex"):
        run_pipeline(load_pipeline(reference / "pipe.toml", base=reference).with_paths(None, home))
    assert sorted(p.name for p in home.iterdir()) == ["thesis.tex"]


# -- one run at a time, and what a killed run leaves ---------------------------------------------
def test_a_second_run_on_a_held_folder_names_the_holder(reference, tmp_path):
    root = tmp_path / "r"
    _copy(reference, root)
    holder = subprocess.Popen(
        [
            sys.executable,
            "-c",
            textwrap.dedent(
                f"""
                import sys, time
                from pointtraj.workdir import WorkFolder
                with WorkFolder({str(root / "work")!r}).lock("pointtraj run"):
                    print("held", flush=True)
                    time.sleep(60)
                """
            ),
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert holder.stdout.readline().strip() == "held"
        for args in (["run", "pipe.toml", "--force", "label"], ["label", "work"]):
            res = _run_cli(args, cwd=root)
            assert res.returncode == 1
            line = _one_line_error(res.stderr)
            assert f"in use by `pointtraj run` (pid {holder.pid} on " in line, line
    finally:
        holder.kill()
        holder.wait()
        holder.stdout.close()
    # The OS released the dead holder's lock: the folder is usable again.
    res = _run_cli(["label", "work"], cwd=root)
    assert res.returncode == 0, res.stderr


def test_temporaries_of_a_killed_run_are_removed_and_user_files_kept(reference, tmp_path):
    root = tmp_path / "r"
    _copy(reference, root)
    work = root / "work"
    stale = [
        work / f"{TEMP_PREFIX}semantic_map.npz.k2j4h5g6.npz",
        work / "clouds" / f"{TEMP_PREFIX}000001.ply.abcdefgh.ply",
        work / ".semantic_map.npz.a1b2c3d4.npz",  # as versions before TEMP_PREFIX named them
    ]
    for p in stale:
        p.write_bytes(b"half")
    user = work / ".my_notes.txt"
    user.write_text("mine")
    res = _run_cli(["label", "work"], cwd=root)
    assert res.returncode == 0, res.stderr
    assert not any(p.exists() for p in stale)
    assert user.read_text() == "mine"


_KILLER = """
import os, signal, sys, threading
from pathlib import Path
from pointtraj.pipeline import load_pipeline, run_pipeline

stage, when = sys.argv[1], sys.argv[2]
root = Path.cwd()

def kill():
    os.kill(os.getpid(), signal.SIGKILL)

def progress(label, done, total):
    if when == "progress" and label.startswith(stage) and done >= 1:
        kill()

def on_stage(name, event):
    if when == "start" and name == stage and event == "start":
        threading.Timer(0.3, kill).start()

run_pipeline(load_pipeline(root / "pipe.toml", base=root), force=["all"], progress=progress,
             on_stage=on_stage)
"""


@pytest.mark.parametrize(
    "stage, when",
    [
        ("synth", "progress"),
        ("reconstruct", "progress"),
        ("semantics", "start"),
        ("affinity", "progress"),
        ("label: clouds", "progress"),
        ("evaluate", "progress"),
        ("view orbit", "progress"),
    ],
)
def test_kill_9_in_any_stage_then_a_rerun_gives_identical_outputs(reference, tmp_path, stage, when):
    root = tmp_path / "r"
    _copy(reference, root)
    work = root / "work"
    expected, expected_metrics = _snapshot(work), _metrics(work)
    killed = subprocess.run(
        [sys.executable, "-c", _KILLER, stage, when], cwd=root, capture_output=True, timeout=600
    )
    assert killed.returncode == -signal.SIGKILL, killed.stderr.decode()[-2000:]
    res = _run_cli(["run", "pipe.toml"], cwd=root)
    assert res.returncode == 0, res.stderr
    got = _snapshot(work)
    assert set(got) == set(expected)
    for name in got:
        if name == "report/metrics.json":
            assert _metrics(work) == expected_metrics
        elif name == "renders/legend.png":
            continue  # drawn again; its pixels are checked readable below
        else:
            assert got[name] == expected[name], name
    _assert_readable(work)
    assert not list(root.rglob(TEMP_PREFIX + "*"))  # the capture's and the work folder's
    assert not WorkFolder(work).labels_pending.exists()


def test_sigint_stops_a_run_cleanly_and_it_resumes(reference, tmp_path):
    root = tmp_path / "r"
    _copy(reference, root)
    work = root / "work"
    expected = _snapshot(work)
    proc = subprocess.Popen(
        [sys.executable, "-m", "pointtraj", "run", "pipe.toml", "--force", "all"],
        cwd=root,
        stderr=subprocess.PIPE,
        text=True,
        # A shell's background job ignores SIGINT, and Python keeps an inherited SIG_IGN: give
        # the run the default, so that Ctrl-C reaches it however the tests were started.
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    for line in proc.stderr:
        if line.startswith("semantics"):
            time.sleep(0.3)
            proc.send_signal(signal.SIGINT)
            break
    _, rest = proc.communicate(timeout=600)
    assert proc.returncode != 0, rest[-3000:]
    assert not list(work.rglob(TEMP_PREFIX + "*"))
    res = _run_cli(["run", "pipe.toml"], cwd=root)
    assert res.returncode == 0, res.stderr
    got = _snapshot(work)
    for name in ("trajectories.npz", "semantic_map.npz", "labels.npz", "clouds/000002.ply"):
        assert got[name] == expected[name], name


def test_a_read_only_work_folder_gives_one_line(reference, small_disk):
    root = small_disk / "r"
    _copy(reference, root)
    work = root / "work"
    before = _snapshot(work)
    res = subprocess.run(["mount", "-o", "remount,ro", str(small_disk)], capture_output=True)
    if res.returncode != 0:
        pytest.skip(f"cannot remount read-only: {res.stderr.decode().strip()}")
    for args in (
        ["semantics", str(work), "-r", "simulated"],
        ["label", str(work)],
        ["render", str(work)],
        ["evaluate", str(work)],
    ):
        res = _run_cli(args, cwd=tmp_path_of(small_disk))
        assert res.returncode == 1, args
        line = _one_line_error(res.stderr)
        assert f"{work}: cannot write into the work folder (read-only file system)" in line, line
    assert _snapshot(work) == before


def tmp_path_of(disk: Path) -> Path:
    """A writable folder beside the mounted disk (the commands' working folder)."""
    return disk.parent
