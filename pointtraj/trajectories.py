"""The ragged trajectory store: M fragmented 3D trajectories with P point-frames in all.

A CSR-like layout (see ``data_specs/trajectories.md``): trajectory ``m`` lives in frames
``first_frame[m] .. first_frame[m] + length[m] - 1`` and its point-frames are rows
``offsets[m] .. offsets[m + 1] - 1`` of the per-point-frame arrays. Visibility is quantised to
uint8 (``V * 255``), so 10^6 trajectories x 30 frames x 69 cameras take about 2 GB.

A frame-major index (built lazily, O(P)) reads frame t's points in O(N_t).
"""

from __future__ import annotations

import logging
import os
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .atomic import atomic_path, save_npz_atomic, verify_file
from .errors import FileFormatError, ValidationError, check_array
from .geometry import finite_rows

if TYPE_CHECKING:  # pragma: no cover
    import open3d as o3d

__all__ = [
    "Trajectories",
    "FrameSlice",
    "quantize_visibility",
    "dequantize_visibility",
    "CLOUD_VISIBILITY",
]

logger = logging.getLogger(__name__)

FORMAT_VERSION = 1


def quantize_visibility(v: np.ndarray) -> np.ndarray:
    """Visibility probabilities in [0, 1] (NaN means 0) to uint8 (``round(255 V)``)."""
    v = np.nan_to_num(np.asarray(v, dtype=np.float32), nan=0.0)
    return np.clip(np.rint(v * 255.0), 0, 255).astype(np.uint8)


def dequantize_visibility(q: np.ndarray) -> np.ndarray:
    """uint8 visibility back to float32 probabilities in [0, 1]."""
    return np.asarray(q, dtype=np.float32) * np.float32(1.0 / 255.0)


#: A view counts as observed where the stored visibility exceeds this (the tracker's default
#: ``visibility_threshold``, 0.05, quantised).
OBSERVED_MIN = 13


def view_counts(visibility: np.ndarray) -> np.ndarray:
    """Cameras observing each point-frame (uint8 visibility above :data:`OBSERVED_MIN`).

    Parameters
    ----------
    visibility : (P, C) uint8 ndarray

    Returns
    -------
    (P,) uint8 ndarray
        A point-frame with 3 or more is *verified*: its views check each other (a two-view
        point always agrees with itself).
    """
    return np.count_nonzero(np.asarray(visibility) >= OBSERVED_MIN, axis=1).astype(np.uint8)


#: The forms a cloud's visibility can take in ``clouds/<t>.ply`` (``data_specs/work_folder.md``):
#: ``"full"``, C float32 columns (the default, for Open3D users); ``"uint8"``, C uint8 columns
#: holding the store's quantised values (exact, a quarter of the size; PLY and Open3D have no
#: float16); ``"sparse"``, only the observed views (visibility at least :data:`OBSERVED_MIN`),
#: as a second PLY element ``view`` (``camera``, ``visibility`` uint8) in vertex order,
#: ``num_views`` of them per vertex; Open3D reads the vertices and skips that element.
CLOUD_VISIBILITY = ("full", "uint8", "sparse")


def check_choice(name: str, form: str) -> None:
    """Refuse a cloud visibility form that is not one of :data:`CLOUD_VISIBILITY`."""
    if form not in CLOUD_VISIBILITY:
        raise ValidationError(
            f"{name} must be one of {', '.join(repr(f) for f in CLOUD_VISIBILITY)}, got {form!r}"
        )


