"""Ground-truth label maps for the simulated recogniser's tests."""

from __future__ import annotations

import numpy as np

from pointtraj.labelset import LabelSet


def figure_map(labels: LabelSet, H: int = 96, W: int = 128) -> np.ndarray:
    """(H, W) int16 label map: a torso, both forearms and hands, and a ball (a disc); -1 is
    background."""
    lab = np.full((H, W), -1, np.int16)
    lab[20:70, 50:78] = labels.index("torso")
    lab[20:60, 30:50] = labels.index("left_forearm")
    lab[60:80, 30:50] = labels.index("left_hand")
    lab[20:60, 78:98] = labels.index("right_forearm")
    lab[60:80, 78:98] = labels.index("right_hand")
    v, u = np.mgrid[0:H, 0:W]
    lab[(u - 110) ** 2 + (v - 80) ** 2 < 100] = labels.index("ball")
    return lab
