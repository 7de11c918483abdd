"""The camera connectivity graph: which camera pairs to match (paper Section 5, step 1).

Two cameras are worth matching when their viewing directions are within ``max_angle_deg``
(the paper: cameras more than 90 degrees apart are unlikely to match) and their fields of view
share part of the capture volume. The shared view is measured by sampling points uniformly in
the capture volume and counting those both cameras see (the Jaccard overlap of the two sets).
Match counts on a first frame can then confirm the edges (:func:`confirm_connectivity`).

The graph is saved as JSON; the format is specified in ``data_specs/connectivity.md``.
"""

from __future__ import annotations

import json
import logging
import os
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..atomic import atomic_path, write_text_atomic
from ..camera import CameraRig
from ..errors import FileFormatError, ValidationError, check_array
from ..geometry import axis_angles

__all__ = [
    "ConnectivityGraph",
    "build_connectivity",
    "confirm_connectivity",
    "estimate_capture_volume",
]

logger = logging.getLogger(__name__)

#: ``format`` field of the JSON file.
FORMAT = "pointtraj-connectivity"
#: ``version`` field of the JSON file.
VERSION = 1


@dataclass(frozen=True, eq=False)
class ConnectivityGraph:
    """An undirected graph over the cameras of a rig.

    Attributes
    ----------
    camera_names : list of str
        C camera names, in rig order; edges refer to these indices.
    edges : (E, 2) int64 ndarray
        Camera index pairs ``i < j``, sorted.
    angles_deg : (E,) float ndarray
        Angle between the two viewing directions, degrees.
    match_counts : (E,) int64 ndarray or None
        Matches found per edge on a confirmation frame (see :func:`confirm_connectivity`).
    overlap : (E,) float ndarray or None
        Shared-view fraction of each edge (Jaccard overlap of the sampled capture volume).
    centers : (C, 3) float ndarray or None
        Camera centres (for :meth:`plot`).
    directions : (C, 3) float ndarray or None
        Unit viewing directions (for :meth:`plot`).
    """

    camera_names: list[str]
    edges: np.ndarray
    angles_deg: np.ndarray
    match_counts: np.ndarray | None = None
    overlap: np.ndarray | None = None
    centers: np.ndarray | None = None
    directions: np.ndarray | None = None

    def __post_init__(self) -> None:
        names = [str(n) for n in self.camera_names]
        if len(set(names)) != len(names):
            raise ValidationError("ConnectivityGraph: camera_names repeat")
        C = len(names)
        edges = check_array("edges", np.reshape(self.edges, (-1, 2)), (None, 2), dtype=np.int64)
        E = edges.shape[0]
        if E and (edges.min() < 0 or edges.max() >= C or np.any(edges[:, 0] >= edges[:, 1])):
            raise ValidationError(f"edges: need index pairs i < j within [0, {C}), got {edges}")
        if np.unique(edges, axis=0).shape[0] != E:
            raise ValidationError("edges: repeated camera pairs")
        order = np.lexsort((edges[:, 1], edges[:, 0]))
        fields: dict[str, object] = {"camera_names": names, "edges": edges[order]}
        fields["angles_deg"] = check_array("angles_deg", self.angles_deg, (E,))[order]
        for name, dtype in (("match_counts", np.int64), ("overlap", float)):
            value = getattr(self, name)
            if value is not None:
                fields[name] = check_array(name, value, (E,), dtype=dtype)[order]
        for name in ("centers", "directions"):
            value = getattr(self, name)
            if value is not None:
                fields[name] = check_array(name, value, (C, 3), finite=True)
        for name, value in fields.items():
            object.__setattr__(self, name, value)

    # -- queries -----------------------------------------------------------------------------
    @property
    def num_cameras(self) -> int:
        return len(self.camera_names)

    @property
    def num_edges(self) -> int:
        return int(self.edges.shape[0])

    def degree(self) -> np.ndarray:
        """(C,) int64: number of edges at each camera."""
        return np.bincount(self.edges.ravel(), minlength=self.num_cameras)

    def adjacency(self) -> np.ndarray:
        """(C, C) bool symmetric adjacency matrix."""
        A = np.zeros((self.num_cameras, self.num_cameras), bool)
        A[self.edges[:, 0], self.edges[:, 1]] = True
        return A | A.T

    def neighbors(self, camera: int | str) -> np.ndarray:
        """Indices of the cameras connected to ``camera`` (an index or a name)."""
        i = self._index(camera)
        return np.flatnonzero(self.adjacency()[i])

    def pairs(self) -> list[tuple[str, str]]:
        """The edges as camera-name pairs."""
        return [(self.camera_names[i], self.camera_names[j]) for i, j in self.edges]

    def _index(self, camera: int | str) -> int:
        if isinstance(camera, str):
            if camera not in self.camera_names:
                raise ValidationError(
                    f"no camera named {camera!r}; the graph has {', '.join(self.camera_names)}"
                )
            return self.camera_names.index(camera)
        i = int(camera)
        if not 0 <= i < self.num_cameras:
            raise ValidationError(f"camera index {i} out of range [0, {self.num_cameras})")
        return i

    def summary(self) -> str:
        """A human-readable description: edge count, degrees, angles, neighbours per camera."""
        deg = self.degree()
        lines = [
            f"connectivity graph: {self.num_cameras} cameras, {self.num_edges} edges "
            f"(degree min {deg.min()}, mean {deg.mean():.1f}, max {deg.max()})"
        ]
        if self.num_edges:
            a = self.angles_deg
            lines.append(
                f"angle between viewing directions: min {a.min():.1f}, "
                f"median {np.median(a):.1f}, max {a.max():.1f} degrees"
            )
        if self.overlap is not None and self.num_edges:
            lines.append(
                f"shared view (overlap): min {self.overlap.min():.2f}, "
                f"median {np.median(self.overlap):.2f}"
            )
        if self.match_counts is not None and self.num_edges:
            lines.append(
                f"confirming matches per edge: min {self.match_counts.min()}, "
                f"median {int(np.median(self.match_counts))}"
            )
        isolated = [self.camera_names[i] for i in np.flatnonzero(deg == 0)]
        if isolated:
            lines.append(f"isolated cameras (nothing to match): {', '.join(isolated)}")
        width = max(6, *(len(n) for n in self.camera_names))
        lines.append(f"{'camera':<{width}}  degree  neighbours")
        A = self.adjacency()
        for i, name in enumerate(self.camera_names):
            nb = " ".join(self.camera_names[j] for j in np.flatnonzero(A[i]))
            lines.append(f"{name:<{width}}  {deg[i]:>6}  {nb}")
        return "\n".join(lines)

    # -- output ------------------------------------------------------------------------------
    def plot(self, path: str | os.PathLike, rig: CameraRig | None = None) -> None:
        """Write a PNG: top view (x, y) of the cameras, their viewing directions and the edges.

        Parameters
        ----------
        path : path-like
            Destination PNG, written atomically.
        rig : CameraRig, optional
            Where to take camera positions from when the graph does not store them.

        Raises
        ------
        ValidationError
            If neither the graph nor ``rig`` gives camera positions.
        """
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        from matplotlib.collections import LineCollection

        if rig is not None:
            if rig.names != self.camera_names:
                raise ValidationError("plot: the rig's camera names differ from the graph's")
            centers, dirs = rig.C, rig.R[:, 2]
        elif self.centers is not None and self.directions is not None:
            centers, dirs = self.centers, self.directions
        else:
            raise ValidationError(
                "plot: the graph stores no camera positions; pass the rig (plot(path, rig))"
            )
        fig, ax = plt.subplots(figsize=(7, 7))
        try:
            seg = centers[self.edges][:, :, :2]  # (E, 2, 2)
            colors = None
            if self.match_counts is not None and self.num_edges:
                colors = plt.cm.viridis(self.match_counts / max(self.match_counts.max(), 1))
            ax.add_collection(
                LineCollection(
                    seg,
                    colors=colors if colors is not None else "tab:blue",
                    lw=0.5,
                    alpha=0.35,
                    zorder=1,
                )
            )
            span = np.ptp(centers[:, :2], axis=0).max() if len(centers) > 1 else 1.0
            arrow = 0.08 * max(span, 1e-6)
            ax.quiver(
                centers[:, 0],
                centers[:, 1],
                dirs[:, 0],
                dirs[:, 1],
                angles="xy",
                scale_units="xy",
                scale=1.0 / arrow,
                color="tab:red",
                width=0.004,
                zorder=4,
            )
            deg = self.degree()
            ax.scatter(centers[:, 0], centers[:, 1], c="k", s=12, zorder=5)
            for i, name in enumerate(self.camera_names):
                ax.annotate(
                    f"{name} ({deg[i]})", centers[i, :2], fontsize=6, xytext=(3, 3),
                    textcoords="offset points",
                )  # fmt: skip
            ax.set_aspect("equal")
            ax.autoscale()
            ax.margins(0.1)
            ax.set_xlabel("x (m)")
            ax.set_ylabel("y (m)")
            ax.set_title(f"camera connectivity: {self.num_cameras} cameras, {self.num_edges} edges")
            with atomic_path(path) as tmp:
                fig.savefig(tmp, format="png", dpi=120)
        finally:
            plt.close(fig)

    def to_dict(self) -> dict:
        """The JSON-ready dictionary of ``data_specs/connectivity.md``."""

        def opt(a: np.ndarray | None) -> list | None:
            return None if a is None else a.tolist()

        return {
            "format": FORMAT,
            "version": VERSION,
            "camera_names": list(self.camera_names),
            "edges": self.edges.tolist(),
            "angles_deg": self.angles_deg.tolist(),
            "overlap": opt(self.overlap),
            "match_counts": opt(self.match_counts),
            "centers": opt(self.centers),
            "directions": opt(self.directions),
        }

    def save(self, path: str | os.PathLike) -> None:
        """Write the graph as JSON (atomically); see ``data_specs/connectivity.md``."""
        write_text_atomic(path, json.dumps(self.to_dict(), indent=1) + "\n")

    @classmethod
    def load(cls, path: str | os.PathLike) -> ConnectivityGraph:
        """Read a graph written by :meth:`save`.

        Raises
        ------
        FileFormatError
            If the file is missing, not JSON, or a field is missing or malformed.
        """
        path = Path(path)
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except FileNotFoundError:
            raise FileFormatError(path, "file not found") from None
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise FileFormatError(path, f"not a readable JSON file: {exc}") from None
        if not isinstance(data, dict) or data.get("format") != FORMAT:
            raise FileFormatError(path, f"field 'format' must be {FORMAT!r}")
        if data.get("version") != VERSION:
            raise FileFormatError(
                path, f"field 'version': unsupported {data.get('version')!r} (expected {VERSION})"
            )
        for key in ("camera_names", "edges", "angles_deg"):
            if key not in data:
                raise FileFormatError(path, f"missing field {key!r}")
        if not isinstance(data["camera_names"], list) or not all(
            isinstance(n, str) for n in data["camera_names"]
        ):
            raise FileFormatError(path, "field 'camera_names' must be a list of strings")
        try:
            return cls(
                camera_names=data["camera_names"],
                edges=np.asarray(data["edges"], dtype=np.int64).reshape(-1, 2),
                angles_deg=np.asarray(data["angles_deg"], dtype=float),
                match_counts=_opt_array(data.get("match_counts"), np.int64),
                overlap=_opt_array(data.get("overlap"), float),
                centers=_opt_array(data.get("centers"), float),
                directions=_opt_array(data.get("directions"), float),
            )
        except (ValidationError, TypeError, ValueError) as exc:
            raise FileFormatError(path, str(exc)) from None


