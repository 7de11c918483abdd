"""The paper's published figures, shown beside ours in every report.

Yoon, Li & Park, CVPR 2018: Table 1 (temporal consistency), Figure 6 (affinity effectiveness),
Figure 7 (predictive validity) and Section 6 (the rig).
"""

from __future__ import annotations

__all__ = ["TEMPORAL_NC", "VALIDITY_TEXT", "AFFINITY_TEXT", "RIG"]

#: Table 1: normalised correlation of pooled confidences between the first frame and t seconds
#: later, mean and standard deviation over all sequences, per pooling.
TEMPORAL_NC: dict[str, dict[int, tuple[float, float]]] = {
    "view": {
        1: (0.96, 0.01),
        3: (0.90, 0.02),
        5: (0.89, 0.03),
        7: (0.88, 0.02),
        9: (0.89, 0.02),
        11: (0.88, 0.03),
        13: (0.87, 0.05),
        15: (0.79, 0.08),
    },
    "average": {
        1: (0.43, 0.10),
        3: (0.44, 0.10),
        5: (0.43, 0.10),
        7: (0.48, 0.09),
        9: (0.44, 0.09),
        11: (0.43, 0.10),
        13: (0.42, 0.10),
        15: (0.37, 0.10),
    },
}

#: Figure 7, as the text states it (the plotted values are not published as numbers).
VALIDITY_TEXT = (
    "With 1-5 labelling cameras view pooling performs like average pooling; it then rises "
    "quickly, to more than 0.6 accuracy at 20 cameras in most sequences, and stays above "
    "average pooling for all sequences."
)

#: Figure 6, as the text states it.
AFFINITY_TEXT = (
    "The label disagreement of ε_s-neighbours rises quickly beyond 10 cm, while the SE(3) "
    "affinity keeps it low up to about 1 m (0.6-1 m in particular)."
)

#: Section 6 and footnote 2.
RIG = {
    "cameras": 69,
    "resolution": (1280, 1024),
    "fps": 30,
    "stage": "3 m diameter x 2.5 m cylinder, two rings of cameras",
    "density_mean_px_per_cm3": 6.4,
    "density_centre_px_per_cm3": 60.0,
    "panoptic_density_px_per_cm3": 0.44,
}