def frame_pointcloud(
    xyz: np.ndarray,
    color: np.ndarray,
    visibility: np.ndarray,
    track_id: np.ndarray,
    label: np.ndarray | None = None,
    visibility_form: str = "full",
    instance: np.ndarray | None = None,
) -> o3d.t.geometry.PointCloud:
    """One frame's points as an Open3D point cloud with pointtraj's attributes.

    Parameters
    ----------
    xyz : (N, 3) float ndarray
    color : (N, 3) uint8 ndarray
    visibility : (N, C) uint8 ndarray
        Quantised visibility (:func:`quantize_visibility`).
    track_id : (N,) int ndarray
    label : (N,) int ndarray, optional
    visibility_form : {"full", "uint8", "sparse"}
        How ``visibility`` is kept (:data:`CLOUD_VISIBILITY`): (N, C) float32 probabilities
        (the default, for Open3D users), (N, C) uint8 as the store quantises it, or not at all
        (:func:`write_cloud_ply` then writes the observed views, given ``views``).
    instance : (N,) int ndarray, optional
        Person id (-1: none).

    Returns
    -------
    open3d.t.geometry.PointCloud
        ``positions`` (N, 3) float32, ``colors`` (N, 3) float32 in [0, 1], ``visibility``
        (N, C) float32 or uint8 (none in the sparse form), ``num_views`` (N, 1) uint8
        (:func:`view_counts`), ``verified`` (N, 1) uint8 (1 where ``num_views >= 3``),
        ``track_id`` (N, 1) int64, ``label`` (N, 1) int32 and ``instance`` (N, 1) int32.
    """
    import open3d as o3d

    check_choice("visibility_form", visibility_form)
    pcd = o3d.t.geometry.PointCloud(o3d.core.Tensor(np.ascontiguousarray(xyz, np.float32)))
    pcd.point.colors = o3d.core.Tensor(np.asarray(color, np.float32) / 255.0)
    if visibility_form == "full":
        pcd.point.visibility = o3d.core.Tensor(
            np.ascontiguousarray(dequantize_visibility(visibility))
        )
    elif visibility_form == "uint8":
        pcd.point.visibility = o3d.core.Tensor(np.ascontiguousarray(visibility, np.uint8))
    views = view_counts(visibility)
    pcd.point.num_views = o3d.core.Tensor(views[:, None])
    pcd.point.verified = o3d.core.Tensor((views >= 3).astype(np.uint8)[:, None])
    pcd.point.track_id = o3d.core.Tensor(np.asarray(track_id, np.int64)[:, None])
    if label is not None:
        pcd.point.label = o3d.core.Tensor(np.asarray(label, np.int32)[:, None])
    if instance is not None:
        pcd.point.instance = o3d.core.Tensor(np.asarray(instance, np.int32)[:, None])
    return pcd