def _opt_array(value: object, dtype: type) -> np.ndarray | None:
    return None if value is None else np.asarray(value, dtype=dtype)


def estimate_capture_volume(rig: CameraRig) -> np.ndarray:
    """Guess the capture volume from where the cameras look.

    The centre is the least-squares point closest to all optical axes; the half-size is half
    the median camera distance to it, so a ring of radius r gives a cube of side r centred
    where the axes meet. If the axes are (near) parallel or meet behind the cameras, the
    centre is placed in front of the rig, twice the median camera spacing along the mean
    viewing direction.

    Parameters
    ----------
    rig : CameraRig

    Returns
    -------
    (2, 3) float ndarray
        ``[min_corner, max_corner]`` in metres.
    """
    d = rig.R[:, 2]  # (C, 3) viewing directions
    proj = np.eye(3) - d[:, :, None] * d[:, None, :]  # (C, 3, 3) projectors off each axis
    A = proj.sum(axis=0)
    b = np.einsum("cij,cj->i", proj, rig.C)
    ev = np.linalg.eigvalsh(A)
    spacing = 1.0
    if len(rig) > 1:
        gaps = np.linalg.norm(rig.C[:, None] - rig.C[None], axis=-1)  # (C, C)
        spacing = float(np.median(gaps[np.triu_indices(len(rig), 1)]))
        spacing = spacing if spacing > 1e-9 else 1.0
    if ev[0] > 1e-3 * ev[-1] and len(rig) > 1:
        center = np.linalg.solve(A, b)
        depth = np.einsum("ci,ci->c", center - rig.C, d)
        if np.median(depth) <= 0:  # the axes meet behind the cameras: fall back
            center = rig.C.mean(0) + d.mean(0) * 2 * spacing
    else:
        center = rig.C.mean(0) + d.mean(0) * 2 * spacing
    half = 0.5 * float(np.median(np.linalg.norm(rig.C - center, axis=1)))
    half = half if half > 1e-9 else 1.0
    return np.stack([center - half, center + half])


