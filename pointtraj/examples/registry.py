"""Fetching an example of :data:`~pointtraj.examples.common.EXAMPLES` by name (:func:`fetch_example`)."""

from __future__ import annotations

import os
from functools import partial

from ..errors import ValidationError
from .caliscope import fetch_caliscope_board
from .common import EXAMPLES, ExampleCapture
from .pose2sim import fetch_pose2sim


def fetch_example(name: str, out: str | os.PathLike, **options: object) -> ExampleCapture:
    """Lay out the example capture ``name`` (a key of :data:`EXAMPLES`) in ``out``.

    Parameters
    ----------
    name : str
    out : path-like
    **options
        Passed to :func:`fetch_pose2sim` or :func:`fetch_caliscope_board`.

    Returns
    -------
    ExampleCapture

    Raises
    ------
    ValidationError
        For an unknown name (listing the valid ones).
    """
    funcs = {
        "pose2sim": fetch_pose2sim,
        "pose2sim-multi": partial(fetch_pose2sim, example="pose2sim-multi"),
        "caliscope-board": fetch_caliscope_board,
    }
    if name not in funcs:
        raise ValidationError(f"unknown example {name!r}; valid names: {', '.join(EXAMPLES)}")
    return funcs[name](out, **options)  # type: ignore[operator]
