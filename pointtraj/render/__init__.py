"""Rendering semantic trajectories: Open3D off-screen views, OpenCV drawing, and ``renders/``.

Two engines draw the same thing, the points alive at frame t coloured by label with the last
``tail`` frames of each trajectory as a polyline (the paper's figures; :mod:`.scene`):

- ``open3d``: :class:`TrajectoryRenderer` (:mod:`.offscreen`) uses Open3D's Filament
  ``OffscreenRenderer``; pinhole views, exact label colours, one renderer open at a time.
- ``opencv``: :func:`draw_scene` (:mod:`.overlay`) projects with the full camera model
  (distortion included) and draws with ``cv2.polylines`` and a depth-sorted disc splat: 10-30x
  faster, for long videos and overlays on the input images (:func:`draw_overlay`).

:func:`render_work` (:mod:`.stage`) renders a labelled work folder into ``WORK/renders/`` (PNG
frames and an MP4 per view, overlays on the camera images, a legend), resuming where a previous
run stopped; see ``data_specs/work_folder.md``. Label colours are in :mod:`.palette`, PNG and
MP4 files in :mod:`.video`, the stage's options in :mod:`.config`.

The names below are imported from their submodules on first use, so that importing one
submodule (``from pointtraj.render.palette import label_colors``) loads only that one.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from .config import ORBIT, RenderConfig
    from .offscreen import TrajectoryRenderer
    from .overlay import (
        draw_caption,
        draw_legend,
        draw_overlay,
        draw_scene,
        draw_segments,
        legend_image,
        legend_origin,
    )
    from .palette import UNLABELLED_COLOR, class_palette, label_colors
    from .scene import floor_grid, orbit_cameras, tail_segments
    from .stage import RenderOutput, RenderResult, render_work
    from .video import read_png, write_png, write_video

__all__ = [
    "RenderConfig",
    "RenderOutput",
    "RenderResult",
    "render_work",
    "TrajectoryRenderer",
    "tail_segments",
    "draw_scene",
    "draw_overlay",
    "draw_segments",
    "draw_legend",
    "draw_caption",
    "legend_image",
    "legend_origin",
    "floor_grid",
    "orbit_cameras",
    "label_colors",
    "class_palette",
    "read_png",
    "write_png",
    "write_video",
    "ORBIT",
    "UNLABELLED_COLOR",
]

#: The submodule that defines each public name.
_HOME = {
    "RenderConfig": "config",
    "ORBIT": "config",
    "RenderOutput": "stage",
    "RenderResult": "stage",
    "render_work": "stage",
    "TrajectoryRenderer": "offscreen",
    "tail_segments": "scene",
    "floor_grid": "scene",
    "orbit_cameras": "scene",
    "draw_scene": "overlay",
    "draw_overlay": "overlay",
    "draw_segments": "overlay",
    "draw_legend": "overlay",
    "draw_caption": "overlay",
    "legend_image": "overlay",
    "legend_origin": "overlay",
    "label_colors": "palette",
    "class_palette": "palette",
    "UNLABELLED_COLOR": "palette",
    "read_png": "video",
    "write_png": "video",
    "write_video": "video",
}


def __getattr__(name: str) -> object:
    """Import a public name from its submodule on first use (PEP 562)."""
    home = _HOME.get(name)
    if home is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{home}", __name__), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})
