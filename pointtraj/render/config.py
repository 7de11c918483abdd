"""What :func:`~pointtraj.render.stage.render_work` draws, and how: :class:`RenderConfig`."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from ..errors import ValidationError
from ..geometry import parse_up

__all__ = ["ORBIT", "RenderConfig"]

#: The view name of the orbiting virtual camera.
ORBIT = "orbit"


@dataclass(frozen=True)
class RenderConfig:
    """What :func:`render_work` draws, and how.

    Parameters
    ----------
    engine : {"open3d", "opencv"}
        Renderer of the views: Open3D off-screen (Filament; pinhole, about 1-2 s a 1280x1024
        frame on a CPU) or OpenCV projection and drawing (distortion included, 10-30x faster).
        Overlays on camera images always use OpenCV.
    views : tuple of str
        Views rendered on a plain background: ``"orbit"`` (a virtual camera circling the scene)
        and/or names of rig cameras (rendered at the camera's image size). May be empty when
        overlays are on.
    tail : int
        Past frames drawn as a polyline behind each point (the paper draws 10 or 30).
    tail_fade : float
        How far, in [0, 1], the oldest tail segment's colour moves towards the background (the
        newest keeps the label colour), so tails show direction. Views only.
    frames : (int or None, int or None), optional
        Frames ``A:B`` rendered (B exclusive; negative values count from the end of the store's
        T frames; None is 0 or T); default the frames where trajectories exist.
    stride : int
        Render every ``stride``-th frame of the range.
    size : (int, int)
        ``(width, height)`` of the orbit view.
    point_size : float
        Point diameter in pixels in the views (pixels, so the same at any scene scale: the
        views' framing and clipping follow the scene's extent).
    line_width : float
        Tail width in pixels in the views.
    background : (int, int, int)
        RGB background of the views.
    orbit_fov_deg : float
        Horizontal field of view of the orbit camera.
    orbit_elevation_deg : float
        Angle of the orbit camera above the horizontal plane through the scene centre.
    orbit_start_deg : float
        Azimuth of the orbit camera at frame 0, measured from the rig's first camera (from world
        x when there is no rig).
    orbit_deg_per_frame : float
        Degrees the orbit camera turns per frame (0: a fixed virtual camera). The camera of
        frame t is the same in every run, whatever the range.
    orbit_distance : float, optional
        Distance from the scene centre in metres (default: a sphere holding 95% of the points,
        enlarged by 10%, fills the view).
    orbit_center : (float, float, float), optional
        Point the orbit camera looks at (default: the median of all point positions, so
        outliers do not move it).
    floor : bool
        Draw a light grid on the floor (the 1st percentile of the points' heights along
        ``up``) in the views. Its spacing is a round number (1, 2, 2.5 or 5 times a power of
        ten) near a sixth of the scene's extent, so it suits a room or a 1 cm subject.
    up : str or (float, float, float)
        The world's up direction, normal to the floor grid and the axis the orbit turns about:
        ``"auto"`` (the capture's ``capture.toml`` ``up`` if set, else detected from the
        cameras by :func:`pointtraj.geometry.detect_up`, else +z), one of ``"+x"``, ``"-x"``,
        ``"+y"``, ``"-y"``, ``"+z"``, ``"-z"``, or 3 numbers (a direction).
    fps : float, optional
        Frame rate of the MP4s (default the capture's, else the store's, divided by
        ``stride``: real time).
    video : bool
        Write an MP4 per view and per overlay camera.
    overlays : bool
        Draw the labelled points and tails over the input camera images.
    overlay_cameras : tuple of str
        Cameras of the overlays (default: the rig cameras among ``views``, else the rig's
        first camera).
    overlay_radius : int
        Point radius of the overlays in pixels.
    colors : {"auto", "labels", "semantic_map", "grey"}
        Colour source: ``labels.npz`` (``pointtraj label``), the argmax of ``semantic_map.npz``
        (``pointtraj semantics``), or grey for all. ``"auto"`` takes the first that exists and
        is an error when neither does.
    color_by : {"label", "instance"}
        Colour each trajectory by its class (``colors``), or by its person
        (``labels.npz`` ``instance``: one colour per person, grey for points on no person;
        needs ``pointtraj label``).
    min_length : int
        Draw only trajectories living at least this many frames (1 draws all).
    unlabelled : bool
        Draw the unlabelled trajectories (label -1, grey). Off shows only the labelled people
        and objects of a real capture, whose room is mostly unlabelled.
    legend : bool
        Draw the legend (class name and colour of each class drawn) in the images; it is
        written to ``renders/legend.png`` in any case.
    legend_corner : {"auto", "top-left", "top-right", "bottom-right", "bottom-left"}
        Where the legend goes. ``"auto"``: per view or overlay, the corner (of top-left,
        top-right, bottom-right) whose legend box covers the fewest of the points drawn,
        over up to 16 frames spread over the store's frames, so that it does not hide the
        subject (a person filling a portrait video); the same corner in every frame.
    caption : bool
        Write the view name and frame number at the bottom-left of each image.
    """

    engine: Literal["open3d", "opencv"] = "open3d"
    views: tuple[str, ...] = (ORBIT,)
    tail: int = 10
    tail_fade: float = 0.6
    frames: tuple[int | None, int | None] | None = None
    stride: int = 1
    size: tuple[int, int] = (1280, 1024)
    point_size: float = 4.0
    line_width: float = 1.5
    background: tuple[int, int, int] = (255, 255, 255)
    orbit_fov_deg: float = 40.0
    orbit_elevation_deg: float = 20.0
    orbit_start_deg: float = 30.0
    orbit_deg_per_frame: float = 1.0
    orbit_distance: float | None = None
    orbit_center: tuple[float, float, float] | None = None
    floor: bool = True
    up: str | tuple[float, float, float] = "auto"
    fps: float | None = None
    video: bool = True
    overlays: bool = True
    overlay_cameras: tuple[str, ...] = ()
    overlay_radius: int = 2
    colors: Literal["auto", "labels", "semantic_map", "grey"] = "auto"
    color_by: Literal["label", "instance"] = "label"
    min_length: int = 1
    unlabelled: bool = True
    legend: bool = True
    legend_corner: Literal["auto", "top-left", "top-right", "bottom-right", "bottom-left"] = "auto"
    caption: bool = True

    def __post_init__(self) -> None:
        def bad(name: str, what: str) -> ValidationError:
            return ValidationError(f"{name}: {what}, got {getattr(self, name)!r}")

        for name in ("views", "overlay_cameras"):
            value = getattr(self, name)
            if isinstance(value, str):
                value = (value,)
            # Drop repeats, keep the order.
            object.__setattr__(self, name, tuple(dict.fromkeys(str(v) for v in value)))
        if self.engine not in ("open3d", "opencv"):
            raise bad("engine", "must be 'open3d' or 'opencv'")
        if self.legend_corner not in (
            "auto",
            "top-left",
            "top-right",
            "bottom-right",
            "bottom-left",
        ):
            raise bad(
                "legend_corner",
                "must be 'auto', 'top-left', 'top-right', 'bottom-right' or 'bottom-left'",
            )
        if self.colors not in ("auto", "labels", "semantic_map", "grey"):
            raise bad("colors", "must be 'auto', 'labels', 'semantic_map' or 'grey'")
        if self.color_by not in ("label", "instance"):
            raise bad("color_by", "must be 'label' or 'instance'")
        if not self.views and not self.overlays:
            raise ValidationError("views: empty and overlays off: nothing to render")
        for name in ("tail", "stride", "min_length", "overlay_radius"):
            v = getattr(self, name)
            if isinstance(v, bool) or int(v) != v:
                raise bad(name, "must be an integer")
        if self.tail < 0 or self.overlay_radius < 0:
            raise bad("tail" if self.tail < 0 else "overlay_radius", "must be non-negative")
        if self.stride < 1 or self.min_length < 1:
            raise bad("stride" if self.stride < 1 else "min_length", "must be at least 1")
        if not 0 <= self.tail_fade <= 1:
            raise bad("tail_fade", "must be in [0, 1]")
        if self.frames is not None and len(self.frames) != 2:
            raise bad("frames", "must be (A, B)")
        if len(self.size) != 2 or min(self.size) < 16 or any(int(s) != s for s in self.size):
            raise bad("size", "must be (width, height), integers of at least 16")
        object.__setattr__(self, "size", (int(self.size[0]), int(self.size[1])))
        if self.point_size <= 0 or self.line_width <= 0:
            raise bad("point_size" if self.point_size <= 0 else "line_width", "must be positive")
        if len(self.background) != 3 or any(not 0 <= c <= 255 for c in self.background):
            raise bad("background", "must be 3 values in 0..255")
        if not 1 <= self.orbit_fov_deg <= 170:
            raise bad("orbit_fov_deg", "must be in [1, 170]")
        if not -89 <= self.orbit_elevation_deg <= 89:
            raise bad("orbit_elevation_deg", "must be in [-89, 89]")
        if self.orbit_distance is not None and not self.orbit_distance > 0:
            raise bad("orbit_distance", "must be positive")
        if self.orbit_center is not None and len(self.orbit_center) != 3:
            raise bad("orbit_center", "must be 3 coordinates")
        if not isinstance(self.up, str):
            object.__setattr__(self, "up", tuple(float(v) for v in self.up))
        parse_up(self.up, "up")  # raises ValidationError naming the valid values
        if self.fps is not None and not self.fps > 0:
            raise bad("fps", "must be positive")
