"""Articulated figures: rigid textured body parts posed by a kinematic chain.

A figure's root frame has x forward, y to its left and z up, with the origin at the pelvis. Every
part has its own local frame whose origin is its proximal joint; limbs hang along local -z in the
rest pose (standing, arms down, palms facing the thighs). A pose is a set of joint rotations; the
forward kinematics (:meth:`Figure.part_transforms`) chains them into local-to-world (4, 4)
matrices, then lifts the figure so that its lowest foot touches the floor (z = 0).

Motions are smooth functions of time (seconds): stepping in place while turning, walking along a
path, arm swing, and a dribble in which the right hand follows the ball down and up (two-bone
inverse kinematics of the right arm).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ..labelset import BODY_PARTS
from .objects import BallPath, PartMesh, make_capsule, make_ellipsoid

__all__ = [
    "BodyShape",
    "Figure",
    "Pose",
    "build_body_meshes",
    "stepping_pose",
    "walking_pose",
    "make_dribble_motion",
    "rot_x",
    "rot_y",
    "rot_z",
    "rigid",
    "solve_two_bone",
]


def rot_x(a: float) -> np.ndarray:
    """(3, 3) rotation by ``a`` radians about x."""
    c, s = math.cos(a), math.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def rot_y(a: float) -> np.ndarray:
    """(3, 3) rotation by ``a`` radians about y."""
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def rot_z(a: float) -> np.ndarray:
    """(3, 3) rotation by ``a`` radians about z."""
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def rigid(R: np.ndarray | None = None, t: object = (0.0, 0.0, 0.0)) -> np.ndarray:
    """(4, 4) rigid transform from a rotation and a translation."""
    m = np.eye(4)
    if R is not None:
        m[:3, :3] = R
    m[:3, 3] = np.asarray(t, float)
    return m


@dataclass(frozen=True)
class BodyShape:
    """Segment lengths and radii of a figure, metres (defaults: a 1.70 m adult)."""

    torso_length: float = 0.52
    torso_radii: tuple[float, float, float] = (0.12, 0.175, 0.30)
    head_radii: tuple[float, float, float] = (0.10, 0.085, 0.12)
    shoulder_width: float = 0.40
    hip_width: float = 0.18
    upper_arm: float = 0.29
    upper_arm_radius: float = 0.046
    forearm: float = 0.26
    forearm_radius: float = 0.038
    hand_radii: tuple[float, float, float] = (0.045, 0.022, 0.085)
    thigh: float = 0.42
    thigh_radius: float = 0.068
    shin: float = 0.42
    shin_radius: float = 0.048
    ankle_height: float = 0.07
    foot_radii: tuple[float, float, float] = (0.125, 0.048, 0.04)

    @property
    def shoulder(self) -> np.ndarray:
        """Left shoulder joint in the torso frame (the right one mirrors y)."""
        return np.array([0.0, self.shoulder_width / 2, self.torso_length - 0.07])


def build_body_meshes(shape: BodyShape) -> dict[str, PartMesh]:
    """The 14 closed part meshes of a figure, each in its part's local frame.

    Parameters
    ----------
    shape : BodyShape

    Returns
    -------
    dict
        Part name (:data:`pointtraj.labelset.BODY_PARTS`) -> :class:`PartMesh`.
    """
    tr = shape.torso_radii
    meshes = {
        "torso": make_ellipsoid((0.0, 0.0, shape.torso_length / 2), tr, rings=20, segments=28),
        "head": make_ellipsoid((0.01, 0.0, shape.head_radii[2] + 0.02), shape.head_radii),
    }
    for side in ("left", "right"):
        meshes[f"{side}_upper_arm"] = make_capsule(
            shape.upper_arm, shape.upper_arm_radius, radius_end=0.9 * shape.upper_arm_radius
        )
        meshes[f"{side}_forearm"] = make_capsule(
            shape.forearm, shape.forearm_radius, radius_end=0.8 * shape.forearm_radius
        )
        meshes[f"{side}_hand"] = make_ellipsoid(
            (0.0, 0.0, -shape.hand_radii[2]), shape.hand_radii, rings=12, segments=18
        )
        meshes[f"{side}_thigh"] = make_capsule(
            shape.thigh, shape.thigh_radius, radius_end=0.8 * shape.thigh_radius
        )
        meshes[f"{side}_shin"] = make_capsule(
            shape.shin, shape.shin_radius, radius_end=0.8 * shape.shin_radius
        )
        fr = shape.foot_radii
        meshes[f"{side}_foot"] = make_ellipsoid(
            (0.06, 0.0, -shape.ankle_height + fr[2]), fr, rings=12, segments=20
        )
    return {name: meshes[name] for name in BODY_PARTS}


@dataclass
class Pose:
    """Joint rotations and root placement of a figure at one instant.

    Attributes
    ----------
    root : (4, 4) float ndarray
        Pelvis frame in the world (its z is replaced so that the feet touch the floor).
    joints : dict
        Joint name -> (3, 3) rotation relative to the parent: ``spine``, ``neck``,
        ``{left,right}_{shoulder,elbow,wrist,hip,knee,ankle}``. Missing joints are identity.
    world : dict
        Part name -> (4, 4) local-to-world matrix overriding the chain (inverse kinematics).
    """

    root: np.ndarray
    joints: dict[str, np.ndarray] = field(default_factory=dict)
    world: dict[str, np.ndarray] = field(default_factory=dict)


def _flex(a: float) -> np.ndarray:
    """Rotation that swings a bone hanging along -z forwards (+x) by ``a`` radians."""
    return rot_y(-a)


def _side_sign(side: str) -> float:
    return 1.0 if side == "left" else -1.0


@dataclass(eq=False)
class Figure:
    """An articulated figure: meshes, body shape and a motion.

    Parameters
    ----------
    name : str
        Instance name (prefix of its geometry names).
    instance : int
        Instance id written to the ground truth.
    motion : callable
        ``motion(figure, t) -> Pose``.
    shape : BodyShape
    """

    name: str
    instance: int
    motion: Callable[[Figure, float], Pose]
    shape: BodyShape = field(default_factory=BodyShape)

    def __post_init__(self) -> None:
        self.meshes = build_body_meshes(self.shape)
        # Lowest points of the feet (the sole), used to put the figure on the floor.
        self._soles = {
            side: self.meshes[f"{side}_foot"].vertices[
                self.meshes[f"{side}_foot"].vertices[:, 2]
                < self.meshes[f"{side}_foot"].vertices[:, 2].min() + 0.01
            ]
            for side in ("left", "right")
        }

    def chain(self, pose: Pose) -> dict[str, np.ndarray]:
        """Forward kinematics of ``pose`` without the floor constraint.

        Returns
        -------
        dict
            Part name -> (4, 4) local-to-world matrix.
        """
        s, J = self.shape, pose.joints
        eye = np.eye(3)
        out = {"torso": pose.root @ rigid(J.get("spine", eye))}
        out["head"] = out["torso"] @ rigid(J.get("neck", eye), (0, 0, s.torso_length))
        for side in ("left", "right"):
            sg = _side_sign(side)
            sh = s.shoulder * (1, sg, 1)
            ua = out["torso"] @ rigid(J.get(f"{side}_shoulder", eye), sh)
            fa = ua @ rigid(J.get(f"{side}_elbow", eye), (0, 0, -s.upper_arm))
            ha = fa @ rigid(J.get(f"{side}_wrist", eye), (0, 0, -s.forearm))
            th = pose.root @ rigid(J.get(f"{side}_hip", eye), (0, sg * s.hip_width / 2, -0.02))
            sn = th @ rigid(J.get(f"{side}_knee", eye), (0, 0, -s.thigh))
            ft = sn @ rigid(J.get(f"{side}_ankle", eye), (0, 0, -s.shin))
            out.update(
                {
                    f"{side}_upper_arm": ua,
                    f"{side}_forearm": fa,
                    f"{side}_hand": ha,
                    f"{side}_thigh": th,
                    f"{side}_shin": sn,
                    f"{side}_foot": ft,
                }
            )
        out.update(pose.world)
        return out

    def ground(self, pose: Pose) -> Pose:
        """Shift ``pose.root`` vertically so that the lowest sole point touches z = 0."""
        parts = self.chain(pose)
        lowest = min(
            float(
                np.min(
                    self._soles[side] @ parts[f"{side}_foot"][2, :3] + parts[f"{side}_foot"][2, 3]
                )
            )
            for side in ("left", "right")
        )
        root = pose.root.copy()
        root[2, 3] -= lowest
        world = {k: rigid(None, (0, 0, -lowest)) @ v for k, v in pose.world.items()}
        return Pose(root=root, joints=pose.joints, world=world)

    def part_transforms(self, t: float) -> dict[str, np.ndarray]:
        """Local-to-world (4, 4) matrix of every part at time ``t`` (seconds), feet on the floor."""
        parts = self.chain(self.ground(self.motion(self, t)))
        return {name: parts[name] for name in BODY_PARTS}


def solve_two_bone(
    shoulder: np.ndarray,
    target: np.ndarray,
    l1: float,
    l2: float,
    pole: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Analytic two-bone inverse kinematics.

    Parameters
    ----------
    shoulder, target : (3,) float ndarray
        Root joint and where the end of the second bone should be (same frame).
    l1, l2 : float
        Bone lengths.
    pole : (3,) float ndarray
        Direction the middle joint (elbow) bends towards.

    Returns
    -------
    elbow, wrist : (3,) float ndarray
        Joint positions; the wrist is on the target, or as close as the bones reach.
    """
    v = target - shoulder
    d = float(np.linalg.norm(v))
    d = min(max(d, abs(l1 - l2) + 1e-6), 0.999 * (l1 + l2))
    vh = v / max(np.linalg.norm(v), 1e-12)
    p = pole - np.dot(pole, vh) * vh
    p /= max(np.linalg.norm(p), 1e-12)
    a = (l1**2 - l2**2 + d**2) / (2 * d)
    h = math.sqrt(max(l1**2 - a**2, 0.0))
    elbow = shoulder + a * vh + h * p
    return elbow, shoulder + d * vh


