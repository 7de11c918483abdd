"""Camera rigs for the tests: a ring of cameras around a capture volume, and cameras facing a
plane. Each test passes the parameters of its own rig, so the rigs (names, positions, sizes,
focal lengths, distortion) are exactly those the tests were written against."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from pointtraj.camera import Camera, CameraRig


def _name(names: str | Sequence[str], i: int) -> str:
    return names.format(i=i) if isinstance(names, str) else names[i]


def ring_rig(
    n: int | None = None,
    *,
    radius: float = 3.0,
    size: tuple[int, int] = (640, 480),
    focal: float = 500.0,
    heights: Sequence[float] = (1.0,),
    target: Sequence[float] = (0.0, 0.0, 1.0),
    angles: Sequence[float] | None = None,
    names: str | Sequence[str] = "c{i}",
    dist: object = None,
    outward: Sequence[int] = (),
) -> CameraRig:
    """Cameras on a horizontal circle about the z axis, looking at ``target``.

    Parameters
    ----------
    n : int, optional
        Number of cameras, at angles ``2 pi i / n``; or give ``angles``.
    radius : float
        Distance of the cameras from the z axis.
    size : (int, int)
        Image ``(width, height)``.
    focal : float
        Focal length in pixels.
    heights : sequence of float
        Camera i stands at height ``heights[i % len(heights)]`` (two values alternate).
    target : (3,) sequence of float
        The point the cameras look at.
    angles : sequence of float, optional
        Angles of the cameras on the circle, radians.
    names : str or sequence of str
        A format string of ``i`` (``"cam{i:02d}"``) or the names themselves.
    dist : array-like, optional
        Distortion coefficients of every camera.
    outward : sequence of int
        Cameras that look away from ``target`` (at its mirror image through the camera).
    """
    if angles is None:
        angles = [2 * np.pi * i / n for i in range(n)]
    look = np.asarray(target, float)
    cams = []
    for i, a in enumerate(angles):
        c = np.array([radius * np.cos(a), radius * np.sin(a), heights[i % len(heights)]])
        cams.append(
            Camera.look_at(
                _name(names, i), c, 2 * c - look if i in outward else look, size, focal, dist=dist
            )
        )
    return CameraRig(cams)


def plane_rig(
    n: int = 3,
    *,
    angles: Sequence[float] | None = None,
    size: tuple[int, int] = (480, 360),
    focal: float = 400.0,
    names: str | Sequence[str] = "c{i}",
    dist: object = None,
) -> CameraRig:
    """Cameras 2 m from the origin facing the plane z = 0 from z > 0, image up along -y.

    Camera i is at angle ``angles[i]`` (degrees, about the y axis; default ``n`` cameras
    spread evenly over -15 to 15), 0.3 m below the x axis (``y = -0.3``).

    Parameters
    ----------
    n : int
        Number of cameras when ``angles`` is not given.
    angles : sequence of float, optional
        Angles of the cameras, degrees.
    size, focal, names, dist
        As for :func:`ring_rig`.
    """
    if angles is None:
        angles = [-15 + 30 * i / max(n - 1, 1) for i in range(n)]
    cams = []
    for i, deg in enumerate(angles):
        a = np.deg2rad(deg)
        C = [2.0 * np.sin(a), -0.3, 2.0 * np.cos(a)]
        cams.append(
            Camera.look_at(_name(names, i), C, [0, 0, 0], size, focal, up=[0, -1, 0], dist=dist)
        )
    return CameraRig(cams)
