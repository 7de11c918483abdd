"""Rendered scenes for the tests: a band-limited random texture on the plane z = 0, as the
cameras of a rig see it, still or moving."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from pointtraj.camera import Camera, CameraRig

#: Corner of the textured square the scenes render (it spans ``extent`` metres in x and y).
PLANE_ORIGIN = (-1.0, -1.0, 0.0)


def make_texture(rng: np.random.Generator, size: int = 768) -> np.ndarray:
    """(size, size, 3) uint8 band-limited random texture (good for ORB and optical flow)."""
    import cv2

    t = cv2.resize(rng.random((size // 8, size // 8)), (size, size), interpolation=cv2.INTER_CUBIC)
    t += 0.5 * cv2.resize(rng.random((size // 2, size // 2)), (size, size))
    t = (255 * (t - t.min()) / (t.max() - t.min())).astype(np.uint8)
    return np.stack([t, np.roll(t, 7, 0), np.roll(t, 13, 1)], axis=2)


def render_plane(cam: Camera, texture: np.ndarray, origin, extent: float) -> np.ndarray:
    """Image of the textured square ``z = origin[2]``, ``[ox, ox + extent] x [oy, oy + extent]``."""
    import cv2

    s = extent / texture.shape[1]
    A = np.array([[s, 0, origin[0]], [0, s, origin[1]], [0, 0, 1.0]])  # texture px -> plane
    t = -cam.R @ cam.C
    M = cam.K @ np.column_stack([cam.R[:, 0], cam.R[:, 1], cam.R[:, 2] * origin[2] + t])
    return cv2.warpPerspective(texture, M @ A, cam.size, flags=cv2.INTER_LINEAR)


def plane_frames(
    rig: CameraRig,
    T: int,
    *,
    seed: int,
    velocity: Sequence[float] = (0.0, 0.0, 0.0),
    origin: Sequence[float] = PLANE_ORIGIN,
    extent: float = 2.0,
) -> list[list[np.ndarray]]:
    """``T`` frames (a list per frame of an image per camera) of the square of texture
    :func:`make_texture` (of ``default_rng(seed)``) with corner ``origin + t * velocity``."""
    texture = make_texture(np.random.default_rng(seed))
    origin, velocity = np.asarray(origin, float), np.asarray(velocity, float)
    return [
        [render_plane(c, texture, origin + t * velocity, extent) for c in rig] for t in range(T)
    ]


def plane_images(rig: CameraRig, *, seed: int, extent: float = 2.0) -> list[np.ndarray]:
    """One image per camera of the still square: frame 0 of :func:`plane_frames`."""
    return plane_frames(rig, 1, seed=seed, extent=extent)[0]
