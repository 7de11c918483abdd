"""Rig calibration: structure from motion with pycolmap, ChArUco boards, metric scale and frame.

The paper (Section 5, step 1) calibrates each camera's intrinsics, recovers the extrinsics with
structure from motion and refines both jointly in a bundle adjustment:

- :mod:`.sfm`: :func:`calibrate_images`, pycolmap SfM on the CPU with per-folder intrinsics, a
  joint bundle adjustment and the rejection (and one retry) of degenerate cameras;
- :mod:`.charuco`: :class:`CharucoBoard` (caliscope's ``charuco.toml``), :func:`detect_charuco`,
  :func:`align_rig_to_charuco` (metric scale and the board's frame) and
  :func:`calibrate_charuco` (calibration from board corners alone, where SfM cannot register);
- :mod:`.align`: SfM fixes the rig only up to a similarity; :func:`scale_rig_by_distance` (a
  known distance between two camera centres) and :func:`align_rig_to` (an existing rig: Umeyama's
  similarity between camera centres after a least-median-of-squares search for outlier cameras)
  fix it; :func:`compare_rigs` measures a rig against a reference;
- :class:`Calibration`, :class:`CalibrationError` and :func:`plot_match_graph`, shared by both
  calibrations.

Heavy dependencies (pycolmap, OpenCV, matplotlib, scipy's optimiser) are imported inside the
functions that use them.
"""

from __future__ import annotations

from ._common import Calibration, CalibrationError, plot_match_graph
from .align import (
    RigAlignment,
    RigComparison,
    align_rig_to,
    compare_rigs,
    estimate_rig_similarity,
    scale_rig_by_distance,
    transform_rig,
    umeyama,
)
from .charuco import CharucoBoard, align_rig_to_charuco, calibrate_charuco, detect_charuco
from .sfm import (
    CAMERA_MODELS,
    CalibrationOptions,
    calibrate_images,
    export_frames,
    find_degenerate_cameras,
)

__all__ = [
    "CAMERA_MODELS",
    "CalibrationError",
    "CalibrationOptions",
    "Calibration",
    "CharucoBoard",
    "RigComparison",
    "align_rig_to",
    "align_rig_to_charuco",
    "estimate_rig_similarity",
    "RigAlignment",
    "calibrate_charuco",
    "calibrate_images",
    "compare_rigs",
    "detect_charuco",
    "export_frames",
    "find_degenerate_cameras",
    "plot_match_graph",
    "scale_rig_by_distance",
    "transform_rig",
    "umeyama",
]
