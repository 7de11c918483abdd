"""What every calibration returns: :class:`Calibration`, :class:`CalibrationError`, and the figure
of a calibration's camera pairs (:func:`plot_match_graph`)."""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ..camera import CameraRig
from ..errors import PointtrajError, check_array

__all__ = ["Calibration", "CalibrationError", "plot_match_graph"]


class CalibrationError(PointtrajError):
    """Calibration could not produce a rig from the given input (too few registered cameras,
    no overlap between cameras, missing images)."""


@dataclass
class Calibration:
    """Result of a calibration.

    Attributes
    ----------
    rig : CameraRig
        The registered cameras, in input order.
    camera_names : list of str
        Every input camera, registered or not.
    errors : dict of str to float
        Mean reprojection error in pixels per registered camera (final rig, all frames).
    observations : dict of str to int
        Observations (2D points of the model) per registered camera.
    failed : dict of str to str
        Camera -> why it is not in ``rig``.
    match_counts : (C, C) int ndarray
        Verified inlier matches between cameras (summed over frames), over ``camera_names``;
        zero diagonal.
    pose_spread_deg : dict of str to float
        Largest rotation difference between a camera's per-frame poses (0 for one frame).
    num_points : int
        3D points in the model.
    notes : list of str
        What was done to set the scale and world frame.
    """

    rig: CameraRig
    camera_names: list[str]
    errors: dict[str, float]
    observations: dict[str, int]
    failed: dict[str, str]
    match_counts: np.ndarray
    pose_spread_deg: dict[str, float] = field(default_factory=dict)
    num_points: int = 0
    notes: list[str] = field(default_factory=list)

    def with_rig(self, rig: CameraRig, note: str) -> Calibration:
        """A copy with a transformed rig (same cameras) and a note appended."""
        return Calibration(
            rig,
            self.camera_names,
            self.errors,
            self.observations,
            self.failed,
            self.match_counts,
            self.pose_spread_deg,
            self.num_points,
            [*self.notes, note],
        )

    def summary(self) -> str:
        """Several lines: per-camera reprojection errors and failures."""
        lines = [
            f"registered {len(self.rig)} of {len(self.camera_names)} cameras, "
            f"{self.num_points} points"
        ]
        for name in self.camera_names:
            if name in self.errors:
                spread = self.pose_spread_deg.get(name, 0.0)
                lines.append(
                    f"  {name}: {self.errors[name]:.3f} px mean reprojection error, "
                    f"{self.observations[name]} observations, pose spread {spread:.3f} deg"
                )
            else:
                lines.append(f"  {name}: FAILED - {self.failed.get(name, 'unknown')}")
        lines.extend(self.notes)
        return "\n".join(lines)


def plot_match_graph(
    rig: CameraRig,
    match_counts: np.ndarray,
    path: str | os.PathLike,
    names: Sequence[str] | None = None,
    geometric_edges: Sequence[tuple[int, int]] | None = None,
    min_matches: int = 15,
) -> None:
    """Top view of the rig with camera pairs joined by their verified match counts.

    Parameters
    ----------
    rig : CameraRig
    match_counts : (N, N) int ndarray
        Over ``names`` (default ``rig.names``).
    path : path-like
        PNG written atomically.
    names : sequence of str, optional
        Camera names indexing ``match_counts``.
    geometric_edges : sequence of (i, j), optional
        Edges of the geometric connectivity graph (indices into ``rig``), drawn dashed grey.
    min_matches : int
        Pairs with fewer matches are not drawn.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..atomic import atomic_path

    names = list(names) if names is not None else rig.names
    counts = check_array("match_counts", match_counts, (len(names), len(names)))
    pos = {n: rig.C[rig.index(n), :2] for n in rig.names}
    fig, ax = plt.subplots(figsize=(6.5, 6))
    if geometric_edges is not None:
        for i, j in geometric_edges:
            a, b = rig.C[i, :2], rig.C[j, :2]
            ax.plot([a[0], b[0]], [a[1], b[1]], "--", color="0.75", lw=0.8, zorder=1)
    vmax = max(int(counts.max()), 1)
    cmap = plt.get_cmap("viridis")
    for i in range(len(names)):
        for j in range(i + 1, len(names)):
            n = int(counts[i, j])
            if n < min_matches or names[i] not in pos or names[j] not in pos:
                continue
            a, b = pos[names[i]], pos[names[j]]
            ax.plot([a[0], b[0]], [a[1], b[1]], color=cmap(n / vmax), lw=0.5 + 2.5 * n / vmax)
    xy = rig.C[:, :2]
    ax.plot(xy[:, 0], xy[:, 1], "r^", ms=6, zorder=3)
    for n, p in pos.items():
        ax.annotate(n, p, fontsize=7, xytext=(3, 3), textcoords="offset points")
    sm = plt.cm.ScalarMappable(cmap=cmap, norm=plt.Normalize(0, vmax))
    fig.colorbar(sm, ax=ax, label="verified inlier matches")
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title("camera pairs by verified matches (dashed: geometric graph)")
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)
