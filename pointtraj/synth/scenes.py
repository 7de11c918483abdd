"""Synthetic scenes: textured rigid geometries with scripted motion, and their registry.

A :class:`Scene` is a list of :class:`Geometry` (a mesh in its local frame, a class label, an
instance id and a procedural texture) plus a function giving every geometry's local-to-world
pose at a time. Scenes are deterministic for a given seed.

Registered scenes (:data:`SCENES`):

- ``dribble``: one figure stepping in place and turning slowly while dribbling a ball with its
  right hand (the paper's Basketball I). Figure instance 0, ball instance 1.
- ``two_people``: two figures walking on concentric circles in opposite directions, so they pass
  and occlude each other every ~3 s. Instances 0 and 1.
- ``static_room``: a static, strongly textured room (floor, walls, crates) for calibration
  tests; every surface is labelled (floor, wall, crate).

The action scenes have a textured floor disc with label -1 (background).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from ..errors import ValidationError
from ..labelset import BODY_PARTS
from .figure import (
    Figure,
    Pose,
    make_dribble_motion,
    rigid,
    rot_z,
    walking_pose,
)
from .objects import BallPath, PartMesh, make_box, make_ellipsoid, make_quad
from .texture import SolidTexture, make_solid_texture

__all__ = [
    "Geometry",
    "Scene",
    "SceneSpec",
    "SCENES",
    "STAGE_CENTRE",
    "make_scene",
    "scale_scene",
    "CLASS_COLORS",
]

#: The centre of the registered scenes' stage (metres; floor at z = 0): what
#: :func:`scale_scene` scales about.
STAGE_CENTRE = (0.0, 0.0, 0.9)

logger = logging.getLogger(__name__)

#: Display colour (RGB) of each class that synthetic scenes use.
CLASS_COLORS: dict[str, tuple[int, int, int]] = {
    "head": (230, 25, 75),
    "torso": (60, 180, 75),
    "left_upper_arm": (255, 225, 25),
    "right_upper_arm": (0, 130, 200),
    "left_forearm": (245, 130, 48),
    "right_forearm": (145, 30, 180),
    "left_hand": (70, 240, 240),
    "right_hand": (240, 50, 230),
    "left_thigh": (210, 245, 60),
    "right_thigh": (250, 190, 212),
    "left_shin": (0, 128, 128),
    "right_shin": (220, 190, 255),
    "left_foot": (170, 110, 40),
    "right_foot": (128, 0, 0),
    "ball": (128, 128, 0),  # olive: apart from the orange of left_forearm
    "floor": (128, 128, 128),
    "wall": (170, 255, 195),
    "crate": (0, 0, 128),
}

# Albedo base colour of each body part (clothes, skin), in [0, 1].
_PART_ALBEDO: dict[str, tuple[float, float, float]] = {
    "head": (0.85, 0.65, 0.5),
    "torso": (0.2, 0.45, 0.8),
    "left_upper_arm": (0.3, 0.6, 0.9),
    "right_upper_arm": (0.25, 0.55, 0.35),
    "left_forearm": (0.9, 0.7, 0.55),
    "right_forearm": (0.8, 0.6, 0.45),
    "left_hand": (0.95, 0.75, 0.6),
    "right_hand": (0.75, 0.55, 0.4),
    "left_thigh": (0.25, 0.25, 0.35),
    "right_thigh": (0.45, 0.3, 0.2),
    "left_shin": (0.5, 0.45, 0.3),
    "right_shin": (0.3, 0.4, 0.45),
    "left_foot": (0.9, 0.9, 0.9),
    "right_foot": (0.8, 0.2, 0.2),
}


@dataclass(eq=False)
class Geometry:
    """One rigid, textured mesh of a scene.

    Attributes
    ----------
    name : str
        Unique within the scene, e.g. ``"person0/left_hand"``.
    mesh : PartMesh
        In the geometry's local frame.
    label : int
        Class index into the scene's classes, -1 for background.
    instance : int
        Instance id, -1 for background.
    base_color : (3,) tuple of float
        Texture base albedo.
    texture_seed : int
        Seed of its texture.
    texture_voxel, texture_scale : float
        See :func:`make_solid_texture` (at the human size).
    size : float
        The mesh's size against its human-sized original (:func:`scale_scene`): the texture
        is the original's, its voxels ``size`` times as large, so that a scaled part looks
        exactly as the original does.
    """

    name: str
    mesh: PartMesh
    label: int
    instance: int
    base_color: tuple[float, float, float]
    texture_seed: int
    texture_voxel: float = 0.004
    texture_scale: float = 1.0
    size: float = 1.0

    @cached_property
    def texture(self) -> SolidTexture:
        """The baked solid texture (built on first use)."""
        lo, hi = self.mesh.bounds
        tex = make_solid_texture(
            lo / self.size,
            hi / self.size,
            self.base_color,
            np.random.default_rng(self.texture_seed),
            voxel=self.texture_voxel,
            scale=self.texture_scale,
        )
        if self.size != 1.0:
            tex = SolidTexture(
                origin=tex.origin * self.size, voxel=tex.voxel * self.size, volume=tex.volume
            )
        return tex


@dataclass(eq=False)
class Scene:
    """Geometries, classes and motion of a synthetic scene.

    Attributes
    ----------
    name : str
    class_names : list of str
        Class index order (written to labels.toml).
    class_kinds : list of str
        ``"body"`` or ``"object"`` per class.
    geometries : list of Geometry
    pose_fn : callable
        ``pose_fn(t) -> (G, 4, 4)`` local-to-world matrices at time ``t`` seconds.
    seed : int
    extras : dict
        Scene-specific objects, e.g. ``"ball"``: the :class:`BallPath` of ``dribble`` (at the
        scene's human size), and ``"recognizers"``: recogniser output name -> class mappings
        for ``labels.toml``.
    scale : float
        Size against the human-sized original (:func:`scale_scene`; 1 for a registered scene).
    """

    name: str
    class_names: list[str]
    class_kinds: list[str]
    geometries: list[Geometry]
    pose_fn: Callable[[float], np.ndarray] = field(repr=False)
    seed: int = 0
    extras: dict[str, object] = field(default_factory=dict)
    scale: float = 1.0

    @property
    def class_colors(self) -> np.ndarray:
        """(K, 3) uint8 display colours."""
        return np.array([CLASS_COLORS[n] for n in self.class_names], np.uint8).reshape(-1, 3)

    def poses(self, t: float) -> np.ndarray:
        """(G, 4, 4) local-to-world matrix of every geometry at time ``t`` (seconds)."""
        return self.pose_fn(float(t))

    @property
    def labelled(self) -> np.ndarray:
        """(G,) bool: geometries with a class (they carry ground-truth points)."""
        return np.array([g.label >= 0 for g in self.geometries])


@dataclass(frozen=True)
class SceneSpec:
    """A registered scene: a description and ``build(seed) -> Scene``."""

    description: str
    build: Callable[[int], Scene]


def _jitter(color: tuple[float, float, float], rng: np.random.Generator) -> tuple[float, ...]:
    return tuple(float(c) for c in np.clip(np.asarray(color) + rng.normal(0, 0.06, 3), 0.05, 0.95))


def _figure_geometries(fig: Figure, classes: list[str], rng: np.random.Generator) -> list[Geometry]:
    return [
        Geometry(
            name=f"{fig.name}/{part}",
            mesh=fig.meshes[part],
            label=classes.index(part),
            instance=fig.instance,
            base_color=_jitter(_PART_ALBEDO[part], rng),
            texture_seed=int(rng.integers(2**31)),
        )
        for part in BODY_PARTS
    ]


def _floor(rng: np.random.Generator, half: float = 3.5) -> Geometry:
    return Geometry(
        name="floor",
        mesh=make_quad((0.0, 0.0, 0.0), (half, 0.0, 0.0), (0.0, half, 0.0), subdivisions=4),
        label=-1,
        instance=-1,
        base_color=(0.55, 0.5, 0.45),
        texture_seed=int(rng.integers(2**31)),
        texture_voxel=0.008,
        texture_scale=2.0,
    )


def _stack(parts: list[np.ndarray]) -> np.ndarray:
    return np.stack(parts).astype(np.float64)


def build_dribble(seed: int) -> Scene:
    """One figure dribbling a ball (Basketball I). See the module docstring."""
    rng = np.random.default_rng(seed)
    classes = [*BODY_PARTS, "ball"]
    ball = BallPath(phase=float(rng.uniform(0, 0.5)))
    motion, ball_center = make_dribble_motion(ball, turn=0.5 + 0.1 * float(rng.random()))
    fig = Figure("person0", 0, motion)
    geoms = _figure_geometries(fig, classes, rng)
    geoms.append(
        Geometry(
            name="ball",
            mesh=make_ellipsoid((0.0, 0.0, 0.0), (ball.radius,) * 3, rings=20, segments=28),
            label=classes.index("ball"),
            instance=1,
            base_color=(0.9, 0.45, 0.1),
            texture_seed=int(rng.integers(2**31)),
            texture_scale=0.8,
        )
    )
    geoms.append(_floor(rng))

    def poses(t: float) -> np.ndarray:
        parts = fig.part_transforms(t)
        spin = rot_z(3.0 * t) @ np.array(
            [
                [1, 0, 0],
                [0, math.cos(2 * t), -math.sin(2 * t)],
                [0, math.sin(2 * t), math.cos(2 * t)],
            ]
        )
        return _stack([parts[p] for p in BODY_PARTS] + [rigid(spin, ball_center(t)), np.eye(4)])

    kinds = ["body"] * 14 + ["object"]
    extras = {"ball": ball, "recognizers": {"object-detector": {"sports_ball": "ball"}}}
    return Scene("dribble", classes, kinds, geoms, poses, seed, extras=extras)


def build_two_people(seed: int) -> Scene:
    """Two figures walking on concentric circles in opposite directions (mutual occlusion)."""
    rng = np.random.default_rng(seed)
    classes = list(BODY_PARTS)
    cycle = 1.2  # metres per gait cycle (two steps)
    tracks = [(0.4, 0.45, float(rng.uniform(0, 2 * math.pi))), (1.05, -0.5, 0.0)]
    figures = []
    for inst, (radius, speed, start) in enumerate(tracks):

        def motion(fig: Figure, t: float, radius=radius, speed=speed, start=start) -> Pose:
            ang = start + speed * t / radius
            heading = ang + math.copysign(math.pi / 2, speed)
            root = rigid(rot_z(heading), (radius * math.cos(ang), radius * math.sin(ang), 0.0))
            phase = 2 * math.pi * abs(speed) * t / cycle
            return Pose(root=root, joints=walking_pose(phase))

        figures.append(Figure(f"person{inst}", inst, motion))
    geoms = []
    for fig in figures:
        geoms += _figure_geometries(fig, classes, rng)
    geoms.append(_floor(rng))

    def poses(t: float) -> np.ndarray:
        mats = []
        for fig in figures:
            parts = fig.part_transforms(t)
            mats += [parts[p] for p in BODY_PARTS]
        return _stack(mats + [np.eye(4)])

    return Scene("two_people", classes, ["body"] * 14, geoms, poses, seed)


def build_static_room(seed: int) -> Scene:
    """A static textured room: floor, four walls and a few crates, all labelled."""
    rng = np.random.default_rng(seed)
    classes = ["floor", "wall", "crate"]
    half, height = 3.0, 2.6
    geoms = [
        Geometry(
            "floor",
            make_quad((0, 0, 0), (half, 0, 0), (0, half, 0), subdivisions=4),
            0,
            -1,
            (0.55, 0.5, 0.45),
            int(rng.integers(2**31)),
            0.008,
            2.0,
        )
    ]
    walls = [((half, 0), (0, 1)), ((-half, 0), (0, -1)), ((0, half), (-1, 0)), ((0, -half), (1, 0))]
    for i, ((x, y), (ux, uy)) in enumerate(walls):
        # Normal u x v points into the room.
        geoms.append(
            Geometry(
                f"wall{i}",
                make_quad((x, y, height / 2), (ux * half, uy * half, 0), (0, 0, height / 2), 4),
                1,
                -1,
                _jitter((0.6, 0.6, 0.55), rng),
                int(rng.integers(2**31)),
                0.008,
                2.0,
            )
        )
    n_crates = 4
    angles = rng.uniform(0, 2 * math.pi, n_crates)
    for i in range(n_crates):
        size = rng.uniform(0.25, 0.6, 3)
        r = rng.uniform(0.3, 1.1)
        centre = (r * math.cos(angles[i]), r * math.sin(angles[i]))
        lo = (centre[0] - size[0] / 2, centre[1] - size[1] / 2, 0.0)
        hi = (centre[0] + size[0] / 2, centre[1] + size[1] / 2, size[2])
        geoms.append(
            Geometry(
                f"crate{i}",
                make_box(lo, hi),
                2,
                -1,
                _jitter((0.6, 0.45, 0.25), rng),
                int(rng.integers(2**31)),
                0.005,
                1.0,
            )
        )
    eye = np.broadcast_to(np.eye(4), (len(geoms), 4, 4)).copy()
    return Scene("static_room", classes, ["object"] * 3, geoms, lambda t: eye.copy(), seed)


#: Scene name -> spec.
SCENES: dict[str, SceneSpec] = {
    "dribble": SceneSpec(
        "one figure dribbling a ball while stepping in place and turning (Basketball I)",
        build_dribble,
    ),
    "two_people": SceneSpec(
        "two figures walking on concentric circles in opposite directions, occluding each other",
        build_two_people,
    ),
    "static_room": SceneSpec(
        "a static textured room (floor, walls, crates) for calibration tests", build_static_room
    ),
}


def make_scene(name: str, seed: int = 0) -> Scene:
    """Build a registered scene.

    Parameters
    ----------
    name : str
        A key of :data:`SCENES`.
    seed : int
        Seeds textures and motion parameters.

    Returns
    -------
    Scene

    Raises
    ------
    ValidationError
        If the scene is unknown (the message lists the valid names).

    Examples
    --------
    >>> scene = make_scene("dribble", seed=0)
    >>> scene.class_names[-1], scene.poses(0.0).shape
    ('ball', (16, 4, 4))
    """
    if name not in SCENES:
        raise ValidationError(f"unknown scene {name!r}; choose one of {', '.join(sorted(SCENES))}")
    return SCENES[name].build(int(seed))


def scale_scene(
    scene: Scene,
    factor: float,
    target: tuple[float, float, float] = STAGE_CENTRE,
    centre: tuple[float, float, float] = STAGE_CENTRE,
) -> Scene:
    """The scene scaled by ``factor`` about ``centre``, which moves to ``target``.

    Geometry, motion and texture are all scaled: every mesh's vertices, the poses'
    translations (``x' = target + factor * (x - centre)``; rotations, and so the motion's
    timing, are unchanged) and each texture's voxel and feature sizes, so that the images of a
    scaled scene seen by a rig scaled by the same factor are those of the original. Ground
    truth sampled from it (:func:`~.groundtruth.sample_ground_truth_points`) is the original's
    times ``factor``.

    Parameters
    ----------
    scene : Scene
    factor : float
        Positive.
    target, centre : (3,) tuple of float
        Metres.

    Returns
    -------
    Scene
        With ``scale`` multiplied by ``factor``; ``scene`` itself when nothing changes.
    """
    f = float(factor)
    if not (f > 0 and math.isfinite(f)):
        raise ValidationError(f"scene scale must be a positive number, got {factor!r}")
    c, tgt = np.asarray(centre, float), np.asarray(target, float)
    if f == 1.0 and np.array_equal(c, tgt):
        return scene
    geoms = [
        Geometry(
            name=g.name,
            mesh=PartMesh(g.mesh.vertices * f, g.mesh.triangles, g.mesh.normals),
            label=g.label,
            instance=g.instance,
            base_color=g.base_color,
            texture_seed=g.texture_seed,
            texture_voxel=g.texture_voxel,
            texture_scale=g.texture_scale,
            size=g.size * f,
        )
        for g in scene.geometries
    ]
    pose_fn = scene.pose_fn

    def poses(t: float) -> np.ndarray:
        P = np.array(pose_fn(t), dtype=np.float64, copy=True)  # (G, 4, 4)
        P[:, :3, 3] = tgt + f * (P[:, :3, 3] - c)
        return P

    return Scene(
        scene.name,
        list(scene.class_names),
        list(scene.class_kinds),
        geoms,
        poses,
        scene.seed,
        dict(scene.extras),
        scene.scale * f,
    )
