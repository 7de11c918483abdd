"""The report writer: markdown, JSON and plots."""

from __future__ import annotations

import json

import numpy as np

from pointtraj.evaluate.report import (
    Section,
    plot_confusion,
    plot_disagreement,
    plot_temporal,
    plot_validity,
    temporal_table,
    write_report,
)


def test_report_round_trip(tmp_path):
    ours = {"view": {1: (0.97, 0.01, 10), 3: (0.95, 0.02, 8)}, "average": {1: (0.5, 0.1, 10)}}
    plot_temporal(ours, tmp_path / "temporal.png")
    plot_disagreement(
        np.linspace(0, 1, 11), {"SE(3)": np.linspace(0, 0.2, 10)}, tmp_path / "aff.png"
    )
    plot_validity([1, 2, 5], {"view": [0.3, 0.5, 0.7]}, tmp_path / "val.png")
    plot_confusion(np.array([[5, 1], [0, 3]]), ["a", "b"], tmp_path / "conf.png")
    table = temporal_table(ours)
    assert "| ours, view | 0.97 ± 0.01 | 0.95 ± 0.02 |" in table
    assert "| paper, view | 0.96 ± 0.01 | 0.90 ± 0.02 |" in table
    index = write_report(
        tmp_path,
        "Demo",
        [Section("Temporal consistency", table, ["temporal.png"])],
        {"temporal_nc.view.1s": 0.97, "gt.error_m.median": float("nan"), "n": np.int64(3)},
    )
    text = index.read_text()
    assert "![Temporal consistency](temporal.png)" in text
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert metrics == {"gt.error_m.median": None, "n": 3, "temporal_nc.view.1s": 0.97}
    for name in ("temporal.png", "aff.png", "val.png", "conf.png"):
        assert (tmp_path / name).stat().st_size > 1000
