"""pointtraj: dense 3D semantic trajectories from synchronised, calibrated multi-camera video.

The method is Yoon, Li and Park, "3D Semantic Trajectory Reconstruction from 3D Pixel Continuum"
(CVPR 2018). Heavy dependencies (Open3D, OpenCV, pycolmap, onnxruntime) are imported lazily by
the functions that need them, so ``import pointtraj`` is fast.
"""

from __future__ import annotations

import logging

from .camera import Camera, CameraRig
from .errors import FileFormatError, PointtrajError, ValidationError
from .trajectories import Trajectories

__version__ = "0.1.0"


def load(work):
    """Load a work folder's trajectories, semantic map and labels (:func:`pointtraj.results.load`).

    Parameters
    ----------
    work : path-like

    Returns
    -------
    pointtraj.results.Result
    """
    from .results import load as _load

    return _load(work)


__all__ = [
    "Camera",
    "CameraRig",
    "Trajectories",
    "PointtrajError",
    "ValidationError",
    "FileFormatError",
    "__version__",
    "load",
]

logging.getLogger(__name__).addHandler(logging.NullHandler())