def build_connectivity(
    rig: CameraRig,
    max_angle_deg: float = 90.0,
    min_overlap: float = 0.05,
    *,
    volume: np.ndarray | None = None,
    samples: int = 20000,
    seed: int = 0,
) -> ConnectivityGraph:
    """Connect the camera pairs worth matching.

    Parameters
    ----------
    rig : CameraRig
        C cameras.
    max_angle_deg : float
        Largest angle between the two viewing directions of an edge (paper: 90 degrees).
    min_overlap : float
        Smallest shared-view fraction of an edge: of the sampled volume points seen by either
        camera (in front, inside the image), the fraction seen by both.
    volume : (2, 3) float ndarray, optional
        Capture volume ``[min_corner, max_corner]`` in metres (default:
        :func:`estimate_capture_volume`).
    samples : int
        Points sampled uniformly in the volume.
    seed : int
        Seed of the sampler.

    Returns
    -------
    ConnectivityGraph
        With ``angles_deg``, ``overlap``, camera centres and directions filled in.

    Raises
    ------
    ValidationError
        On an out-of-range angle or overlap, a bad volume, or fewer than one sample.

    Examples
    --------
    >>> import numpy as np
    >>> from pointtraj.camera import Camera, CameraRig
    >>> rig = CameraRig([Camera.look_at(f"c{i}", [3 * np.cos(a), 3 * np.sin(a), 1], [0, 0, 1],
    ...                  (640, 480), 500.0) for i, a in enumerate(np.linspace(0, 2 * np.pi, 8,
    ...                  endpoint=False))])
    >>> g = build_connectivity(rig)  # neighbours up to 90 degrees apart
    >>> g.num_edges, g.degree().tolist()
    (16, [4, 4, 4, 4, 4, 4, 4, 4])
    """
    if not isinstance(rig, CameraRig):
        raise ValidationError(f"rig: expected a CameraRig, got {type(rig).__name__}")
    if not 0 <= max_angle_deg <= 180:
        raise ValidationError(f"max_angle_deg must be in [0, 180], got {max_angle_deg!r}")
    if not 0 <= min_overlap <= 1:
        raise ValidationError(f"min_overlap must be in [0, 1], got {min_overlap!r}")
    if int(samples) < 1:
        raise ValidationError(f"samples must be >= 1, got {samples!r}")
    if volume is None:
        box = estimate_capture_volume(rig)
    else:
        box = check_array("volume", volume, (2, 3), finite=True)
        if np.any(box[1] < box[0]):
            raise ValidationError(f"volume: need [min_corner, max_corner], got {box.tolist()}")
    C = len(rig)
    angles = axis_angles(rig)  # (C, C)
    rng = np.random.default_rng(seed)
    pts = rng.uniform(box[0], box[1], size=(int(samples), 3))  # (S, 3)
    seen = rig.project(pts).in_image.astype(np.float64)  # (C, S)
    both = seen @ seen.T  # (C, C) counts seen by both
    n = np.diag(both)
    either = n[:, None] + n[None, :] - both
    overlap = np.where(either > 0, both / np.maximum(either, 1), 0.0)
    i, j = np.triu_indices(C, 1)
    keep = (angles[i, j] <= max_angle_deg + 1e-9) & (overlap[i, j] >= min_overlap)
    if np.any(n == 0):
        logger.warning(
            "cameras %s see none of the sampled capture volume %s",
            [rig.names[k] for k in np.flatnonzero(n == 0)],
            box.tolist(),
        )
    graph = ConnectivityGraph(
        camera_names=rig.names,
        edges=np.stack([i[keep], j[keep]], axis=1),
        angles_deg=angles[i, j][keep],
        overlap=overlap[i, j][keep],
        centers=rig.C.copy(),
        directions=rig.R[:, 2].copy(),
    )
    logger.info("connectivity: %d of %d camera pairs kept", graph.num_edges, i.size)
    return graph


