"""Per-frame 3D reconstruction (paper Section 5): connectivity, matching, triangulation, tracking.

Heavy dependencies (OpenCV, pycolmap) are imported inside the functions that use them.
"""

from .connectivity import (
    ConnectivityGraph,
    build_connectivity,
    confirm_connectivity,
    estimate_capture_volume,
)
from .occlusion import occlusion_test
from .triangulate import (
    Triangulation,
    TriangulationConfig,
    compute_visibility,
    triangulate_points,
    triangulate_ransac,
)

__all__ = [
    "ConnectivityGraph",
    "build_connectivity",
    "confirm_connectivity",
    "estimate_capture_volume",
    "Triangulation",
    "TriangulationConfig",
    "compute_visibility",
    "occlusion_test",
    "triangulate_points",
    "triangulate_ransac",
]
