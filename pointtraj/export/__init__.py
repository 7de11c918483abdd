"""Exports of a finished work folder to other tools' formats, one module per format family.

- :mod:`pointtraj.export.mocap`: joint centres and part centroids as motion-capture markers,
  C3D (``save_c3d``, through ezc3d) and TRC (``save_trc`` / ``load_trc``, Pose2Sim and OpenSim).

The modules import their heavy dependencies lazily; this package imports nothing.
"""

from __future__ import annotations

__all__ = ["mocap"]