def _bone_frame(origin: np.ndarray, tip: np.ndarray, forward: np.ndarray) -> np.ndarray:
    """(4, 4) frame at ``origin`` whose -z points at ``tip`` and whose x leans to ``forward``."""
    b = (tip - origin) / np.linalg.norm(tip - origin)
    z = -b
    x = forward - np.dot(forward, z) * z
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return rigid(np.stack([x, y, z], axis=1), origin)


def stepping_pose(t: float, *, rate: float = 0.8, lift: float = 0.45) -> dict[str, np.ndarray]:
    """Joint rotations for stepping in place with a gentle arm swing.

    Parameters
    ----------
    t : float
        Time, seconds.
    rate : float
        Steps per second per leg.
    lift : float
        Peak hip flexion, radians.

    Returns
    -------
    dict
        Joint name -> (3, 3) rotation.
    """
    ph = 2 * math.pi * rate * t
    J = {}
    for side, sg in (("left", 1.0), ("right", -1.0)):
        up = max(0.0, sg * math.sin(ph)) ** 2  # smooth (C1) lift of one leg at a time
        hip, knee = lift * up + 0.05, 2 * lift * up + 0.1
        J[f"{side}_hip"] = _flex(hip)
        J[f"{side}_knee"] = rot_y(knee)
        J[f"{side}_ankle"] = rot_y(hip - knee)  # keep the foot level
        J[f"{side}_shoulder"] = _flex(-0.25 * sg * math.sin(ph)) @ rot_x(sg * 0.12)
        J[f"{side}_elbow"] = _flex(0.35 + 0.15 * math.sin(ph + sg))
        J[f"{side}_wrist"] = _flex(0.1)
    J["neck"] = rot_z(0.15 * math.sin(0.5 * ph))
    return J


