"""The 3D semantic map (the paper's Section 4.1).

Each image is run through a 2D recogniser (:mod:`pointtraj.semantics.recognizers`), its
confidence map is sampled at the projections of the 3D points (:mod:`.sampling`), the per-camera
samples of a point are pooled across views (:mod:`.pooling`), and the pooled confidences are
averaged over each trajectory's lifetime (:mod:`.semantic_map`).
"""

from __future__ import annotations

from .pooling import POOLINGS, pool_views
from .recognizers import RECOGNIZERS, ImageContext, Recognizer, make_recognizer
from .sampling import sample_confidences
from .semantic_map import SemanticMap, SemanticsConfig, build_semantic_map, normalized_correlation

__all__ = [
    "POOLINGS",
    "pool_views",
    "sample_confidences",
    "RECOGNIZERS",
    "Recognizer",
    "ImageContext",
    "make_recognizer",
    "SemanticMap",
    "SemanticsConfig",
    "build_semantic_map",
    "normalized_correlation",
]
