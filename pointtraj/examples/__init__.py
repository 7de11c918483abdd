"""Real example captures, laid out as pointtraj capture folders (``pointtraj examples fetch``).

=====================  ========================================================================
name                   what
=====================  ========================================================================
``pose2sim``           Pose2Sim's ``Demo_SinglePerson`` (``pose2sim==0.10.49`` wheel from PyPI,
                       BSD-3-Clause): 4 portrait cameras, 100 frames at 60 fps, a man balancing
                       on a treadmill; Qualisys calibration.
``pose2sim-multi``     Pose2Sim's ``Demo_MultiPerson``: the same cameras and calibration, two
                       people (the man on the treadmill, a woman beside it).
``caliscope-board``    caliscope's ``post_optimization`` test session (BSD-2-Clause), read from
                       ``shared/data/caliscope_board_4cam``: 4 webcams, 57 frames at ~6 fps, a
                       person moving a ChArUco board; caliscope calibration and corner files.
=====================  ========================================================================

Each ``fetch_*`` function writes a capture folder (``data_specs/capture.md``): ``rig.toml``,
``videos/<camera>.mp4``, ``capture.toml``, ``labels.toml`` and a ``README.md`` on its origin,
plus the source files that matter for evaluation (``data_specs/examples.md``).

Two of Pose2Sim's demo videos (``cam01``, ``cam02``) are 1080 px wide while the calibration says
1088: they were rescaled by 1080/1088 and letterboxed with 7 black rows above and below. The
correction is measured from image content (:func:`measure_image_mapping` against the 1088 px
frames Pose2Sim ships in ``calibration/extrinsics``), checked against the candidate models of
:func:`candidate_mappings`, and applied to the intrinsics (:meth:`ImageMapping.apply`); see
``docs/real_captures.md`` for the evidence.
"""

from .caliscope import (
    CALISCOPE_FOLDER as CALISCOPE_FOLDER,
)
from .caliscope import (
    SHARED_ENV as SHARED_ENV,
)
from .caliscope import (
    SyncReport,
    caliscope_sync_report,
    fetch_caliscope_board,
    find_shared_data,
)
from .common import EXAMPLES, ExampleCapture, ExampleNotFoundError, ExampleSpec
from .landmarks import detect_landmarks, landmark_reprojection_errors
from .mapping import (
    BAR_LEVEL as BAR_LEVEL,
)
from .mapping import (
    MAPPING_TOLERANCE_PX as MAPPING_TOLERANCE_PX,
)
from .mapping import (
    MIN_MAPPING_INLIERS as MIN_MAPPING_INLIERS,
)
from .mapping import (
    ImageMapping,
    candidate_mappings,
    choose_image_mapping,
    measure_image_mapping,
)
from .pose2sim import (
    POSE2SIM_DEMO as POSE2SIM_DEMO,
)
from .pose2sim import (
    POSE2SIM_FPS as POSE2SIM_FPS,
)
from .pose2sim import (
    POSE2SIM_REQUIREMENT as POSE2SIM_REQUIREMENT,
)
from .pose2sim import (
    POSE2SIM_SHA256 as POSE2SIM_SHA256,
)
from .pose2sim import (
    download_pose2sim_wheel,
    fetch_pose2sim,
)
from .registry import fetch_example

__all__ = [
    "EXAMPLES",
    "ExampleSpec",
    "ExampleCapture",
    "ExampleNotFoundError",
    "ImageMapping",
    "SyncReport",
    "candidate_mappings",
    "measure_image_mapping",
    "choose_image_mapping",
    "fetch_example",
    "fetch_pose2sim",
    "fetch_caliscope_board",
    "download_pose2sim_wheel",
    "find_shared_data",
    "caliscope_sync_report",
    "detect_landmarks",
    "landmark_reprojection_errors",
]
