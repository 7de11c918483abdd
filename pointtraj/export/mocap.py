"""Joint centres and part centroids as motion-capture markers: C3D and TRC files.

The markers come from ``segments.npz`` (:class:`pointtraj.segments.Segments`): every joint with
a centre (status ``ball`` or ``hinge``) under its name, then every segment's centroid as
``<part>_centroid`` (names prefixed ``person<i>/`` when there are several people). Missing
frames (a pose not found) are gaps: NaN in C3D (residual -1), empty fields in TRC. Joints that
are not observable carry no marker at all (``pointtraj segments`` lists them).

- **C3D** (:func:`save_c3d`, through ``ezc3d``): ``POINT:RATE`` the capture's frame rate,
  ``POINT:LABELS`` the marker names, ``POINT:UNITS`` ``mm`` (or ``m``).
- **TRC** (:func:`save_trc`, :func:`load_trc`): the tab-separated text that Pose2Sim writes and
  OpenSim reads (``PathFileType 4 (X/Y/Z)``), units in the header. OpenSim's convention is
  Y up: ``up="y"`` turns pointtraj's Z-up world (floor z = 0) into it by the cyclic
  permutation ``(X, Y, Z) <- (y, z, x)``, a proper rotation.

The files hold T x K markers (K joints and parts, not trajectories), so memory does not grow
with the number of trajectories.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..atomic import atomic_path, write_text_atomic
from ..errors import FileFormatError, ValidationError

__all__ = ["Markers", "segment_markers", "save_c3d", "save_trc", "load_trc", "UNITS"]

if TYPE_CHECKING:
    from ..segments import Segments

logger = logging.getLogger(__name__)

#: Units a file may be written in, and metres per unit.
UNITS: dict[str, float] = {"mm": 0.001, "m": 1.0}


@dataclass(eq=False)
class Markers:
    """K named 3D markers over T frames.

    Attributes
    ----------
    names : list of K str
    xyz : (T, K, 3) float64 ndarray
        World positions, metres; NaN where a marker is missing.
    fps : float
        Frame rate.
    first_frame : int
        Frame number of ``xyz[0]`` (0-based).
    """

    names: list[str]
    xyz: np.ndarray
    fps: float
    first_frame: int = 0


def segment_markers(segments: Segments, joints: bool = True, centroids: bool = True) -> Markers:
    """The markers of ``segments``: observable joint centres, then part centroids.

    Parameters
    ----------
    segments : Segments
    joints, centroids : bool
        Which markers to include.

    Returns
    -------
    Markers
    """
    names: list[str] = []
    cols: list[np.ndarray] = []
    if joints:
        pos = segments.joint_positions()  # (J, T, 3)
        for j, name in enumerate(segments.joint_labels()):
            if segments.joint_status[j] <= 1:  # ball or hinge: a centre exists
                names.append(name)
                cols.append(pos[j])
    if centroids:
        cen = segments.centroids()  # (S, T, 3)
        for s, name in enumerate(segments.segment_names()):
            names.append(f"{name}_centroid")
            cols.append(cen[s])
    xyz = np.stack(cols, axis=1) if cols else np.zeros((segments.num_frames, 0, 3))
    return Markers(names, xyz, float(segments.fps))


def _check(markers: Markers, units: str, up: str) -> None:
    if units not in UNITS:
        raise ValidationError(f"units must be one of {', '.join(UNITS)}, got {units!r}")
    if up not in ("z", "y"):
        raise ValidationError(f"up must be 'z' or 'y', got {up!r}")
    if not markers.names:
        raise ValidationError("no markers to write (no segment has a pose: run the labelling?)")


def _oriented(xyz: np.ndarray, up: str) -> np.ndarray:
    """pointtraj's Z-up world, or OpenSim's Y up: ``(X, Y, Z) <- (y, z, x)``."""
    return xyz if up == "z" else xyz[..., [1, 2, 0]]


def save_c3d(markers: Markers, path: str | os.PathLike, units: str = "mm", up: str = "z") -> None:
    """Write ``markers`` as a C3D file (atomically, through ``ezc3d``).

    Parameters
    ----------
    markers : Markers
    path : path-like
    units : {"mm", "m"}
    up : {"z", "y"}
        The world's up axis in the file (pointtraj's is z).

    Raises
    ------
    ValidationError
        On bad units or no markers.
    """
    import ezc3d

    _check(markers, units, up)
    T, K, _ = markers.xyz.shape
    points = np.ones((4, K, T))
    points[:3] = np.transpose(_oriented(markers.xyz, up) / UNITS[units], (2, 1, 0))
    c3d = ezc3d.c3d()
    c3d["parameters"]["POINT"]["RATE"]["value"] = [float(markers.fps)]
    c3d["parameters"]["POINT"]["LABELS"]["value"] = tuple(markers.names)
    c3d["parameters"]["POINT"]["UNITS"]["value"] = [units]
    c3d["data"]["points"] = points
    missing = ~np.isfinite(points[:3]).all(axis=0)  # (K, T)
    c3d["data"]["meta_points"] = {
        "residuals": np.where(missing, -1.0, 0.0)[None],  # C3D's mark of a missing point
        "camera_masks": np.zeros((7, K, T), dtype=bool),
    }
    with atomic_path(path) as tmp:
        c3d.write(str(tmp))
    logger.info("wrote %d markers x %d frames to %s", K, T, path)


def save_trc(markers: Markers, path: str | os.PathLike, units: str = "mm", up: str = "z") -> None:
    """Write ``markers`` as a TRC file (Pose2Sim's layout; atomically).

    Parameters
    ----------
    markers : Markers
    path : path-like
    units : {"mm", "m"}
    up : {"z", "y"}
        The world's up axis in the file (pointtraj's is z; OpenSim expects y).

    Raises
    ------
    ValidationError
        On bad units or no markers.
    """
    _check(markers, units, up)
    path = Path(path)
    T, K, _ = markers.xyz.shape
    fps = float(markers.fps)
    start = int(markers.first_frame) + 1  # TRC frames count from 1
    lines = [
        f"PathFileType\t4\t(X/Y/Z)\t{path.name}",
        "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\t"
        "OrigDataStartFrame\tOrigNumFrames",
        f"{fps:g}\t{fps:g}\t{T}\t{K}\t{units}\t{fps:g}\t{start}\t{T}",
        "Frame#\tTime\t" + "\t\t\t".join(markers.names) + "\t\t",
        "\t\t" + "\t".join(f"X{k + 1}\tY{k + 1}\tZ{k + 1}" for k in range(K)),
    ]
    xyz = _oriented(markers.xyz, up).reshape(T, 3 * K) / UNITS[units]
    text = np.where(np.isfinite(xyz), np.char.mod("%.6f", xyz), "")  # (T, 3K) str
    for t in range(T):  # T rows of K markers: not a per-point loop
        lines.append(f"{start + t}\t{t / fps:.6f}\t" + "\t".join(text[t]))
    write_text_atomic(path, "\n".join(lines) + "\n")
    logger.info("wrote %d markers x %d frames to %s", K, T, path)


def load_trc(path: str | os.PathLike) -> tuple[Markers, str]:
    """Read a TRC file (the layout of :func:`save_trc`, Pose2Sim's and OpenSim's).

    Parameters
    ----------
    path : path-like

    Returns
    -------
    markers : Markers
        Positions in metres, as the file's axes are (no up-axis change); empty fields NaN.
    units : str
        The header's units.

    Raises
    ------
    FileFormatError
        Naming the file: missing, a malformed header, unknown units, or a row with the wrong
        number of fields.
    """
    path = Path(path)
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except FileNotFoundError:
        raise FileFormatError(path, "no such file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise FileFormatError(path, f"unreadable ({exc})") from None
    if len(lines) < 5 or not lines[0].startswith("PathFileType"):
        raise FileFormatError(path, "not a TRC file (no PathFileType header)")
    keys = lines[1].split("\t")
    values = lines[2].split("\t")
    header = dict(zip(keys, values))
    try:
        fps = float(header["DataRate"])
        K = int(header["NumMarkers"])
        units = header["Units"].strip()
        start = int(header.get("OrigDataStartFrame", "1"))
    except (KeyError, ValueError) as exc:
        raise FileFormatError(path, f"bad header line 3 ({exc})") from None
    if units not in UNITS:
        raise FileFormatError(path, f"units {units!r} (expected one of {', '.join(UNITS)})")
    names = [n for n in lines[3].split("\t")[2:] if n.strip()]
    if len(names) != K:
        raise FileFormatError(path, f"NumMarkers is {K} but line 4 names {len(names)} markers")
    rows = [ln for ln in lines[5:] if ln.strip()]
    xyz = np.full((len(rows), K, 3), np.nan)
    for t, ln in enumerate(rows):
        fields = ln.split("\t")[2:]
        if len(fields) < 3 * K:
            fields += [""] * (3 * K - len(fields))
        if len(fields) > 3 * K:
            raise FileFormatError(path, f"row {t + 6} has {len(fields)} values, expected {3 * K}")
        try:
            xyz[t] = np.array([float(f) if f.strip() else np.nan for f in fields]).reshape(K, 3)
        except ValueError as exc:
            raise FileFormatError(path, f"row {t + 6}: {exc}") from None
    return Markers(names, xyz * UNITS[units], fps, start - 1), units
