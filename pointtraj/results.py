"""``pointtraj.load(work)``: a work folder's results as Python objects.

>>> import pointtraj                                    # doctest: +SKIP
>>> res = pointtraj.load("pointtraj-demo/work")         # doctest: +SKIP
>>> res.trajectories.num_trajectories, res.class_names  # doctest: +SKIP
>>> pcd = res.pointcloud(10)  # doctest: +SKIP

``pcd`` is an ``open3d.t.geometry.PointCloud`` with ``label``, ``visibility`` and ``track_id``.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from .errors import FileFormatError
from .workdir import WorkFolder

if TYPE_CHECKING:
    import open3d as o3d

    from .labelfile import TrajectoryLabels
    from .semantics.semantic_map import SemanticMap
    from .trajectories import Trajectories

__all__ = ["Result", "load"]

logger = logging.getLogger(__name__)


@dataclass(eq=False)
class Result:
    """The trajectories of a work folder with their semantic map and labels.

    Attributes
    ----------
    work : pathlib.Path
    trajectories : Trajectories
        M trajectories over T frames and C cameras.
    semantic_map : SemanticMap or None
        L3D per trajectory, when ``semantic_map.npz`` exists.
    labels : TrajectoryLabels or None
        The graph-cut labels, when ``labels.npz`` exists.
    class_names : tuple of K str
        From the labels or the semantic map (empty without either).
    class_colors : (K, 3) uint8 ndarray or None
        Display colours from the capture's ``labels.toml``, when it can be read.
    """

    work: Path
    trajectories: Trajectories
    semantic_map: SemanticMap | None
    labels: TrajectoryLabels | None
    class_names: tuple[str, ...]
    class_colors: np.ndarray | None

    @property
    def label(self) -> np.ndarray:
        """(M,) int64 label per trajectory: the graph cut's, else the argmax of the semantic
        map's default pooling, else -1."""
        if self.labels is not None:
            return self.labels.labels
        if self.semantic_map is not None:
            return self.semantic_map.argmax_labels()
        return np.full(self.trajectories.num_trajectories, -1, np.int64)

    @property
    def instance(self) -> np.ndarray | None:
        """(M,) int64 person id per trajectory (-1: on no person), or None without one."""
        return None if self.labels is None else self.labels.instance

    def pointcloud(self, frame: int, color_by: str = "label") -> o3d.t.geometry.PointCloud:
        """Frame ``frame`` as an ``open3d.t.geometry.PointCloud``.

        Attributes: ``positions``, ``colors`` (the class colour with ``color_by="label"`` and
        known colours, a colour per person with ``color_by="instance"`` and person ids, else
        the image colour), ``visibility`` (N, C), ``track_id`` (N, 1), ``label`` (N, 1) int32
        (-1: unlabelled) and, with person ids, ``instance`` (N, 1) int32 (-1: no person).
        """
        from .render.palette import label_colors

        colors = None
        if color_by == "label" and self.class_colors is not None:
            colors = label_colors(self.label, self.class_colors)
        elif color_by == "instance" and self.instance is not None:
            from .render.palette import person_palette

            colors = label_colors(
                self.instance, person_palette(int(self.instance.max(initial=-1)) + 1)
            )
        return self.trajectories.to_pointcloud(
            int(frame), labels=self.label, colors=colors, instances=self.instance
        )


def load(work: str | os.PathLike) -> Result:
    """Load a work folder's trajectories, semantic map and labels.

    Parameters
    ----------
    work : path-like
        A work folder holding at least ``trajectories.npz``.

    Returns
    -------
    Result

    Raises
    ------
    FileFormatError
        If ``trajectories.npz`` is missing or a present file is unreadable or inconsistent.
    """
    from .labelfile import load_labels
    from .semantics.semantic_map import SemanticMap
    from .trajectories import Trajectories

    wf = WorkFolder(work)
    if not wf.trajectories.is_file():
        raise FileFormatError(wf.trajectories, "no such file (run `pointtraj reconstruct` first)")
    trajectories = Trajectories.load(wf.trajectories)
    M = trajectories.num_trajectories
    smap = SemanticMap.load(wf.semantic_map) if wf.semantic_map.is_file() else None
    if smap is not None and smap.num_trajectories != M:
        raise FileFormatError(wf.semantic_map, f"has {smap.num_trajectories} trajectories, not {M}")
    labels = load_labels(wf.labels) if wf.labels.is_file() else None
    if labels is not None and len(labels) != M:
        raise FileFormatError(wf.labels, f"has {len(labels)} trajectories, not {M}")
    names: tuple[str, ...] = ()
    if labels is not None:
        names = labels.class_names
    elif smap is not None:
        names = smap.class_names
    return Result(wf.path, trajectories, smap, labels, names, _class_colors(wf, names))


def _class_colors(wf: WorkFolder, names: tuple[str, ...]) -> np.ndarray | None:
    """Colours of ``names`` from the capture's labels.toml (None when unavailable)."""
    from .labelset import LabelSet

    try:
        capture = wf.capture_path()
    except FileFormatError:
        return None
    path = None if capture is None else capture / "labels.toml"
    if path is None or not path.is_file() or not names:
        return None
    try:
        labelset = LabelSet.load(path)
    except FileFormatError as exc:
        logger.warning("no class colours: %s", exc)
        return None
    if tuple(labelset.names) != tuple(names):
        logger.warning("%s lists other classes than the work folder; no class colours", path)
        return None
    return np.asarray(labelset.colors, np.uint8)
