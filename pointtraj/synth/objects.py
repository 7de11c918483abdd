"""Rigid shapes (triangle meshes in a local frame) and scripted objects such as a bouncing ball.

Meshes are plain numpy (:class:`PartMesh`): vertices, triangles and smooth vertex normals in the
part's local frame. Closed shapes (ellipsoids, capsules) are watertight; background planes are
open quads.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..errors import ValidationError

__all__ = [
    "PartMesh",
    "make_ellipsoid",
    "make_capsule",
    "make_quad",
    "make_box",
    "BallPath",
    "GRAVITY",
]

#: Gravitational acceleration, m/s^2.
GRAVITY = 9.81


@dataclass(eq=False)
class PartMesh:
    """A triangle mesh in a part's local frame.

    Attributes
    ----------
    vertices : (V, 3) float64 ndarray
    triangles : (F, 3) int32 ndarray
        Counter-clockwise seen from outside (normals point out).
    normals : (V, 3) float64 ndarray
        Unit vertex normals for smooth shading.
    """

    vertices: np.ndarray
    triangles: np.ndarray
    normals: np.ndarray = field(default=None)  # type: ignore[assignment]

    def __post_init__(self) -> None:
        self.vertices = np.asarray(self.vertices, np.float64)
        self.triangles = np.asarray(self.triangles, np.int32)
        if self.normals is None:
            self.normals = _vertex_normals(self.vertices, self.triangles)
        self.normals = np.asarray(self.normals, np.float64)

    @property
    def triangle_areas(self) -> np.ndarray:
        """(F,) triangle areas in m^2."""
        tri = self.vertices[self.triangles]  # (F, 3, 3)
        return 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """``(lo, hi)`` (3,) corners of the local bounding box."""
        return self.vertices.min(axis=0), self.vertices.max(axis=0)

    def sample_surface(self, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """Points uniformly distributed (by area) on the surface.

        Parameters
        ----------
        n : int
            Number of points.
        rng : numpy.random.Generator

        Returns
        -------
        points : (n, 3) float64 ndarray
            Local coordinates, exactly on the triangles.
        triangle : (n,) int64 ndarray
            The triangle each point lies on.
        """
        area = self.triangle_areas
        tri = rng.choice(len(area), size=n, p=area / area.sum())
        r1, r2 = rng.random(n), rng.random(n)
        s = np.sqrt(r1)
        u, v = 1 - s, s * (1 - r2)  # uniform barycentrics
        corners = self.vertices[self.triangles[tri]]  # (n, 3, 3)
        pts = u[:, None] * corners[:, 0] + v[:, None] * corners[:, 1]
        pts += (1 - u - v)[:, None] * corners[:, 2]
        return pts, tri.astype(np.int64)

    def transformed(self, matrix: np.ndarray) -> np.ndarray:
        """(V, 3) vertices mapped by a (4, 4) local-to-world matrix."""
        return self.vertices @ matrix[:3, :3].T + matrix[:3, 3]


def _vertex_normals(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    tri = vertices[triangles]
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])  # area-weighted
    n = np.zeros_like(vertices)
    for k in range(3):
        np.add.at(n, triangles[:, k], fn)
    norm = np.linalg.norm(n, axis=1, keepdims=True)
    return n / np.where(norm > 0, norm, 1.0)


def _uv_sphere(rings: int, segments: int) -> tuple[np.ndarray, np.ndarray]:
    """Unit sphere: poles at +-z, ``rings`` latitude bands, ``segments`` longitudes."""
    theta = np.linspace(0, math.pi, rings + 1)[1:-1]  # interior latitudes
    phi = np.linspace(0, 2 * math.pi, segments, endpoint=False)
    st, ct = np.sin(theta)[:, None], np.cos(theta)[:, None]
    ring_pts = np.stack(
        [st * np.cos(phi), st * np.sin(phi), np.broadcast_to(ct, (len(theta), segments))], axis=-1
    ).reshape(-1, 3)
    verts = np.concatenate([[[0, 0, 1.0]], ring_pts, [[0, 0, -1.0]]])
    south = len(verts) - 1
    tris = []
    j = np.arange(segments)
    jn = (j + 1) % segments
    tris.append(np.stack([np.zeros(segments, int), 1 + j, 1 + jn], axis=1))
    for r in range(rings - 2):
        a, b = 1 + r * segments, 1 + (r + 1) * segments
        tris.append(np.stack([a + j, b + j, b + jn], axis=1))
        tris.append(np.stack([a + j, b + jn, a + jn], axis=1))
    last = 1 + (rings - 2) * segments
    tris.append(np.stack([np.full(segments, south), last + jn, last + j], axis=1))
    return verts, np.concatenate(tris).astype(np.int32)


def make_ellipsoid(
    center: tuple[float, float, float],
    radii: tuple[float, float, float],
    rings: int = 16,
    segments: int = 24,
) -> PartMesh:
    """A closed ellipsoid mesh.

    Parameters
    ----------
    center : (3,) tuple
        Local centre, metres.
    radii : (3,) tuple
        Semi-axes along local x, y, z, metres.
    rings, segments : int
        Tessellation.

    Returns
    -------
    PartMesh
    """
    if min(radii) <= 0:
        raise ValidationError(f"ellipsoid radii must be positive, got {radii}")
    unit, tris = _uv_sphere(rings, segments)
    r = np.asarray(radii, float)
    normals = unit / r
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return PartMesh(unit * r + np.asarray(center, float), tris, normals)


def make_capsule(
    length: float, radius: float, rings: int = 16, segments: int = 24, radius_end: float = None
) -> PartMesh:
    """A closed capsule hanging from the local origin along -z: a bone of ``length`` metres.

    The segment from ``(0, 0, 0)`` to ``(0, 0, -length)`` is swept by a sphere whose radius
    tapers linearly from ``radius`` to ``radius_end``.

    Parameters
    ----------
    length, radius : float
    rings, segments : int
        Tessellation (``rings`` must be even).
    radius_end : float, optional
        Radius at the distal end (default ``radius``).

    Returns
    -------
    PartMesh
    """
    if length <= 0 or radius <= 0:
        raise ValidationError(f"capsule length and radius must be positive, got {length}, {radius}")
    r1 = radius if radius_end is None else radius_end
    unit, tris = _uv_sphere(rings, segments)
    upper = unit[:, 2] >= 0
    r = np.where(upper, radius, r1)[:, None]
    verts = unit * r
    verts[:, 2] -= np.where(upper, 0.0, length)
    return PartMesh(verts, tris)


def make_quad(
    center: tuple[float, float, float],
    axis_u: tuple[float, float, float],
    axis_v: tuple[float, float, float],
    subdivisions: int = 8,
) -> PartMesh:
    """An open rectangle ``center + a * axis_u + b * axis_v`` for ``a, b`` in [-1, 1].

    Its normal is ``axis_u x axis_v``. Used for floors and walls (background).
    """
    n = subdivisions + 1
    a = np.linspace(-1, 1, n)
    aa, bb = np.meshgrid(a, a, indexing="ij")
    u, v = np.asarray(axis_u, float), np.asarray(axis_v, float)
    verts = np.asarray(center, float) + aa.reshape(-1, 1) * u + bb.reshape(-1, 1) * v
    idx = np.arange(n * n).reshape(n, n)
    q0, q1, q2, q3 = idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]
    tris = np.concatenate(
        [np.stack([q0, q1, q2], -1).reshape(-1, 3), np.stack([q0, q2, q3], -1).reshape(-1, 3)]
    )
    normal = np.cross(u, v)
    normal /= np.linalg.norm(normal)
    return PartMesh(verts, tris, np.broadcast_to(normal, verts.shape).copy())


def make_box(lo: tuple[float, float, float], hi: tuple[float, float, float]) -> PartMesh:
    """A closed axis-aligned box with flat faces (separate vertices per face)."""
    lo_, hi_ = np.asarray(lo, float), np.asarray(hi, float)
    c, h = (lo_ + hi_) / 2, (hi_ - lo_) / 2
    e = np.eye(3)
    faces = []
    for ax in range(3):
        for sgn in (1.0, -1.0):
            n = sgn * e[ax]
            u = e[(ax + 1) % 3] * h[(ax + 1) % 3]
            v = e[(ax + 2) % 3] * h[(ax + 2) % 3]
            if sgn < 0:
                u, v = v, u
            faces.append(make_quad(c + n * h[ax], u, v, subdivisions=2))
    verts, tris, normals, off = [], [], [], 0
    for f in faces:
        verts.append(f.vertices)
        tris.append(f.triangles + off)
        normals.append(f.normals)
        off += len(f.vertices)
    return PartMesh(np.concatenate(verts), np.concatenate(tris), np.concatenate(normals))


@dataclass(frozen=True)
class BallPath:
    """Vertical motion of a dribbled ball: hand contact, ballistic fall, floor bounce, rise.

    One period ``contact + flight`` starts with the hand taking the ball at height ``top``
    (ball centre) rising at speed ``v0``; the hand reverses it smoothly (cubic Hermite, continuous
    velocity) and releases it at ``top`` moving down at ``v0``; it then falls under gravity, bounces
    elastically off the floor (centre at ``radius``) and rises back to ``top``.

    Attributes
    ----------
    radius : float
        Ball radius, metres.
    top : float
        Height of the ball centre at catch and release, metres.
    v0 : float
        Speed at release and catch, m/s.
    contact : float
        Duration of the hand contact, seconds.
    phase : float
        Time offset of the first catch, seconds.
    """

    radius: float = 0.12
    top: float = 0.82
    v0: float = 2.2
    contact: float = 0.2
    phase: float = 0.0

    @property
    def fall_time(self) -> float:
        """Seconds from release to the floor."""
        drop = self.top - self.radius
        return (-self.v0 + math.sqrt(self.v0**2 + 2 * GRAVITY * drop)) / GRAVITY

    @property
    def period(self) -> float:
        """Seconds per dribble."""
        return self.contact + 2 * self.fall_time

    def split(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Cycle index, time within the cycle, and an in-contact mask for times ``t``."""
        t = np.asarray(t, float) - self.phase
        k = np.floor(t / self.period)
        local = t - k * self.period
        return k.astype(np.int64), local, local < self.contact

    def height(self, t: np.ndarray) -> np.ndarray:
        """Ball-centre height at times ``t`` (any shape), metres."""
        _, local, contact = self.split(t)
        s = np.clip(local / self.contact, 0, 1)
        z_contact = self.top + self.v0 * self.contact * s * (1 - s)
        tf = np.abs(local - self.contact - self.fall_time)  # symmetric about the bounce
        z_flight = self.radius + (self.v0 + GRAVITY * self.fall_time) * tf - 0.5 * GRAVITY * tf**2
        # (speed at the floor is v0 + g * fall_time; going back in time from the bounce)
        return np.where(contact, z_contact, z_flight)