def confirm_connectivity(
    graph: ConnectivityGraph, counts: np.ndarray, min_matches: int
) -> ConnectivityGraph:
    """Keep the edges confirmed by enough matches on a first frame.

    Parameters
    ----------
    graph : ConnectivityGraph
    counts : (E,) int ndarray or (C, C) int ndarray
        Matches per edge of ``graph`` in edge order, or a camera-by-camera matrix (the larger
        of ``counts[i, j]`` and ``counts[j, i]`` is used, so either triangle may be filled).
    min_matches : int
        Edges with fewer matches are dropped.

    Returns
    -------
    ConnectivityGraph
        The kept edges, with ``match_counts`` set.

    Raises
    ------
    ValidationError
        If ``counts`` has neither shape, or is negative.
    """
    if not isinstance(graph, ConnectivityGraph):
        raise ValidationError(f"graph: expected a ConnectivityGraph, got {type(graph).__name__}")
    c = np.asarray(counts)
    C, E = graph.num_cameras, graph.num_edges
    if c.shape == (C, C) and c.shape != (E,):
        m = np.maximum(c, c.T)
        per_edge = m[graph.edges[:, 0], graph.edges[:, 1]]
    elif c.shape == (E,):
        per_edge = c
    else:
        raise ValidationError(
            f"counts: expected shape ({E},) (one per edge) or ({C}, {C}), got {c.shape}"
        )
    per_edge = check_array("counts", per_edge, (E,), dtype=np.int64)
    if np.any(per_edge < 0):
        raise ValidationError("counts: match counts must be >= 0")
    keep = per_edge >= int(min_matches)
    out = replace(
        graph,
        edges=graph.edges[keep],
        angles_deg=graph.angles_deg[keep],
        match_counts=per_edge[keep],
        overlap=None if graph.overlap is None else graph.overlap[keep],
    )
    logger.info(
        "connectivity: %d of %d edges confirmed by >= %d matches", keep.sum(), E, min_matches
    )
    return out
