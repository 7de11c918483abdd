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
from ..geometry import axis_angles, finite_rows

__all__ = [
    "ConnectivityGraph",
    "CommonView",
    "build_connectivity",
    "common_view",
    "confirm_connectivity",
    "estimate_capture_volume",
    "working_depths",
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


@dataclass(frozen=True)
class CommonView:
    """The region the cameras' frusta share (:func:`common_view`).

    Attributes
    ----------
    box : (2, 3) float ndarray
        ``[min_corner, max_corner]`` (metres) of the region: the 1st and 99th percentiles of its
        sampled points along each axis.
    min_cameras : int
        A point is in the region when at least this many cameras see it within their depth
        ranges.
    depth_range : (C, 2) float ndarray
        Each camera's ``[near, far]`` depth along its optical axis (metres).
    volume_m3 : float
        Estimated volume of the region itself (not of its box), cubic metres.
    samples : int
        Sampled points that fell in the region.
    """

    box: np.ndarray
    min_cameras: int
    depth_range: np.ndarray
    volume_m3: float
    samples: int

    def summary(self) -> str:
        """One line: the box's size and centre and the region's volume, in the rig's scale."""
        size = self.box[1] - self.box[0]
        unit, k = _length_unit(float(size.max()))
        centre = self.box.mean(axis=0)
        return (
            f"common view (seen by >= {self.min_cameras} cameras within their depth range): "
            f"box {' x '.join(f'{k * s:.3g}' for s in size)} {unit} centred at "
            f"({', '.join(f'{k * c:.3g}' for c in centre)}) {unit}, region "
            f"{self.volume_m3 * k**3:.3g} {unit}^3"
        )


def _length_unit(extent_m: float) -> tuple[str, float]:
    """The unit to print a length of about ``extent_m`` metres in, and the factor from metres."""
    if extent_m < 0.1:
        return "mm", 1000.0
    if extent_m < 1.0:
        return "cm", 100.0
    return "m", 1.0


def working_depths(rig: CameraRig, min_angle_deg: float = 2.0) -> np.ndarray:
    """Each camera's working distance: where its optical axis passes closest to the others'.

    For every other camera whose axis is at least ``min_angle_deg`` from its own, the point of
    the camera's axis nearest to the other axis (both in front of their cameras) gives a depth;
    the working distance is their median. A camera with no such partner (parallel axes, or
    axes that meet behind the cameras) gets twice the median spacing of the rig's cameras.

    Parameters
    ----------
    rig : CameraRig
        C cameras.
    min_angle_deg : float
        Nearly parallel axes give no reliable nearest point and are skipped.

    Returns
    -------
    (C,) float ndarray
        Metres along each optical axis.
    """
    C = len(rig)
    d = rig.R[:, 2]  # (C, 3)
    spacing = 1.0
    if C > 1:
        gaps = np.linalg.norm(rig.C[:, None] - rig.C[None], axis=-1)  # (C, C)
        spacing = float(np.median(gaps[np.triu_indices(C, 1)]))
        spacing = spacing if spacing > 1e-12 else 1.0
    # axes p_i + s d_i and p_j + u d_j: nearest points solve the 2x2 normal equations
    b = np.clip(d @ d.T, -1.0, 1.0)  # (C, C) cos of the angle
    w = rig.C[None, :, :] - rig.C[:, None, :]  # (C, C, 3): C_j - C_i
    wd_i = np.einsum("ijk,ik->ij", w, d)  # w . d_i
    wd_j = np.einsum("ijk,jk->ij", w, d)  # w . d_j
    den = 1.0 - b**2
    ok = den > np.sin(np.radians(min_angle_deg)) ** 2
    np.fill_diagonal(ok, False)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (wd_i - b * wd_j) / den  # depth along axis i
        u = (b * wd_i - wd_j) / den  # depth along axis j
    ok &= (s > 0) & (u > 0)
    has = ok.any(axis=1)
    depth = np.full(C, 2.0 * spacing)
    depth[has] = np.nanmedian(np.where(ok, s, np.nan)[has], axis=1)
    return depth


def common_view(
    rig: CameraRig,
    min_cameras: int | None = None,
    *,
    samples: int = 40000,
    near: float = 0.2,
    far: float = 1.5,
    seed: int = 0,
) -> CommonView:
    """The capture volume from the cameras' frusta: the region seen by several cameras.

    Each camera sees a frustum from ``near`` to ``far`` times its working distance
    (:func:`working_depths`: where its axis passes the others'; a ring of radius r aimed at its
    centre sees half way from its centre to the opposite cameras). Points are sampled uniformly in every frustum,
    and those that at least ``min_cameras`` cameras see within their depth ranges form the
    common view. Everything scales with the rig: the same rig at a thousandth of the size,
    with the same images, gives the same region at a thousandth of the size.

    Parameters
    ----------
    rig : CameraRig
        C cameras.
    min_cameras : int, optional
        Cameras a point of the region needs (default: a third of the rig, at least 2 and at
        most C: 2 on rigs of up to 7 cameras, 3 on the demo's 8, 23 on paper69's 69, whose
        common view is then a 2.9 x 2.8 x 3.1 m box around the paper's 3 m x 2.5 m stage).
    samples : int
        Points sampled over all the frusta.
    near, far : float
        The depth range, as fractions of the working distance.
    seed : int
        Seed of the sampler.

    Returns
    -------
    CommonView
        If no sample is seen by ``min_cameras`` cameras, the box of the points where the
        cameras' axes meet (:func:`working_depths`) is used, with a warning.
    """
    C = len(rig)
    k = max(2, int(round(C / 3))) if min_cameras is None else int(min_cameras)
    k = min(max(k, 1), C)
    work = working_depths(rig)
    lo, hi = near * work, far * work  # (C,)
    rng = np.random.default_rng(seed)
    n = max(int(samples) // C, 200)
    wh = rig.sizes.astype(float)  # (C, 2)
    pix = rng.uniform(0.0, 1.0, size=(C, n, 2)) * wh[:, None, :]  # (C, n, 2)
    # depth with density ~ z^2: uniform in the frustum's volume
    z = np.cbrt(lo[:, None] ** 3 + rng.uniform(size=(C, n)) * (hi**3 - lo**3)[:, None])
    xy = rig.normalized(pix)  # (C, n, 2)
    cam = np.concatenate([xy * z[..., None], z[..., None]], axis=-1)  # (C, n, 3)
    pts = (np.einsum("cji,cnj->cni", rig.R, cam) + rig.C[:, None, :]).reshape(-1, 3)
    ok = finite_rows(pts)
    pts, owner = pts[ok], np.repeat(np.arange(C), n)[ok]
    proj = rig.project(pts)
    inside = proj.in_image & (proj.depth >= lo[:, None]) & (proj.depth <= hi[:, None])
    m = inside.sum(axis=0)  # (S,) cameras seeing each sample
    sel = m >= k
    # the region's volume: each frustum's samples weigh its volume / n, shared by the m frusta
    x = (wh[:, 0] / rig.K[:, 0, 0]) * (wh[:, 1] / rig.K[:, 1, 1])  # image area at depth 1
    frustum = x * (hi**3 - lo**3) / 3.0  # (C,)
    volume = float(np.sum(frustum[owner[sel]] / n / np.maximum(m[sel], 1)))
    if sel.sum() >= 10:
        box = np.percentile(pts[sel], [1.0, 99.0], axis=0)
    else:
        meet = rig.C + work[:, None] * rig.R[:, 2]  # (C, 3)
        box = np.stack([meet.min(axis=0), meet.max(axis=0)])
        pad = 0.05 * float(np.median(work))
        box = box + np.array([[-pad], [pad]])
        logger.warning(
            "capture volume: no point is seen by %d cameras within their depth ranges; "
            "using the box of where their axes pass each other %s (set [reconstruct] "
            "capture_volume to give it)",
            k,
            np.round(box, 4).tolist(),
        )
    return CommonView(box, k, np.stack([lo, hi], axis=1), volume, int(sel.sum()))


def estimate_capture_volume(rig: CameraRig, min_cameras: int | None = None) -> np.ndarray:
    """The capture volume's box from the cameras' frusta (:func:`common_view`).

    Parameters
    ----------
    rig : CameraRig
    min_cameras : int, optional
        See :func:`common_view`.

    Returns
    -------
    (2, 3) float ndarray
        ``[min_corner, max_corner]`` in metres.
    """
    return common_view(rig, min_cameras).box


def build_connectivity(
    rig: CameraRig,
    max_angle_deg: float = 90.0,
    min_overlap: float = 0.2,
    *,
    volume: np.ndarray | None = None,
    samples: int = 20000,
    seed: int = 0,
) -> ConnectivityGraph:
    """Connect the camera pairs worth matching.

    A pair is kept when its viewing directions are at most ``max_angle_deg`` apart and its
    shared view of the capture volume is at least ``min_overlap`` times the rig's reference:
    the median, over the cameras, of each camera's best shared view with a partner within
    ``max_angle_deg``. The cut-off is relative, so it does not depend on how large the volume
    is against the cameras' fields of view. Dropped pairs are logged as warnings with their
    reason, and a warning says when most pairs within the angle are dropped.

    Parameters
    ----------
    rig : CameraRig
        C cameras.
    max_angle_deg : float
        Largest angle between the two viewing directions of an edge (paper: 90 degrees).
    min_overlap : float
        Smallest shared view of an edge, as a fraction of the rig's reference shared view. The
        shared view of a pair is, of the sampled volume points seen by either camera (in front,
        inside the image), the fraction seen by both.
    volume : (2, 3) float ndarray, optional
        Capture volume ``[min_corner, max_corner]`` in metres (default: the cameras' common
        view, :func:`estimate_capture_volume`).
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
        view = common_view(rig, seed=seed)
        box, where = view.box, view.summary()
    else:
        box = check_array("volume", volume, (2, 3), finite=True)
        if np.any(box[1] < box[0]):
            raise ValidationError(f"volume: need [min_corner, max_corner], got {box.tolist()}")
        where = f"capture volume {box.tolist()} (set)"
    logger.info("connectivity: %s", where)
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
    by_angle = angles[i, j] <= max_angle_deg + 1e-9
    # the reference shared view: each camera's best partner within the angle, median over cameras
    near = np.zeros((C, C), bool)
    near[i[by_angle], j[by_angle]] = True
    near |= near.T
    best = np.where(near, overlap, -1.0).max(axis=1)  # (C,)
    reference = float(np.median(best[best >= 0])) if np.any(best >= 0) else 0.0
    by_overlap = (overlap[i, j] >= min_overlap * reference) & (reference > 0)
    keep = by_angle & by_overlap
    if np.any(n == 0):
        logger.warning(
            "connectivity: cameras %s see none of the capture volume %s",
            ", ".join(rig.names[k] for k in np.flatnonzero(n == 0)),
            np.round(box, 4).tolist(),
        )

    def listed(sel: np.ndarray) -> str:
        idx = np.flatnonzero(sel)
        text = ", ".join(
            f"{rig.names[i[k]]}-{rig.names[j[k]]} ({angles[i[k], j[k]]:.0f} deg, "
            f"shared view {overlap[i[k], j[k]]:.2f})"
            for k in idx[:6]
        )
        return text + (f" and {idx.size - 6} more" if idx.size > 6 else "")

    if np.any(~by_angle):
        logger.warning(
            "connectivity: %d of %d camera pairs not matched: their viewing directions are more "
            "than max_angle_deg = %.0f degrees apart: %s",
            int((~by_angle).sum()),
            i.size,
            max_angle_deg,
            listed(~by_angle),
        )
    dropped = by_angle & ~by_overlap
    if np.any(dropped):
        logger.warning(
            "connectivity: %d of %d camera pairs within max_angle_deg not matched: they share "
            "less than min_overlap = %.2f of the rig's reference shared view (%.2f) of the "
            "%s: %s",
            int(dropped.sum()),
            int(by_angle.sum()),
            min_overlap,
            reference,
            where,
            listed(dropped),
        )
    if by_angle.sum() and 0 < reference < 0.1:
        logger.warning(
            "connectivity: the camera pairs share little of the %s (the median camera's best "
            "pair: %.3f of what either sees): the volume is probably much larger than what the "
            "cameras see together; set [reconstruct] capture_volume, or leave it out to take "
            "the cameras' common view",
            where,
            reference,
        )
    if by_angle.sum() and keep.sum() < 0.5 * by_angle.sum():
        logger.warning(
            "connectivity: most of the rig is unused: %d of the %d camera pairs within "
            "max_angle_deg = %.0f degrees are matched. If the subject is much smaller than the "
            "capture volume, set it ([reconstruct] capture_volume = [[xmin, ymin, zmin], "
            "[xmax, ymax, zmax]], metres); see `pointtraj rig info`",
            int(keep.sum()),
            int(by_angle.sum()),
            max_angle_deg,
        )
    graph = ConnectivityGraph(
        camera_names=rig.names,
        edges=np.stack([i[keep], j[keep]], axis=1),
        angles_deg=angles[i, j][keep],
        overlap=overlap[i, j][keep],
        centers=rig.C.copy(),
        directions=rig.R[:, 2].copy(),
    )
    logger.info(
        "connectivity: %d of %d camera pairs kept (reference shared view %.2f)",
        graph.num_edges,
        i.size,
        reference,
    )
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
