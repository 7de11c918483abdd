"""Shared fixtures: the tiny synthetic pipeline that several test modules run the CLI on."""

from __future__ import annotations

from pathlib import Path

import pytest

#: A tiny synthetic pipeline (4 cameras at 320x256, 3 frames): every stage in seconds.
TINY = """
name = "tiny"
capture = "cap"
work = "work"

[synth]
preset = "tiny4"
frames = 3
points_per_part = 40

[semantics]
recognizer = "simulated"
options = { noise = "low" }

[affinity]
tau = 0.02

[render]
size = [320, 256]
tail = 2
"""


@pytest.fixture(scope="session")
def tiny_reference(tmp_path_factory) -> Path:
    """One complete run of :data:`TINY` for the session: a folder with ``pipe.toml``, ``cap/``
    and ``work/``. Copy it before changing anything in it."""
    from pointtraj.pipeline import load_pipeline, run_pipeline

    root = tmp_path_factory.mktemp("tiny_reference")
    (root / "pipe.toml").write_text(TINY, encoding="utf-8")
    run_pipeline(load_pipeline(root / "pipe.toml", base=root))
    return root