def walking_pose(phase: float, *, stride: float = 0.4) -> dict[str, np.ndarray]:
    """Joint rotations of a walking gait at gait phase ``phase`` (radians).

    Parameters
    ----------
    phase : float
        Gait phase; one cycle (2 pi) is two steps.
    stride : float
        Peak hip swing, radians.

    Returns
    -------
    dict
        Joint name -> (3, 3) rotation.
    """
    J = {}
    for side, sg, off in (("left", 1.0, 0.0), ("right", -1.0, math.pi)):
        p = phase + off
        hip = stride * math.sin(p)
        knee = 0.15 + 0.55 * max(0.0, math.sin(p + 0.6)) ** 2
        J[f"{side}_hip"] = _flex(hip)
        J[f"{side}_knee"] = rot_y(knee)
        J[f"{side}_ankle"] = rot_y(hip - knee + 0.1 * math.cos(p))
        J[f"{side}_shoulder"] = _flex(-0.6 * stride * math.sin(p)) @ rot_x(sg * 0.1)
        J[f"{side}_elbow"] = _flex(0.3 + 0.2 * max(0.0, -math.sin(p)))
        J[f"{side}_wrist"] = _flex(0.05)
    J["spine"] = rot_z(0.08 * math.sin(phase))
    return J


def make_dribble_motion(
    ball: BallPath,
    spot: tuple[float, float] = (0.36, -0.30),
    turn: float = 0.5,
    turn_period: float = 6.0,
) -> tuple[Callable[[Figure, float], Pose], Callable[[float], np.ndarray]]:
    """A figure stepping in place, turning slowly, dribbling with the right hand.

    Parameters
    ----------
    ball : BallPath
        The ball's vertical motion (contact with the hand at the top of each bounce).
    spot : (2,) tuple
        Where the ball bounces, in the figure's root frame (x forward, y left), metres.
    turn : float
        Amplitude of the slow yaw oscillation, radians.
    turn_period : float
        Its period, seconds.

    Returns
    -------
    motion : callable
        ``motion(figure, t) -> Pose`` for :class:`Figure`.
    ball_center : callable
        ``ball_center(t) -> (3,)`` world position of the ball centre; in flight it moves on a
        straight horizontal line between release and catch (a true projectile).
    """

    def yaw(t: float) -> float:
        return turn * math.sin(2 * math.pi * t / turn_period)

    def spot_world(t: float) -> np.ndarray:
        return rot_z(yaw(t))[:2, :2] @ np.asarray(spot, float)

    def ball_center(t: float) -> np.ndarray:
        k, local, contact = ball.split(np.array(t))
        z = float(ball.height(np.array(t)))
        if contact:
            xy = spot_world(t)
        else:
            t0 = ball.phase + float(k) * ball.period + ball.contact  # release
            t1 = ball.phase + float(k + 1) * ball.period  # next catch
            s = (t - t0) / (t1 - t0)
            xy = (1 - s) * spot_world(t0) + s * spot_world(t1)
        return np.array([xy[0], xy[1], z])

    def motion(fig: Figure, t: float) -> Pose:
        s = fig.shape
        J = stepping_pose(t, rate=0.5, lift=0.12)
        # Knees bend a little with every bounce; small alternating steps (turning on the spot).
        knee = 0.33 + 0.06 * math.sin(2 * math.pi * t / ball.period + 1.0)
        step = math.sin(2 * math.pi * 0.4 * t)
        for side, sg in (("left", 1.0), ("right", -1.0)):
            up = 0.15 * max(0.0, sg * step) ** 2
            hip, knee_s = 0.5 * knee + up, knee + 2 * up
            J[f"{side}_hip"] = _flex(hip)
            J[f"{side}_knee"] = rot_y(knee_s)
            J[f"{side}_ankle"] = rot_y(hip - knee_s)
        J["spine"] = _flex(-0.2) @ rot_z(0.1 * math.sin(2 * math.pi * t / turn_period))
        J["left_shoulder"] = _flex(0.25 + 0.15 * math.sin(2 * math.pi * 0.7 * t)) @ rot_x(0.15)
        J["left_elbow"] = _flex(0.9 + 0.2 * math.sin(2 * math.pi * 0.7 * t + 1.0))
        pose = fig.ground(Pose(root=rigid(rot_z(yaw(t))), joints=J))
        root = pose.root
        fwd = root[:3, 0]
        # Palm target: on the ball top during contact (lifted by ``lift`` so that the tilted
        # fingers touch rather than enter the ball); in flight it dips and comes back up.
        lift = 0.011
        k, local, contact = ball.split(np.array(t))
        if contact:
            c = ball_center(t)
            palm = np.array([c[0], c[1], c[2] + ball.radius + lift])
        else:
            u = (float(local) - ball.contact) / (ball.period - ball.contact)
            top = ball.top + ball.radius + lift
            palm = np.array([*spot_world(t), top - 0.45 * u * (1 - u)])
        # Fingers point forward and 0.5 rad down, palm facing the floor.
        hand_R = rot_z(yaw(t)) @ rot_y(-(math.pi / 2 - 0.5)) @ rot_z(math.pi / 2)
        palm_local = np.array([0.0, s.hand_radii[1], -s.hand_radii[2]])
        wrist = palm - hand_R @ palm_local
        torso = fig.chain(pose)["torso"]
        shoulder = (torso @ np.r_[s.shoulder * (1, -1, 1), 1.0])[:3]
        pole = -0.5 * fwd - 0.8 * torso[:3, 1] - np.array([0.0, 0.0, 0.4])
        elbow, wr = solve_two_bone(shoulder, wrist, s.upper_arm, s.forearm, pole)
        pose.world["right_upper_arm"] = _bone_frame(shoulder, elbow, fwd)
        pose.world["right_forearm"] = _bone_frame(elbow, wr, fwd)
        pose.world["right_hand"] = rigid(hand_R, wr)
        return pose

    return motion, ball_center
