"""Shared fixtures: the tiny synthetic pipeline that several test modules run the CLI on."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from helpers.pipelines import TINY

# The commands run their stages serially in the tests (this process, and the commands the tests
# start as subprocesses): no test starts a Dask cluster unless it is about one (test_executor).
os.environ["POINTTRAJ_WORKERS"] = "1"
os.environ.pop("POINTTRAJ_SCHEDULER", None)


@pytest.fixture(scope="session")
def tiny_reference(tmp_path_factory) -> Path:
    """One complete run of :data:`TINY` for the session: a folder with ``pipe.toml``, ``cap/``
    and ``work/``. Copy it before changing anything in it."""
    from pointtraj.pipeline import load_pipeline, run_pipeline

    root = tmp_path_factory.mktemp("tiny_reference")
    (root / "pipe.toml").write_text(TINY, encoding="utf-8")
    run_pipeline(load_pipeline(root / "pipe.toml", base=root))
    return root
