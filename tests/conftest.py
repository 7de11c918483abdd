"""Shared fixtures: the tiny synthetic pipeline that several test modules run the CLI on."""

from __future__ import annotations

from pathlib import Path

import pytest
from helpers.pipelines import TINY


@pytest.fixture(scope="session")
def tiny_reference(tmp_path_factory) -> Path:
    """One complete run of :data:`TINY` for the session: a folder with ``pipe.toml``, ``cap/``
    and ``work/``. Copy it before changing anything in it."""
    from pointtraj.pipeline import load_pipeline, run_pipeline

    root = tmp_path_factory.mktemp("tiny_reference")
    (root / "pipe.toml").write_text(TINY, encoding="utf-8")
    run_pipeline(load_pipeline(root / "pipe.toml", base=root))
    return root
