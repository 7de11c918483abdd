"""Synthetic 3D pixel continuum: rig presets, articulated figures, a ray-cast renderer and
ground truth (surface-point trajectories, visibility, label and depth maps).

Heavy dependencies (Open3D, OpenCV, SciPy) are imported by the functions that use them.
"""

from __future__ import annotations

from .groundtruth import (
    GroundTruth,
    load_depth_map,
    load_ground_truth,
    load_label_map,
)
from .presets import PRESETS, make_rig, scale_rig
from .render import CaptureSummary, Renderer, RenderSettings, render_capture, synthetic_world
from .scenes import SCENES, Scene, make_scene, scale_scene

__all__ = [
    "GroundTruth",
    "load_ground_truth",
    "load_label_map",
    "load_depth_map",
    "PRESETS",
    "make_rig",
    "SCENES",
    "Scene",
    "make_scene",
    "scale_scene",
    "scale_rig",
    "synthetic_world",
    "Renderer",
    "RenderSettings",
    "CaptureSummary",
    "render_capture",
]
