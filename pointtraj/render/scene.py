"""What a frame shows, as world geometry: the points alive and their tails, a floor grid, and
virtual cameras orbiting the scene. Both engines (:mod:`.offscreen`, :mod:`.overlay`) draw it."""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence

import numpy as np

from ..camera import Camera, CameraRig
from ..errors import ValidationError
from ..trajectories import Trajectories
from .palette import blend_colors

__all__ = ["tail_segments", "frame_geometry", "plane_basis", "floor_grid", "orbit_cameras"]


def tail_segments(
    trajectories: Trajectories, t: int, tail: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Line segments of the last ``tail`` frames of the trajectories alive at frame ``t``.

    Parameters
    ----------
    trajectories : Trajectories
    t : int
        Current frame.
    tail : int
        Number of past frames drawn (0 draws none).

    Returns
    -------
    segments : (S, 2, 3) float32 ndarray
        Start and end of each segment, world coordinates; a segment joins frames f and f + 1
        of one trajectory, ``t - tail <= f < t``.
    track : (S,) int64 ndarray
        Trajectory of each segment.
    age : (S,) int64 ndarray
        ``t - f``, from 1 (the segment ending at frame t) to ``tail``.
    """
    if tail <= 0:
        return np.zeros((0, 2, 3), np.float32), np.zeros(0, np.int64), np.zeros(0, np.int64)
    alive = np.zeros(trajectories.num_trajectories, bool)
    alive[trajectories.row_track[trajectories.frame_rows(t)]] = True
    frames = range(max(0, t - tail), t)
    rows = np.concatenate([trajectories.frame_rows(f) for f in frames] or [np.zeros(0, np.int64)])
    track = trajectories.row_track[rows]
    # A row and the next one belong to the same trajectory unless it ends there.
    keep = alive[track] & (rows + 1 < trajectories.offsets[track + 1])
    rows, track = rows[keep], track[keep]
    seg = np.stack([trajectories.xyz[rows], trajectories.xyz[rows + 1]], axis=1)  # (S, 2, 3)
    return seg, track, t - trajectories.row_frame[rows]


def frame_geometry(
    trajectories: Trajectories,
    t: int,
    colors: np.ndarray,
    tail: int,
    fade: float = 0.0,
    background: Sequence[int] = (255, 255, 255),
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Frame t's points and tails with their colours; tails fade towards ``background``.

    Parameters
    ----------
    trajectories, t, tail
        As in :func:`tail_segments`.
    colors : (M, 3) uint8 ndarray
        Colour per trajectory.
    fade : float
        How far, in [0, 1], the oldest segment's colour moves towards ``background``.
    background : (3,) int
        RGB of the background.

    Returns
    -------
    points : (N, 3) float32 ndarray
    point_colors : (N, 3) uint8 ndarray
    segments : (S, 2, 3) float32 ndarray
    segment_colors : (S, 3) uint8 ndarray
    """
    fs = trajectories.frame(t)
    seg, track, age = tail_segments(trajectories, t, tail)
    seg_col = colors[track]
    if fade > 0 and tail > 1 and len(seg):
        # The newest segment keeps the label colour; the oldest moves ``fade`` of the way.
        seg_col = blend_colors(seg_col, background, fade * (age - 1) / (tail - 1))
    return fs.xyz, colors[fs.track_id], seg, seg_col


def plane_basis(up: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit ``up`` and two unit vectors spanning the plane perpendicular to it (right-handed).

    Parameters
    ----------
    up : (3,) float ndarray

    Returns
    -------
    u, e1, e2 : (3,) float ndarrays
        ``u = up / |up|``, and ``e1``, ``e2 = u x e1`` orthonormal.
    """
    u = np.asarray(up, float)
    u = u / np.linalg.norm(u)
    for axis in (np.array([1.0, 0, 0]), np.array([0, 1.0, 0])):
        e1 = axis - (axis @ u) * u
        if np.linalg.norm(e1) > 1e-6:
            break
    e1 /= np.linalg.norm(e1)
    return u, e1, np.cross(u, e1)


def floor_grid(
    center: Iterable[float],
    up: Iterable[float],
    half_size: float,
    spacing: float,
    piece: float | None = None,
) -> np.ndarray:
    """Segments of a square grid in the plane through ``center`` perpendicular to ``up``.

    Each grid line is cut into pieces of length ``piece`` so that a camera that sees only part
    of a line still draws that part (the OpenCV engine drops segments leaving the image).

    Parameters
    ----------
    center : (3,) array-like
        Centre of the grid (world, metres).
    up : (3,) array-like
        Normal of the grid plane.
    half_size : float
        Half the side of the square.
    spacing : float
        Distance between grid lines.
    piece : float, optional
        Length of the pieces (default ``spacing / 4``).

    Returns
    -------
    (S, 2, 3) float64 ndarray
    """
    if half_size <= 0 or spacing <= 0:
        raise ValidationError(
            f"floor_grid: half_size and spacing must be positive, got {half_size}, {spacing}"
        )
    c = np.asarray(list(center), float)
    _, e1, e2 = plane_basis(np.asarray(list(up), float))
    n = int(math.floor(half_size / spacing + 1e-9))
    ticks = np.arange(-n, n + 1) * spacing  # (L,)
    m = max(1, int(math.ceil(2 * half_size / (piece or spacing / 4))))
    s = np.linspace(-half_size, half_size, m + 1)  # (m + 1,)
    segs = []
    for a, b in ((e1, e2), (e2, e1)):
        pts = c + s[None, :, None] * a + ticks[:, None, None] * b  # (L, m + 1, 3)
        segs.append(np.stack([pts[:, :-1], pts[:, 1:]], axis=2).reshape(-1, 2, 3))
    return np.concatenate(segs)


def orbit_cameras(
    center: Iterable[float],
    radius: float,
    height: float,
    n: int,
    size: tuple[int, int] = (1280, 1024),
    fov_deg: float = 50.0,
    start_deg: float = 0.0,
    sweep_deg: float = 360.0,
    up: Iterable[float] = (0.0, 0.0, 1.0),
) -> CameraRig:
    """Virtual cameras on a circle around ``center``, looking at it.

    Parameters
    ----------
    center : (3,) array-like
        Point looked at (world, metres).
    radius, height : float
        Circle radius and height above ``center`` (along ``up``).
    n : int
        Number of views.
    size : (int, int)
        Image (width, height).
    fov_deg : float
        Horizontal field of view.
    start_deg, sweep_deg : float
        First azimuth and the angle swept by the ``n`` views. Azimuth 0 is the direction of
        world x projected on the plane perpendicular to ``up`` (of y if up is x).
    up : (3,) array-like
        World up direction; it points up in the images.

    Returns
    -------
    CameraRig
        Cameras named ``orbit000``, ``orbit001``, ...
    """
    if n < 1:
        raise ValidationError(f"orbit_cameras: n must be at least 1, got {n}")
    c = np.asarray(list(center), dtype=float)
    u, e1, e2 = plane_basis(np.asarray(list(up), float))
    focal = size[0] / 2 / np.tan(np.radians(fov_deg) / 2)
    step = sweep_deg / n if abs(sweep_deg) >= 360 else sweep_deg / max(n - 1, 1)
    az = np.radians(start_deg + step * np.arange(n))
    cams = [
        Camera.look_at(
            f"orbit{i:03d}",
            c + radius * (np.cos(a) * e1 + np.sin(a) * e2) + height * u,
            c,
            size,
            focal,
            up=u,
        )
        for i, a in enumerate(az)
    ]
    return CameraRig(cams)
