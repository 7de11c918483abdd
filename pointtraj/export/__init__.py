"""A finished work folder in other tools' formats (one module per format family).

- :mod:`pointtraj.export.rerun`: a Rerun recording (``export_rerun``, ``write_recording``).
- :mod:`pointtraj.export.mocap`: joint centres and part centroids as motion-capture markers,
  C3D (``save_c3d``, through ezc3d) and TRC (``save_trc`` / ``load_trc``, Pose2Sim and OpenSim).

The modules import their format's library (an optional dependency) inside the functions that
need it, so that ``import pointtraj.export`` stays light; the names below load on first use.
"""

from __future__ import annotations

import importlib
from typing import Any

__all__ = ["RerunConfig", "RerunExport", "export_rerun", "mocap", "write_recording"]

#: Public name -> the module of this package that defines it.
_HOMES: dict[str, str] = {
    "RerunConfig": "rerun",
    "RerunExport": "rerun",
    "export_rerun": "rerun",
    "write_recording": "rerun",
}


def __getattr__(name: str) -> Any:
    if name == "mocap":
        return importlib.import_module(".mocap", __name__)
    if name in _HOMES:
        return getattr(importlib.import_module(f".{_HOMES[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
