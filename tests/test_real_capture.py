"""A short cut of a real capture (caliscope's ChArUco board session) through every stage.

Four frames of the 4-webcam session run through ``run_pipeline`` (capture, trajectories,
semantics with the ChArUco-board recogniser, affinity, label, evaluate, render); the test
checks the output against caliscope's own triangulated board corners, which the pipeline never
reads. It needs the shared data folder (``../shared/data/caliscope_board_4cam``) and no network.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

from pointtraj.examples import fetch_caliscope_board
from pointtraj.labelfile import load_labels
from pointtraj.pipeline import load_pipeline, run_pipeline
from pointtraj.trajectories import Trajectories

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
CALISCOPE = SHARED / "data" / "caliscope_board_4cam"

#: Frames 24-27: the board is seen by every camera and moves by a few centimetres a frame.
PIPELINE = """
name = "board_cut"
capture = "cap"
work = "work"
frames = "24:28"

[semantics]
recognizer = "charuco-board"

[evaluate]
validity_frames = 2
validity_tracks = 500
affinity_draws = 4

[render]
engine = "opencv"
views = []
video = false
size = [320, 256]
tail = 2

[executor]
workers = 1
"""


def _board_planes(capture: Path) -> dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per video frame, caliscope's corners: (centre (3,), normal (3,), corners (K, 3))."""
    rows: dict[int, list[list[float]]] = {}
    with open(capture / "charuco" / "corners_3d.csv", newline="") as f:
        for r in csv.DictReader(f):
            rows.setdefault(int(r["frame"]), []).append([float(r[k]) for k in "xyz"])
    out = {}
    for t, pts in rows.items():
        K = np.array(pts)
        if len(K) >= 4:
            c = K.mean(axis=0)
            out[t] = (c, np.linalg.svd(K - c)[2][2], K)
    return out


@pytest.mark.slow
@pytest.mark.shared
@pytest.mark.skipif(
    not CALISCOPE.is_dir(), reason=f"needs the shared caliscope capture at {CALISCOPE}"
)
def test_board_cut_through_every_stage(tmp_path):
    fetch_caliscope_board(tmp_path / "cap", source=CALISCOPE)
    (tmp_path / "pipe.toml").write_text(PIPELINE, encoding="utf-8")
    config = load_pipeline(tmp_path / "pipe.toml", base=tmp_path)
    result = run_pipeline(config)
    assert result.ran[-1] == "render" and "label" in result.ran
    work = config.work
    traj = Trajectories.load(work / "trajectories.npz")
    labels = load_labels(work / "labels.npz")
    assert len(labels) == traj.num_trajectories > 100
    board = labels.class_names.index("board")

    # Point-frames on the board: within 1.5 cm of the plane of caliscope's inner corners of
    # that frame, and within 12 cm of one (the board's frame reaches about 10 cm beyond them).
    planes = _board_planes(tmp_path / "cap")
    on_board = np.zeros(traj.num_point_frames, bool)
    for t in range(24, 28):
        rows = traj.frame_rows(t)
        c, n, K = planes[t]
        X = traj.xyz[rows].astype(np.float64)
        near = np.linalg.norm(X[:, None] - K[None], axis=2).min(axis=1) < 0.12
        on_board[rows] = near & (np.abs((X - c) @ n) < 0.015)
    frac = np.bincount(traj.row_track[on_board], minlength=len(labels)) / traj.lengths
    geometric = frac >= 0.5  # (M,) trajectories on the board by geometry
    labelled = labels.labels == board
    assert geometric.sum() >= 30, "too few trajectories reconstructed on the board"
    # The labels agree with the geometry both ways.
    assert labelled[geometric].mean() > 0.8
    assert geometric[labelled].mean() > 0.8
    # Walls and furniture, where no recogniser fires, stay unlabelled.
    assert (labels.labels == -1).sum() > 0.3 * len(labels)

    # The board is rigid: pairwise distances of its trajectories change by a few mm.
    ids = np.flatnonzero(labelled & (traj.lengths == 4))
    X = traj.dense_positions(ids).astype(np.float64)  # (B, T, 3), NaN outside the lifetime
    X = X[:, 24:28]
    i, j = np.triu_indices(len(ids), k=1)
    D = np.linalg.norm(X[i] - X[j], axis=2)  # (Q, 4)
    change = np.abs(D - D[:, :1]).max(axis=1)
    assert len(change) > 100 and np.median(change) < 0.005

    report = (work / "report" / "index.md").read_text(encoding="utf-8")
    assert "## Predictive validity" in report and "view pooling" in report
    overlays = sorted((work / "renders" / "overlays" / "cam_0").glob("*.png"))
    assert len(overlays) == 4
