"""Camera-rig presets for synthetic captures.

Every preset is a ring (or two rings) of cameras built with :meth:`Camera.look_at`, looking at the
stage centre, without lens distortion. The world frame has z up and the stage floor at ``z = 0``;
the stage is centred on the z axis.

=========  =======  ==========  ========  =============================================
preset     cameras  resolution  focal px  geometry
=========  =======  ==========  ========  =============================================
paper69    69       1280x1024   600       two rings on a 1.6 m radius (just outside the
                                          paper's 3 m x 2.5 m cylinder): 35 cameras at
                                          1.0 m aimed at (0, 0, 0.9) (tilted 3.6 degrees
                                          down) and 34 at 2.2 m aimed at (0, 0, 1.1)
                                          (tilted 34.5 degrees down), rings staggered by
                                          half a step; field of view 93.7 x 81.0 degrees
paper69q   69       320x256     150       paper69's geometry at a quarter of its resolution
                                          (for affordable long runs, e.g. memory benchmarks)
ring12     12       800x640     420       one ring, radius 2.5 m, heights alternating
                                          1.1 m / 2.0 m, aimed at (0, 0, 0.9);
                                          field of view 87.2 x 74.6 degrees
ring8      8        640x512     380       one ring, radius 2.4 m, height 1.4 m, aimed at
                                          (0, 0, 0.85); field of view 80.2 x 67.9 degrees
tiny4      4        320x256     190       one ring, radius 2.4 m, height 1.4 m, aimed at
                                          (0, 0, 0.85), 90 degrees apart (45 degrees
                                          offset); field of view 80.2 x 67.9 degrees
lab4       4        1280x720    900       a webcam lab rig on one side of the room: an arc
                                          of 120 degrees (cameras 40 degrees apart) of
                                          radius 3 m, heights alternating 1.2 m / 2.0 m,
                                          aimed at (0, 0, 0.9); field of view
                                          70.8 x 43.6 degrees
narrow7    7        1280x1024   21556     a narrow-field rig for a subject a few mm across
                                          at the origin: 6 cameras on a ring 40 degrees
                                          above it and 1 above it, all 11.8 cm away;
                                          field of view 3.4 x 2.7 degrees (each camera
                                          sees about 7 x 5.6 mm at the subject); its
                                          scenes are scaled by 0.004 (a 7.2 mm figure
                                          whose stage centre is at the origin)
=========  =======  ==========  ========  =============================================

The synthetic scenes are human-sized; a preset's ``scene_scale`` scales them to its rig
(``narrow7``: 0.004, a 7.2 mm figure), and ``pointtraj synth --scale`` / ``--rig-scale``
change the scene's and the rig's size (:func:`~.render.synthetic_world`).

Camera names are ``cam00``, ``cam01``, ... in ring order (the lower ring first for ``paper69``).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..camera import Camera, CameraRig
from ..errors import ValidationError

__all__ = ["PRESETS", "RigPreset", "make_rig", "ring_cameras", "field_of_view", "scale_rig"]


@dataclass(frozen=True)
class RigPreset:
    """A named rig recipe.

    Attributes
    ----------
    description : str
        One line: camera count, resolution, focal length and geometry.
    build : callable
        ``build() -> CameraRig``.
    fps : float
        Frame rate of captures made with this rig.
    target : (3,) tuple of float
        The stage centre, which every camera must see (metres); a scene's stage centre is
        placed there.
    scene_scale : float
        The size of the scenes rendered with this rig against their human size (the default
        of ``pointtraj synth --scale``; :func:`~.scenes.scale_scene`).
    """

    description: str
    build: Callable[[], CameraRig]
    fps: float = 30.0
    target: tuple[float, float, float] = (0.0, 0.0, 0.9)
    scene_scale: float = 1.0


def field_of_view(size: tuple[int, int], focal: float) -> tuple[float, float]:
    """Horizontal and vertical field of view in degrees of a pinhole camera.

    Parameters
    ----------
    size : (int, int)
        ``(width, height)`` in pixels.
    focal : float
        Focal length in pixels.

    Returns
    -------
    (float, float)
        ``(horizontal, vertical)`` in degrees.

    Examples
    --------
    >>> [round(a, 1) for a in field_of_view((1280, 1024), 600.0)]
    [93.7, 81.0]
    """
    w, h = size
    return (
        math.degrees(2 * math.atan(w / 2 / focal)),
        math.degrees(2 * math.atan(h / 2 / focal)),
    )


def ring_cameras(
    count: int,
    radius: float,
    heights: float | list[float],
    target: tuple[float, float, float],
    size: tuple[int, int],
    focal: float,
    *,
    start_angle: float = 0.0,
    first_index: int = 0,
    targets: list[tuple[float, float, float]] | None = None,
) -> list[Camera]:
    """Cameras evenly spaced on a horizontal circle around the z axis, looking inwards.

    Parameters
    ----------
    count : int
        Number of cameras.
    radius : float
        Circle radius in metres.
    heights : float or list of float
        Camera height, or a list cycled over the cameras.
    target : (3,) tuple
        Point every camera looks at (overridden per camera by ``targets``).
    size : (int, int)
        Image ``(width, height)``.
    focal : float
        Focal length in pixels.
    start_angle : float
        Azimuth of the first camera in radians.
    first_index : int
        Number of the first camera name (``cam{index:02d}``).
    targets : list of (3,) tuples, optional
        One look-at point per height in ``heights`` (cycled like the heights).

    Returns
    -------
    list of Camera
    """
    hs = [heights] if isinstance(heights, int | float) else list(heights)
    cams = []
    for i in range(count):
        a = start_angle + 2 * math.pi * i / count
        centre = (radius * math.cos(a), radius * math.sin(a), hs[i % len(hs)])
        aim = target if targets is None else targets[i % len(targets)]
        cams.append(Camera.look_at(f"cam{first_index + i:02d}", centre, aim, size, focal))
    return cams


def _paper69() -> CameraRig:
    size, focal, radius = (1280, 1024), 600.0, 1.6
    lower = ring_cameras(35, radius, 1.0, (0.0, 0.0, 0.9), size, focal)
    upper = ring_cameras(
        34, radius, 2.2, (0.0, 0.0, 1.1), size, focal, start_angle=math.pi / 34, first_index=35
    )
    return CameraRig(lower + upper)


def _paper69q() -> CameraRig:
    size, focal, radius = (320, 256), 150.0, 1.6
    lower = ring_cameras(35, radius, 1.0, (0.0, 0.0, 0.9), size, focal)
    upper = ring_cameras(
        34, radius, 2.2, (0.0, 0.0, 1.1), size, focal, start_angle=math.pi / 34, first_index=35
    )
    return CameraRig(lower + upper)


def _ring12() -> CameraRig:
    return CameraRig(ring_cameras(12, 2.5, [1.1, 2.0], (0.0, 0.0, 0.9), (800, 640), 420.0))


def _ring8() -> CameraRig:
    return CameraRig(ring_cameras(8, 2.4, 1.4, (0.0, 0.0, 0.85), (640, 512), 380.0))


def _tiny4() -> CameraRig:
    return CameraRig(
        ring_cameras(4, 2.4, 1.4, (0.0, 0.0, 0.85), (320, 256), 190.0, start_angle=math.pi / 4)
    )


def _lab4() -> CameraRig:
    cams = []
    for i, deg in enumerate((-60.0, -20.0, 20.0, 60.0)):
        a = math.radians(deg)
        centre = (3.0 * math.cos(a), 3.0 * math.sin(a), (1.2, 2.0)[i % 2])
        cams.append(Camera.look_at(f"cam{i:02d}", centre, (0.0, 0.0, 0.9), (1280, 720), 900.0))
    return CameraRig(cams)


#: Focal length (px) of ``narrow7``: a 3.4 degree horizontal field of view at 1280 px.
NARROW_FOCAL = 640.0 / math.tan(math.radians(1.7))


#: The scene scale of ``narrow7``: the 1.8 m figure becomes 7.2 mm tall, filling the 7 x 5.6 mm
#: that each camera sees.
NARROW_SCENE_SCALE = 0.004


def _narrow7() -> CameraRig:
    distance, elevation = 0.118, math.radians(40.0)
    cams = []
    for i in range(6):
        a = 2 * math.pi * i / 6
        centre = (
            distance * math.cos(a) * math.cos(elevation),
            distance * math.sin(a) * math.cos(elevation),
            distance * math.sin(elevation),
        )
        cams.append(
            Camera.look_at(f"cam{i:02d}", centre, (0.0, 0.0, 0.0), (1280, 1024), NARROW_FOCAL)
        )
    top = (0.002, 0.0, distance)  # off the vertical, so that look_at has an up direction
    cams.append(Camera.look_at("cam06", top, (0.0, 0.0, 0.0), (1280, 1024), NARROW_FOCAL))
    return CameraRig(cams)


#: Preset name -> recipe.
PRESETS: dict[str, RigPreset] = {
    "paper69": RigPreset(
        "69 cameras, 1280x1024, f=600 px (FOV 93.7x81.0 deg), two rings (35 at 1.0 m, 34 at "
        "2.2 m) on a 1.6 m radius around the 3 m x 2.5 m stage cylinder, 30 Hz",
        _paper69,
    ),
    "paper69q": RigPreset(
        "paper69 at a quarter of its resolution: 69 cameras, 320x256, f=150 px (the same "
        "fields of view and geometry), 30 Hz (for affordable long runs)",
        _paper69q,
    ),
    "ring12": RigPreset(
        "12 cameras, 800x640, f=420 px (FOV 87.2x74.6 deg), one ring of radius 2.5 m at "
        "alternating heights 1.1 m / 2.0 m, 30 Hz",
        _ring12,
    ),
    "ring8": RigPreset(
        "8 cameras, 640x512, f=380 px (FOV 80.2x67.9 deg), one ring of radius 2.4 m at "
        "1.4 m height, 30 Hz (the demo rig)",
        _ring8,
    ),
    "tiny4": RigPreset(
        "4 cameras, 320x256, f=190 px (FOV 80.2x67.9 deg), one ring of radius 2.4 m at "
        "1.4 m height, 30 Hz (for fast tests)",
        _tiny4,
    ),
    "lab4": RigPreset(
        "4 cameras, 1280x720, f=900 px (FOV 70.8x43.6 deg), a webcam lab rig: an arc of 120 "
        "degrees of radius 3 m on one side of the stage, heights 1.2 m / 2.0 m, 30 Hz",
        _lab4,
    ),
    "narrow7": RigPreset(
        "7 cameras, 1280x1024, f=21556 px (FOV 3.4x2.7 deg), 11.8 cm from a subject a few mm "
        "across at the origin: 6 on a ring 40 degrees above it, 1 above it, 30 Hz (scenes at "
        "0.004 of their size: a 7 mm figure)",
        _narrow7,
        target=(0.0, 0.0, 0.0),
        scene_scale=NARROW_SCENE_SCALE,
    ),
}


def scale_rig(rig: CameraRig, factor: float, centre: tuple[float, float, float]) -> CameraRig:
    """The rig with its camera centres scaled by ``factor`` about ``centre`` (same images).

    Parameters
    ----------
    rig : CameraRig
    factor : float
        Positive.
    centre : (3,) tuple of float

    Returns
    -------
    CameraRig
        ``rig`` itself when ``factor`` is 1.
    """
    f = float(factor)
    if not (f > 0 and math.isfinite(f)):
        raise ValidationError(f"rig scale must be a positive number, got {factor!r}")
    if f == 1.0:
        return rig
    c = np.asarray(centre, float)
    return CameraRig(
        Camera(cam.name, cam.K, cam.R, c + f * (np.asarray(cam.C) - c), cam.size, cam.dist)
        for cam in rig
    )


def make_rig(name: str) -> CameraRig:
    """Build the camera rig of a preset.

    Parameters
    ----------
    name : str
        A key of :data:`PRESETS`.

    Returns
    -------
    CameraRig

    Raises
    ------
    ValidationError
        If the preset is unknown (the message lists the valid names).

    Examples
    --------
    >>> rig = make_rig("tiny4")
    >>> len(rig), tuple(rig[0].size)
    (4, (320, 256))
    """
    if name not in PRESETS:
        raise ValidationError(
            f"unknown rig preset {name!r}; choose one of {', '.join(sorted(PRESETS))}"
        )
    rig = PRESETS[name].build()
    # Every camera must see the stage centre; a preset that fails this is a bug.
    proj = rig.project(np.array([PRESETS[name].target]))
    if not proj.in_image.all():
        raise ValidationError(f"rig preset {name!r}: some camera does not see the stage centre")
    return rig
