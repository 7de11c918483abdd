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
paper69t   69       160x128     75        paper69's geometry at an eighth of its resolution,
                                          sampled at 10 Hz (the paper's 15 s Table 1 on
                                          2 cores: ``pipelines/paper_table1.toml``)
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

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..camera import Camera, CameraRig
from ..errors import ValidationError
from .scenes import STAGE_CENTRE

__all__ = [
    "PRESETS",
    "RigPreset",
    "make_rig",
    "ring_cameras",
    "field_of_view",
    "scale_rig",
    "twin_rig",
    "axes_meeting_point",
]

logger = logging.getLogger(__name__)


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


def _paper69_at(size: tuple[int, int], focal: float) -> CameraRig:
    """paper69's two rings with another image size and focal length (the same fields of view
    when both are scaled together)."""
    radius = 1.6
    lower = ring_cameras(35, radius, 1.0, (0.0, 0.0, 0.9), size, focal)
    upper = ring_cameras(
        34, radius, 2.2, (0.0, 0.0, 1.1), size, focal, start_angle=math.pi / 34, first_index=35
    )
    return CameraRig(lower + upper)


def _paper69() -> CameraRig:
    return _paper69_at((1280, 1024), 600.0)


def _paper69q() -> CameraRig:
    return _paper69_at((320, 256), 150.0)


def _paper69t() -> CameraRig:
    return _paper69_at((160, 128), 75.0)


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
    "paper69t": RigPreset(
        "paper69 at an eighth of its resolution, sampled at 10 Hz: 69 cameras, 160x128, "
        "f=75 px (the same fields of view and geometry; scene time is frame / fps, so the "
        "motion is that of 30 Hz), for the paper's 15 s studies",
        _paper69t,
        fps=10.0,
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


def axes_meeting_point(rig: CameraRig) -> np.ndarray:
    """The point nearest to every camera's optical axis, in the least-squares sense.

    Parameters
    ----------
    rig : CameraRig
        C cameras (at least 2).

    Returns
    -------
    (3,) float ndarray
        World coordinates.

    Raises
    ------
    ValidationError
        If the axes are (nearly) parallel, so that they meet nowhere.

    Examples
    --------
    >>> (np.round(axes_meeting_point(make_rig("ring8")), 6) + 0.0).tolist()  # + 0.0: no -0.0
    [0.0, 0.0, 0.85]
    """
    d = np.asarray(rig.R, np.float64)[:, 2]  # (C, 3) optical axes
    proj = np.eye(3)[None] - d[:, :, None] * d[:, None, :]  # (C, 3, 3) off-axis projectors
    A = proj.sum(axis=0)
    if len(rig) < 2 or np.linalg.cond(A) > 1e6:
        raise ValidationError(
            "the cameras' optical axes do not meet (fewer than 2 cameras, or all parallel); "
            "give the subject's position"
        )
    return np.linalg.solve(A, np.einsum("cij,cj->i", proj, np.asarray(rig.C, np.float64)))


def twin_rig(
    rig: CameraRig,
    *,
    at: object = None,
    up: object = "auto",
    scale: float = 1.0,
) -> tuple[CameraRig, str]:
    """A user's rig moved into the synthetic scenes' frame: a synthetic twin of a real capture.

    The scenes stand on the floor ``z = 0`` with their centre at :data:`STAGE_CENTRE` (0.9 m up,
    the figure's waist). The rig is moved rigidly so that the point ``at`` (the subject's centre
    in the rig's coordinates; by default where the cameras' optical axes meet,
    :func:`axes_meeting_point`) lands on the stage centre and the rig's up direction
    (:func:`pointtraj.geometry.resolve_up`) becomes +z; its horizontal heading is kept.
    Intrinsics, distortion and image sizes are unchanged, so the twin's images show what the
    real cameras would see of the synthetic subject.

    Parameters
    ----------
    rig : CameraRig
        The user's C cameras.
    at : (3,) array-like, optional
        The subject's centre in the rig's world coordinates (its units).
    up : str or (3,) array-like
        The rig's up direction (:func:`pointtraj.geometry.parse_up`); ``"auto"`` detects it.
    scale : float
        Metres per unit of the rig's coordinates (1 for a rig in metres, 0.001 in mm).

    Returns
    -------
    twin : CameraRig
        The cameras in the scene frame (metres).
    how : str
        One line for the log: where the subject was put and how up was found.

    Raises
    ------
    ValidationError
        On a bad ``at``, ``up`` or ``scale``, or a rig whose axes do not meet when ``at`` is
        not given.
    """
    from ..geometry import resolve_up

    if not (np.isfinite(scale) and scale > 0):
        raise ValidationError(f"scale must be a positive number of metres per unit, got {scale!r}")
    if at is None:
        centre = axes_meeting_point(rig)
        where = "where the optical axes meet"
    else:
        centre = np.asarray(at, np.float64).reshape(-1)
        if centre.shape != (3,) or not np.isfinite(centre).all():
            raise ValidationError(f"at must be 3 finite numbers (x, y, z), got {at!r}")
        where = "as given"
    up_vec, up_how = resolve_up(up, rig)
    z = up_vec / np.linalg.norm(up_vec)
    x = np.array([1.0, 0.0, 0.0]) - z[0] * z  # the rig's x axis, made horizontal
    if np.linalg.norm(x) < 1e-6:
        x = np.array([0.0, 1.0, 0.0]) - z[1] * z
    x /= np.linalg.norm(x)
    Rw = np.stack([x, np.cross(z, x), z])  # (3, 3) rig frame to scene frame
    stage = np.asarray(STAGE_CENTRE)
    cams = [
        Camera(
            cam.name, cam.K, cam.R @ Rw.T, Rw @ (cam.C - centre) * scale + stage, cam.size, cam.dist
        )
        for cam in rig
    ]
    twin = CameraRig(cams)
    unseen = [cam.name for cam, ok in zip(twin, twin.project(stage[None]).in_image[:, 0]) if not ok]
    if unseen:
        logger.warning(
            "synthetic twin: %d of %d cameras do not see the subject's centre (%s); they will "
            "see little of the scene",
            len(unseen),
            len(twin),
            ", ".join(unseen),
        )
    how = (
        f"subject centre {np.round(centre, 3).tolist()} ({where}) on the stage centre, "
        f"up {np.round(z, 3).tolist()} ({up_how}), {scale:g} m per unit"
    )
    return twin, how