def load_cloud(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Read a ``clouds/<t>.ply`` that pointtraj wrote back into arrays.

    Parameters
    ----------
    path : path-like

    Returns
    -------
    dict
        ``xyz`` (N, 3) float32, ``color`` (N, 3) uint8, ``visibility`` (N, C) float32 (the
        PLY's ``visibility_0 .. visibility_{C-1}`` restacked, dequantised where they are
        uint8; in the sparse form the observed views, 0 elsewhere: every form of
        :data:`CLOUD_VISIBILITY`), ``track_id`` (N,) int64, and,
        where present, ``num_views`` (N,) uint8, ``verified`` (N,) bool, ``label`` (N,) int32
        and ``instance`` (N,) int32.

    Raises
    ------
    FileFormatError
        If the file is missing, unreadable or lacks positions or track ids.
    """
    import open3d as o3d

    path = Path(path)
    if not path.is_file():
        raise FileFormatError(path, "no such file")
    problem = verify_file(path, ".ply")
    if problem is not None:
        raise FileFormatError(path, f"not a complete PLY file ({problem})")
    pcd = o3d.t.io.read_point_cloud(str(path))
    attrs = {k: pcd.point[k].numpy() for k in pcd.point}
    if "positions" not in attrs or "track_id" not in attrs:
        raise FileFormatError(path, "not a pointtraj cloud (no positions or track_id)")
    n = len(attrs["positions"])
    cols = sorted(
        (k for k in attrs if re.fullmatch(r"visibility_\d+", k)), key=lambda k: int(k[11:])
    )
    if cols:
        stacked = np.hstack([attrs[k] for k in cols])
        vis = (
            dequantize_visibility(stacked)
            if stacked.dtype == np.uint8
            else stacked.astype(np.float32)
        )
    else:
        nv = attrs["num_views"].reshape(-1) if "num_views" in attrs else None
        vis = _sparse_visibility(path, nv)
        if vis is None:
            vis = np.zeros((n, 0), np.float32)
    out = {
        "xyz": attrs["positions"].astype(np.float32),
        "color": np.clip(np.rint(attrs.get("colors", np.zeros((n, 3))) * 255), 0, 255).astype(
            np.uint8
        ),
        "visibility": vis,
        "track_id": attrs["track_id"].reshape(-1).astype(np.int64),
    }
    if "num_views" in attrs:
        out["num_views"] = attrs["num_views"].reshape(-1).astype(np.uint8)
    if "verified" in attrs:
        out["verified"] = attrs["verified"].reshape(-1).astype(bool)
    if "label" in attrs:
        out["label"] = attrs["label"].reshape(-1).astype(np.int32)
    if "instance" in attrs:
        out["instance"] = attrs["instance"].reshape(-1).astype(np.int32)
    return out


def _empty_ply_header(pcd: o3d.t.geometry.PointCloud) -> str:
    """A binary PLY with no vertex and the point attributes of ``pcd`` (as Open3D names them)."""
    lines = ["ply", "format binary_little_endian 1.0", "comment Created by pointtraj"]
    lines.append("element vertex 0")
    present = list(pcd.point)
    first = [k for k in ("positions", "colors") if k in present]
    for key in first + sorted(k for k in present if k not in first):
        tensor = pcd.point[key]
        kind = "float" if "Float" in str(tensor.dtype) else "int"
        if key == "positions":
            names = ["x", "y", "z"]
        elif key == "colors":
            names = ["red", "green", "blue"]
        else:
            width = int(tensor.shape[1]) if len(tensor.shape) > 1 else 1
            names = [key] if width == 1 else [f"{key}_{i}" for i in range(width)]
        lines += [f"property {kind} {n}" for n in names]
    return "\n".join([*lines, "end_header"]) + "\n"


def write_cloud_ply(
    path: str | os.PathLike, pcd: o3d.t.geometry.PointCloud, views: np.ndarray | None = None
) -> None:
    """Write a point cloud as PLY, atomically; a cloud without points too (Open3D refuses it).

    Parameters
    ----------
    path : path-like
    pcd : open3d.t.geometry.PointCloud
        Its attributes become PLY properties (``visibility`` (N, C) as ``visibility_0`` ...).
        PLY has no 64-bit integers: Int64 attributes (``track_id``) are written as int32.
    views : (N, C) uint8 ndarray, optional
        Quantised visibility to write sparse (:data:`CLOUD_VISIBILITY`): the observed views
        follow the vertices as the element ``view``, and the header says
        ``comment pointtraj visibility sparse C``.

    Raises
    ------
    FileFormatError
        If Open3D cannot write the file.
    """
    import open3d as o3d

    for key in list(pcd.point):
        if pcd.point[key].dtype == o3d.core.Dtype.Int64:
            pcd.point[key] = pcd.point[key].to(o3d.core.Dtype.Int32)
    with atomic_path(path) as tmp:
        if len(pcd.point.positions) == 0:
            tmp.write_text(_empty_ply_header(pcd), encoding="ascii")
        elif not o3d.t.io.write_point_cloud(str(tmp), pcd):
            raise FileFormatError(path, "Open3D failed to write the point cloud")
        if views is not None:
            _append_views(tmp, views)


def _append_views(path: Path, views: np.ndarray) -> None:
    """Add the observed views of ``views`` (N, C) uint8 to a binary PLY as the element ``view``."""
    q = np.asarray(views, np.uint8)
    C = q.shape[1]
    rows, cams = np.nonzero(q >= OBSERVED_MIN)  # vertex order, cameras ascending
    kind, dtype = ("uchar", np.uint8) if C <= 256 else ("ushort", np.dtype("<u2"))
    table = np.empty(len(rows), dtype=[("camera", dtype), ("visibility", np.uint8)])
    table["camera"] = cams
    table["visibility"] = q[rows, cams]
    data = path.read_bytes()
    end = data.index(b"end_header\n")
    extra = (
        f"comment pointtraj visibility sparse {C}\nelement view {len(rows)}\n"
        f"property {kind} camera\nproperty uchar visibility\n"
    )
    path.write_bytes(data[:end] + extra.encode("ascii") + data[end:] + table.tobytes())


def _sparse_visibility(path: Path, num_views: np.ndarray | None) -> np.ndarray | None:
    """The (N, C) float32 visibility of a cloud written sparse, or None for another form.

    Raises
    ------
    FileFormatError
        If the ``view`` element disagrees with the vertices' ``num_views``.
    """
    from .atomic import _PLY_SIZES

    with open(path, "rb") as f:
        head = f.read(65536)
    end = head.find(b"end_header\n")
    lines = head[:end].decode("ascii", "replace").splitlines()
    sparse = [ln.split() for ln in lines if ln.startswith("comment pointtraj visibility sparse")]
    if not sparse:
        return None
    C = int(sparse[0][4])
    elements: list[list] = []  # [name, count, [(type, name), ...]]
    for line in lines:
        words = line.split()
        if words[:1] == ["element"]:
            elements.append([words[1], int(words[2]), []])
        elif words[:1] == ["property"] and elements:
            elements[-1][2].append((words[1], words[2]))
    offset = end + len(b"end_header\n")
    for name, count, props in elements:
        if name == "view":
            break
        offset += count * sum(_PLY_SIZES[t] for t, _ in props)
    else:
        raise FileFormatError(path, "a sparse-visibility cloud without its 'view' element")
    _, count, props = elements[[e[0] for e in elements].index("view")]
    np_types = {"uchar": np.uint8, "ushort": np.dtype("<u2")}
    table = np.fromfile(
        path, dtype=[(n, np_types[t]) for t, n in props], count=count, offset=offset
    )
    N = 0 if num_views is None else len(num_views)
    if num_views is None or len(table) != count or int(num_views.sum()) != count:
        raise FileFormatError(
            path, f"its {count} views do not match the vertices' num_views (or it has none)"
        )
    vis = np.zeros((N, C), np.float32)
    rows = np.repeat(np.arange(N), num_views.astype(np.int64))
    vis[rows, table["camera"].astype(np.int64)] = dequantize_visibility(table["visibility"])
    return vis


def _check_finite_xyz(path: Path, xyz: np.ndarray) -> None:
    """Refuse NaN or infinite positions: every row of the ragged store is a live point-frame.

    Parameters
    ----------
    path : pathlib.Path
        The store, for the message.
    xyz : (P, 3) ndarray
        Positions as read.

    Raises
    ------
    FileFormatError
        Naming the file and the number of non-finite point-frames.
    """
    if not np.issubdtype(xyz.dtype, np.number) or xyz.ndim != 2:
        return  # the shape and type checks of the constructor name the problem
    bad = ~np.isfinite(xyz).all(axis=1)  # (P,)
    if bad.any():
        first = int(np.flatnonzero(bad)[0])
        raise FileFormatError(
            path,
            f"xyz: {int(bad.sum())} of {len(xyz)} point-frames are NaN or infinite (first at "
            f"row {first}); every point-frame of the store is a live point",
        )


@dataclass(frozen=True)
class FrameSlice:
    """The point-frames of one frame.

    Attributes
    ----------
    frame : int
    track_id : (N,) int64 ndarray
        Trajectory index of each point.
    rows : (N,) int64 ndarray
        Row of each point in the store's per-point-frame arrays.
    xyz : (N, 3) float32 ndarray
    visibility : (N, C) float32 ndarray
        Dequantised visibility probabilities.
    """

    frame: int
    track_id: np.ndarray
    rows: np.ndarray
    xyz: np.ndarray
    visibility: np.ndarray


@dataclass(eq=False)
class Trajectories:
    """Ragged store of M trajectories with P point-frames, seen by C cameras.

    Parameters
    ----------
    first_frame : (M,) int64 ndarray
        Frame where each trajectory emerges.
    offsets : (M + 1,) int64 ndarray
        Trajectory m's rows are ``offsets[m]:offsets[m + 1]``; ``offsets[0] == 0``.
    xyz : (P, 3) float32 ndarray
        World position per point-frame, metres.
    visibility : (P, C) uint8 ndarray
        Quantised visibility probability per camera (see :func:`quantize_visibility`).
    reprojection_error : (P,) float32 ndarray
        Mean reprojection error over the visible cameras, pixels (NaN if unknown).
    color : (P, 3) uint8 ndarray
        RGB colour per point-frame.
    camera_names : list of str
        Names of the C cameras, in the order of ``visibility``'s columns.
    fps : float
        Frame rate of the capture.
    num_frames : int
        Number of frames T of the capture (at least ``max(last_frame) + 1``).

    Raises
    ------
    ValidationError
        If the arrays are inconsistent.
    """

    first_frame: np.ndarray
    offsets: np.ndarray
    xyz: np.ndarray
    visibility: np.ndarray
    reprojection_error: np.ndarray
    color: np.ndarray
    camera_names: list[str] = field(default_factory=list)
    fps: float = 30.0
    num_frames: int = 0

    def __post_init__(self) -> None:
        self.first_frame = check_array("first_frame", self.first_frame, (None,), dtype=np.int64)
        M = self.first_frame.shape[0]
        self.offsets = check_array("offsets", self.offsets, (M + 1,), dtype=np.int64)
        P = int(self.offsets[-1]) if M else 0
        if self.offsets[0] != 0 or np.any(np.diff(self.offsets) < 1):
            raise ValidationError(
                "offsets must start at 0 and increase (every trajectory non-empty)"
            )
        if np.any(self.first_frame < 0):
            raise ValidationError("first_frame must be non-negative")
        C = len(self.camera_names)
        self.xyz = check_array("xyz", self.xyz, (P, 3), dtype=np.float32)
        self.visibility = check_array("visibility", self.visibility, (P, C), dtype=None)
        if self.visibility.dtype != np.uint8:
            raise ValidationError(
                f"visibility must be quantised uint8 (use quantize_visibility), got {self.visibility.dtype}"
            )
        self.reprojection_error = check_array(
            "reprojection_error", self.reprojection_error, (P,), dtype=np.float32
        )
        self.color = check_array("color", self.color, (P, 3), dtype=np.uint8)
        last = int(self.last_frame.max()) + 1 if M else 0
        self.num_frames = max(int(self.num_frames), last)
        self.fps = float(self.fps)
        self.camera_names = [str(n) for n in self.camera_names]

    # -- basic properties --------------------------------------------------------------------
    @property
    def num_trajectories(self) -> int:
        """M."""
        return int(self.first_frame.shape[0])

    def __len__(self) -> int:
        return self.num_trajectories

    @property
    def num_point_frames(self) -> int:
        """P, the sum of trajectory lengths."""
        return int(self.offsets[-1])

    @property
    def num_cameras(self) -> int:
        """C."""
        return len(self.camera_names)

    @property
    def lengths(self) -> np.ndarray:
        """(M,) int64 number of frames of each trajectory."""
        return np.diff(self.offsets)

    @property
    def last_frame(self) -> np.ndarray:
        """(M,) int64 last frame of each trajectory (inclusive)."""
        return self.first_frame + self.lengths - 1

    @property
    def occupied_frames(self) -> range:
        """The frames from the first to the last where a trajectory lives (empty without any).

        A reconstruction of frames ``A:B`` of a longer capture has ``num_frames`` = the
        capture's, and trajectories only in ``A:B``.
        """
        if self.num_trajectories == 0:
            return range(0)
        return range(int(self.first_frame.min()), int(self.last_frame.max()) + 1)

    @cached_property
    def row_track(self) -> np.ndarray:
        """(P,) int64 trajectory index of each point-frame row."""
        return np.repeat(np.arange(self.num_trajectories, dtype=np.int64), self.lengths)

    @cached_property
    def row_frame(self) -> np.ndarray:
        """(P,) int64 frame of each point-frame row."""
        local = np.arange(self.num_point_frames, dtype=np.int64) - self.offsets[self.row_track]
        return self.first_frame[self.row_track] + local

    @cached_property
    def _frame_index(self) -> tuple[np.ndarray, np.ndarray]:
        order = np.argsort(self.row_frame, kind="stable")  # (P,)
        counts = np.bincount(self.row_frame, minlength=self.num_frames)
        starts = np.concatenate([[0], np.cumsum(counts)])
        return order, starts

    # -- access ------------------------------------------------------------------------------
    def frame_rows(self, t: int) -> np.ndarray:
        """(N_t,) rows of the point-frames alive at frame ``t``, in trajectory order."""
        if not 0 <= t < self.num_frames:
            raise ValidationError(f"frame {t} out of range [0, {self.num_frames})")
        order, starts = self._frame_index
        return order[starts[t] : starts[t + 1]]

    def frame(self, t: int) -> FrameSlice:
        """All points alive at frame ``t``."""
        rows = self.frame_rows(t)
        return FrameSlice(
            frame=t,
            track_id=self.row_track[rows],
            rows=rows,
            xyz=self.xyz[rows],
            visibility=dequantize_visibility(self.visibility[rows]),
        )

    def track(self, m: int) -> np.ndarray:
        """(L_m, 3) float32 positions of trajectory ``m``."""
        return self.xyz[self.offsets[m] : self.offsets[m + 1]]

    def dense_positions(self, tracks: np.ndarray | None = None) -> np.ndarray:
        """Positions as a dense (M', T, 3) array with NaN outside each lifetime.

        Parameters
        ----------
        tracks : (M',) int ndarray, optional
            A subset of trajectories (default all). Memory is ``M' * T * 12`` bytes.
        """
        tracks = np.arange(self.num_trajectories) if tracks is None else np.asarray(tracks)
        out = np.full((len(tracks), self.num_frames, 3), np.nan, dtype=np.float32)
        rows = self.rows_of(tracks)
        which = np.repeat(np.arange(len(tracks)), self.lengths[tracks])
        out[which, self.row_frame[rows]] = self.xyz[rows]
        return out

    def rows_of(self, tracks: np.ndarray) -> np.ndarray:
        """(sum of lengths,) int64 rows of trajectories ``tracks``, trajectory after trajectory."""
        tracks = np.asarray(tracks, dtype=np.int64)
        lengths = self.lengths[tracks]
        starts = np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(np.int64)
        return np.repeat(self.offsets[tracks] - starts, lengths) + np.arange(int(lengths.sum()))

    def subset(self, tracks: np.ndarray) -> Trajectories:
        """A store holding only trajectories ``tracks`` (in that order)."""
        tracks = np.asarray(tracks, dtype=np.int64)
        return self._select(tracks, self.lengths[tracks], self.rows_of(tracks))

    def truncate(self, lengths: np.ndarray) -> Trajectories:
        """A store holding the first ``lengths[m]`` rows of every trajectory m.

        Parameters
        ----------
        lengths : (M,) int ndarray
            Between 1 and each trajectory's length.

        Returns
        -------
        Trajectories
            Same trajectory indices and first frames.
        """
        lengths = np.asarray(lengths, dtype=np.int64)
        if lengths.shape != (self.num_trajectories,) or np.any(
            (lengths < 1) | (lengths > self.lengths)
        ):
            raise ValidationError("truncate: lengths must be in [1, length] per trajectory")
        rows = np.repeat(self.offsets[:-1], lengths) + (
            np.arange(int(lengths.sum())) - np.repeat(np.cumsum(lengths) - lengths, lengths)
        )
        return self._select(np.arange(self.num_trajectories), lengths, rows)

    def _select(self, tracks: np.ndarray, lengths: np.ndarray, rows: np.ndarray) -> Trajectories:
        """The store of trajectories ``tracks`` with ``lengths`` rows each, taken at ``rows``."""
        return Trajectories(
            first_frame=self.first_frame[tracks],
            offsets=np.concatenate([[0], np.cumsum(lengths)]),
            xyz=self.xyz[rows],
            visibility=self.visibility[rows],
            reprojection_error=self.reprojection_error[rows],
            color=self.color[rows],
            camera_names=list(self.camera_names),
            fps=self.fps,
            num_frames=self.num_frames,
        )

    # -- construction ------------------------------------------------------------------------
    @classmethod
    def empty(
        cls, camera_names: Sequence[str], fps: float = 30.0, num_frames: int = 0
    ) -> Trajectories:
        """A store of no trajectories, seen by the cameras ``camera_names``.

        Parameters
        ----------
        camera_names : sequence of str
        fps : float
        num_frames : int

        Returns
        -------
        Trajectories
            M = P = 0, with arrays of the documented dtypes and ``(0, C)`` visibility.
        """
        return cls(
            np.zeros(0, np.int64),
            np.zeros(1, np.int64),
            np.zeros((0, 3), np.float32),
            np.zeros((0, len(camera_names)), np.uint8),
            np.zeros(0, np.float32),
            np.zeros((0, 3), np.uint8),
            camera_names=list(camera_names),
            fps=fps,
            num_frames=num_frames,
        )

    @classmethod
    def from_dense(
        cls,
        xyz: np.ndarray,
        visibility: np.ndarray | None = None,
        *,
        camera_names: list[str] | None = None,
        color: np.ndarray | None = None,
        reprojection_error: np.ndarray | None = None,
        fps: float = 30.0,
    ) -> Trajectories:
        """Build from dense (M, T, 3) positions with NaN where a trajectory is absent.

        Each row must be one contiguous run of finite positions (a gap would split it into two
        trajectories; we refuse rather than guess).

        Parameters
        ----------
        xyz : (M, T, 3) float ndarray
        visibility : (M, T, C) float ndarray, optional
            Probabilities in [0, 1]; default all zero with C = len(camera_names).
        camera_names : list of str, optional
        color : (M, T, 3) uint8 ndarray, optional
        reprojection_error : (M, T) float ndarray, optional
        fps : float

        Returns
        -------
        Trajectories
        """
        xyz = check_array("xyz", xyz, (None, None, 3))
        M, T, _ = xyz.shape
        alive = finite_rows(xyz)  # (M, T)
        if not np.all(alive.any(axis=1)):
            raise ValidationError("from_dense: every trajectory needs at least one finite frame")
        first = np.argmax(alive, axis=1)
        lengths = alive.sum(axis=1)
        last = T - 1 - np.argmax(alive[:, ::-1], axis=1)
        if np.any(last - first + 1 != lengths):
            raise ValidationError("from_dense: a trajectory has a gap; split it first")
        names = list(camera_names or [])
        if visibility is not None:
            visibility = check_array("visibility", visibility, (M, T, None))
            if not names:
                names = [f"cam{i:02d}" for i in range(visibility.shape[2])]
        C = len(names)
        mask = alive.ravel()
        vis = (
            quantize_visibility(visibility.reshape(M * T, C)[mask])
            if visibility is not None
            else np.zeros((int(mask.sum()), C), np.uint8)
        )
        return cls(
            first_frame=first,
            offsets=np.concatenate([[0], np.cumsum(lengths)]),
            xyz=xyz.reshape(M * T, 3)[mask],
            visibility=vis,
            reprojection_error=(
                np.full(int(mask.sum()), np.nan)
                if reprojection_error is None
                else np.asarray(reprojection_error, np.float32).reshape(M * T)[mask]
            ),
            color=(
                np.full((int(mask.sum()), 3), 200, np.uint8)
                if color is None
                else np.asarray(color, np.uint8).reshape(M * T, 3)[mask]
            ),
            camera_names=names,
            fps=fps,
            num_frames=T,
        )

    # -- Open3D views ------------------------------------------------------------------------
    def to_pointcloud(
        self,
        t: int,
        labels: np.ndarray | None = None,
        colors: np.ndarray | None = None,
        visibility_form: str = "full",
        instances: np.ndarray | None = None,
    ) -> o3d.t.geometry.PointCloud:
        """Frame ``t`` as an ``open3d.t.geometry.PointCloud``.

        Attributes as :func:`frame_pointcloud` gives them (``label`` when ``labels`` (M,) is
        given, ``instance`` when ``instances`` (M,) is).

        Parameters
        ----------
        t : int
        labels : (M,) int ndarray, optional
            A label per trajectory.
        colors : (M, 3) uint8 ndarray, optional
            A colour per trajectory, overriding the per-point colours (e.g. label colours).
        visibility_form : {"full", "uint8", "sparse"}
            See :func:`frame_pointcloud`.
        instances : (M,) int ndarray, optional
            A person id per trajectory (-1: none).
        """
        fs = self.frame(t)
        col = self.color[fs.rows] if colors is None else np.asarray(colors, np.uint8)[fs.track_id]
        lab = None
        if labels is not None:
            lab = np.asarray(labels, dtype=np.int32)
            if lab.shape != (self.num_trajectories,):
                raise ValidationError(
                    f"labels: expected shape ({self.num_trajectories},), got {lab.shape}"
                )
            lab = lab[fs.track_id]
        ins = None
        if instances is not None:
            ins = np.asarray(instances, dtype=np.int32)
            if ins.shape != (self.num_trajectories,):
                raise ValidationError(
                    f"instances: expected shape ({self.num_trajectories},), got {ins.shape}"
                )
            ins = ins[fs.track_id]
        return frame_pointcloud(
            fs.xyz, col, self.visibility[fs.rows], fs.track_id, lab, visibility_form, ins
        )

    def write_frame_ply(
        self, t: int, path: str | os.PathLike, visibility_form: str = "full", **kwargs
    ) -> None:
        """Write frame ``t`` as a PLY with its attributes, atomically (see :meth:`to_pointcloud`).

        ``visibility_form`` is one of :data:`CLOUD_VISIBILITY` (default ``"full"``).
        """
        pcd = self.to_pointcloud(t, visibility_form=visibility_form, **kwargs)
        views = self.visibility[self.frame_rows(t)] if visibility_form == "sparse" else None
        write_cloud_ply(path, pcd, views)

    # -- files -------------------------------------------------------------------------------
    def save(self, path: str | os.PathLike) -> None:
        """Write ``trajectories.npz`` atomically (format: ``data_specs/trajectories.md``)."""
        save_npz_atomic(
            path,
            format_version=np.int64(FORMAT_VERSION),
            first_frame=self.first_frame,
            offsets=self.offsets,
            xyz=self.xyz,
            visibility=self.visibility,
            reprojection_error=self.reprojection_error,
            color=self.color,
            camera_names=np.array(self.camera_names, dtype=str),
            fps=np.float64(self.fps),
            num_frames=np.int64(self.num_frames),
        )

    @classmethod
    def load(cls, path: str | os.PathLike) -> Trajectories:
        """Read a ``trajectories.npz`` written by :meth:`save`.

        Raises
        ------
        FileFormatError
            If the file is missing, not an npz, lacks a field or is inconsistent.
        """
        from .npzfile import load_npz

        path = Path(path)
        need = (
            "first_frame",
            "offsets",
            "xyz",
            "visibility",
            "reprojection_error",
            "color",
            "camera_names",
        )
        data = load_npz(path, need, "a trajectory store")
        version = int(data.get("format_version", FORMAT_VERSION))
        if version > FORMAT_VERSION:
            raise FileFormatError(
                path,
                f"format_version {version} is newer than this pointtraj reads ({FORMAT_VERSION})",
            )
        _check_finite_xyz(path, data["xyz"])
        try:
            return cls(
                first_frame=data["first_frame"],
                offsets=data["offsets"],
                xyz=data["xyz"],
                visibility=data["visibility"],
                reprojection_error=data["reprojection_error"],
                color=data["color"],
                camera_names=[str(s) for s in data["camera_names"]],
                fps=float(data.get("fps", 30.0)),
                num_frames=int(data.get("num_frames", 0)),
            )
        except ValidationError as exc:
            raise FileFormatError(path, str(exc)) from None

    def check_cameras(self, capture: Any, path: str | os.PathLike) -> None:
        """Refuse a capture whose cameras are not this store's (a work folder of another rig).

        Parameters
        ----------
        capture : Capture
            Has ``path`` and ``camera_names``.
        path : path-like
            This store's file, for the message.

        Raises
        ------
        FileFormatError
            Naming the store, the capture and both camera lists.
        """
        ours, theirs = list(self.camera_names), list(capture.camera_names)
        if sorted(ours) == sorted(theirs):
            return
        raise FileFormatError(
            path,
            f"its {len(ours)} cameras ({', '.join(ours)}) are not the {len(theirs)} cameras of "
            f"capture {capture.path} ({', '.join(theirs)}): the work folder belongs to another "
            "rig or capture",
        )

    @staticmethod
    def concatenate(parts: list[Trajectories]) -> Trajectories:
        """Join stores with the same cameras into one (trajectory indices follow ``parts``' order)."""
        if not parts:
            raise ValidationError("concatenate needs at least one store")
        names = parts[0].camera_names
        for p in parts[1:]:
            if p.camera_names != names:
                raise ValidationError("concatenate: stores have different cameras")
        lengths = np.concatenate([p.lengths for p in parts])
        return Trajectories(
            first_frame=np.concatenate([p.first_frame for p in parts]),
            offsets=np.concatenate([[0], np.cumsum(lengths)]),
            xyz=np.concatenate([p.xyz for p in parts]),
            visibility=np.concatenate([p.visibility for p in parts]),
            reprojection_error=np.concatenate([p.reprojection_error for p in parts]),
            color=np.concatenate([p.color for p in parts]),
            camera_names=list(names),
            fps=parts[0].fps,
            num_frames=max(p.num_frames for p in parts),
        )
