"""Rig analysis: how many cameras see each voxel of the capture volume, and at what pixel density.

The paper (Section 6, Figure 4b) calls a rig a "3D pixel continuum" and quotes its pixel density:
6.4 pixels/cm³ on average and more than 60 at the centre of the stage. The paper does not define
the quantity, so we compute the candidates side by side; ``docs/rig_density.md`` gives the
definitions, the figures of the ``paper69`` preset and why they differ from the paper's
(:meth:`RigCoverage.report` prints ``global`` as the mean and ``projected_max`` at the centre):

``projected`` (``density``), px/cm²
    For each camera that sees the voxel centre, the image area in pixels covered by a 1 cm x
    1 cm patch facing it at that depth, ``fx * fy * (1 cm)^2 / d^2`` (``d`` the depth along
    the optical axis), summed over the cameras: the pixels imaging a face of a 1 cm cube. It
    is an area density, so its unit is px/cm², not px/cm³, and it grows as 1/d² towards each
    camera.
``projected_max`` (``density_max``), px/cm²
    The same for the best single camera.
``global``, px/cm³
    The pixels of all cameras whose rays enter the volume, divided by the volume in cm³: one
    number for the rig (total pixels per unit volume); at most the total pixel count over the
    volume.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from .camera import CameraRig
from .errors import ValidationError

__all__ = [
    "CaptureVolume",
    "RigCoverage",
    "analyze_rig",
    "plot_coverage",
    "format_length",
    "format_volume",
]

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class CaptureVolume:
    """A vertical cylinder (the paper's stage), or a box when ``radius`` is None.

    Parameters
    ----------
    center : (3,) tuple of float
        Centre of the floor disc (x, y, z), metres.
    radius : float or None
        Cylinder radius; None for the axis-aligned box ``center ± half_extent``.
    height : float
        Height above ``center[2]``.
    half_extent : (2,) tuple of float
        Box half sizes in x and y when ``radius`` is None.
    """

    center: tuple[float, float, float] = (0.0, 0.0, 0.0)
    radius: float | None = 1.5
    height: float = 2.5
    half_extent: tuple[float, float] = (1.5, 1.5)

    def grid(self, voxel: float) -> tuple[np.ndarray, np.ndarray, tuple[np.ndarray, ...]]:
        """Voxel centres inside the volume.

        Returns
        -------
        centers : (V, 3) float ndarray
            Centres of the voxels inside the volume.
        index : (V, 3) int ndarray
            Their (ix, iy, iz) indices in the bounding grid.
        axes : tuple of three 1-D float ndarrays
            Grid coordinates along x, y and z.
        """
        if voxel <= 0:
            raise ValidationError(f"voxel size must be positive, got {voxel}")
        cx, cy, cz = self.center
        hx, hy = (self.radius, self.radius) if self.radius is not None else self.half_extent
        xs = np.arange(cx - hx + voxel / 2, cx + hx, voxel)
        ys = np.arange(cy - hy + voxel / 2, cy + hy, voxel)
        zs = np.arange(cz + voxel / 2, cz + self.height, voxel)
        ix, iy, iz = np.meshgrid(
            np.arange(len(xs)), np.arange(len(ys)), np.arange(len(zs)), indexing="ij"
        )
        idx = np.stack([ix.ravel(), iy.ravel(), iz.ravel()], axis=1)
        pts = np.stack([xs[idx[:, 0]], ys[idx[:, 1]], zs[idx[:, 2]]], axis=1)
        if self.radius is not None:
            inside = (pts[:, 0] - cx) ** 2 + (pts[:, 1] - cy) ** 2 <= self.radius**2
            pts, idx = pts[inside], idx[inside]
        return pts, idx, (xs, ys, zs)

    @property
    def volume_m3(self) -> float:
        """Volume in cubic metres."""
        if self.radius is not None:
            return float(np.pi * self.radius**2 * self.height)
        return float(4 * self.half_extent[0] * self.half_extent[1] * self.height)


@dataclass(frozen=True)
class RigCoverage:
    """Per-voxel coverage of a capture volume.

    Attributes
    ----------
    volume : CaptureVolume
    voxel : float
        Voxel size, metres.
    axes : tuple of (X,), (Y,), (Z,) float ndarrays
        Grid coordinates.
    count : (X, Y, Z) int16 ndarray
        Cameras seeing each voxel centre; -1 outside the volume.
    density : (X, Y, Z) float32 ndarray
        ``projected`` density (px/cm²: pixels on a 1 cm x 1 cm patch facing the camera,
        summed over cameras); NaN outside.
    density_max : (X, Y, Z) float32 ndarray
        Best single camera's projected density (px/cm²); NaN outside.
    global_density : float
        Pixels of all cameras whose rays enter the volume per cm³ of volume.
    """

    volume: CaptureVolume
    voxel: float
    axes: tuple[np.ndarray, np.ndarray, np.ndarray]
    count: np.ndarray
    density: np.ndarray
    density_max: np.ndarray
    global_density: float

    def summary(self) -> dict[str, float]:
        """Headline figures: mean and centre densities and the fraction seen by >= 2, 5, 10 cameras."""
        inside = self.count >= 0
        c = self.count[inside]
        xs, ys, zs = self.axes
        cx, cy, cz = self.volume.center
        centre = (
            int(np.argmin(np.abs(xs - cx))),
            int(np.argmin(np.abs(ys - cy))),
            int(np.argmin(np.abs(zs - (cz + self.volume.height / 2)))),
        )
        return {
            "voxel_m": self.voxel,
            "volume_m3": self.volume.volume_m3,
            "projected_sum_mean_px_per_cm2": float(np.nanmean(self.density[inside])),
            "projected_sum_centre_px_per_cm2": float(self.density[centre]),
            "projected_best_mean_px_per_cm2": float(np.nanmean(self.density_max[inside])),
            "projected_best_centre_px_per_cm2": float(self.density_max[centre]),
            "global_px_per_cm3": self.global_density,
            "cameras_mean": float(c.mean()),
            "cameras_centre": int(self.count[centre]),
            "fraction_seen_by_2": float(np.mean(c >= 2)),
            "fraction_seen_by_5": float(np.mean(c >= 5)),
            "fraction_seen_by_10": float(np.mean(c >= 10)),
        }

    def report(self) -> str:
        """Several lines: the paper's two density figures by the nearest definitions
        (``docs/rig_density.md``), then the other candidates and camera counts.

        Lengths, volumes and densities are in units that suit the rig's scale (a room in m³
        and cm, a small-scale rig in cm³ or mm³ and mm; :func:`format_length`,
        :func:`format_volume`); densities are per mm when the voxel is under 1 cm.
        """
        s = self.summary()
        mm = self.voxel < 0.01  # densities per mm (a small-scale rig), else per cm
        unit, k2, k3 = ("mm", 1e-2, 1e-3) if mm else ("cm", 1.0, 1.0)
        paper_centre = (
            "(paper: > 60 pixels seeing a 1 cm cube = 0.6 px/mm^2)"
            if mm
            else "(paper: > 60 pixels seeing a 1 cm cube, which it writes px/cm^3)"
        )
        return "\n".join(
            [
                f"capture volume {format_volume(s['volume_m3'])}, voxel "
                f"{format_length(self.voxel)}",
                f"mean pixel density   {_g(k3 * s['global_px_per_cm3'])} px/{unit}^3  "
                f"(paper: {_g(k3 * 6.4)} px/{unit}^3) = pixels of all cameras whose rays enter "
                "the volume / volume",
                f"centre pixel density {_g(k2 * s['projected_best_centre_px_per_cm2'])} "
                f"px/{unit}^2  {paper_centre} = pixels of the best camera on a 1 {unit} x 1 "
                f"{unit} patch at the centre, fx fy (1 {unit})^2 / d^2",
                f"  other definitions (px/{unit}^2): summed over cameras "
                f"{k2 * s['projected_sum_centre_px_per_cm2']:.4g} at the centre, "
                f"{k2 * s['projected_sum_mean_px_per_cm2']:.4g} mean; best camera "
                f"{k2 * s['projected_best_mean_px_per_cm2']:.4g} mean",
                f"cameras seeing a voxel: {s['cameras_mean']:.1f} mean, {s['cameras_centre']} at "
                f"the centre; seen by >= 2 / 5 / 10: {100 * s['fraction_seen_by_2']:.1f} / "
                f"{100 * s['fraction_seen_by_5']:.1f} / {100 * s['fraction_seen_by_10']:.1f} %",
            ]
        )


def _g(x: float) -> str:
    """A density in a fixed-width field: 2 decimals, or 4 significant digits when tiny."""
    return f"{x:8.2f}" if x == 0 or abs(x) >= 0.01 else f"{x:8.4g}"


def _sig(x: float) -> str:
    """3 significant digits, without an exponent from 100 up."""
    return f"{x:.0f}" if abs(x) >= 100 else f"{x:.3g}"


def format_length(metres: float) -> str:
    """A length in the unit that suits it: m from 1 m, cm from 1 cm, else mm (3 significant
    digits).

    Examples
    --------
    >>> format_length(2.5), format_length(0.05), format_length(0.0004)
    ('2.5 m', '5 cm', '0.4 mm')
    """
    for unit, k in (("m", 1.0), ("cm", 1e-2)):
        if abs(metres) >= k:
            return f"{_sig(metres / k)} {unit}"
    return f"{_sig(metres * 1e3)} mm"


def format_volume(cubic_metres: float) -> str:
    """A volume in the unit that suits it: m^3 from 0.1 m^3 (a 46 cm cube), cm^3 from
    0.1 cm^3, else mm^3 (3 significant digits).

    Examples
    --------
    >>> format_volume(17.67), format_volume(0.001), format_volume(2e-9)
    ('17.7 m^3', '1000 cm^3', '2 mm^3')
    """
    for unit, k in (("m^3", 0.1), ("cm^3", 1e-7)):
        if abs(cubic_metres) >= k:
            scale = 1.0 if unit == "m^3" else 1e-6
            return f"{_sig(cubic_metres / scale)} {unit}"
    return f"{_sig(cubic_metres * 1e9)} mm^3"


def analyze_rig(
    rig: CameraRig, volume: CaptureVolume | None = None, voxel: float = 0.05, chunk: int = 200_000
) -> RigCoverage:
    """Count the cameras seeing each voxel and the pixel density there.

    Parameters
    ----------
    rig : CameraRig
    volume : CaptureVolume, optional
        Default: the paper's 3 m diameter x 2.5 m cylinder centred at the origin.
    voxel : float
        Voxel size in metres.
    chunk : int
        Voxels projected at once (bounds memory at about ``C * chunk * 40`` bytes).

    Returns
    -------
    RigCoverage
    """
    volume = volume or CaptureVolume()
    pts, idx, axes = volume.grid(voxel)
    shape = tuple(len(a) for a in axes)
    count = np.full(shape, -1, np.int16)
    density = np.full(shape, np.nan, np.float32)
    dmax = np.full(shape, np.nan, np.float32)
    fxfy = (rig.K[:, 0, 0] * rig.K[:, 1, 1])[:, None]  # (C, 1)
    for s in range(0, len(pts), chunk):
        p = pts[s : s + chunk]
        proj = rig.project(p)
        with np.errstate(divide="ignore"):
            area = np.where(proj.in_image, fxfy * 1e-4 / proj.depth**2, 0.0)  # (C, n) px per cm²
        i = idx[s : s + chunk]
        count[i[:, 0], i[:, 1], i[:, 2]] = proj.in_image.sum(axis=0)
        density[i[:, 0], i[:, 1], i[:, 2]] = area.sum(axis=0)
        dmax[i[:, 0], i[:, 1], i[:, 2]] = area.max(axis=0)
    global_density = _global_density(rig, volume)
    return RigCoverage(volume, voxel, axes, count, density, dmax, global_density)


def _global_density(rig: CameraRig, volume: CaptureVolume, step: int = 8) -> float:
    """Pixels (on a ``step`` grid, scaled) whose rays enter the volume, per cm³ of volume."""
    total = 0.0
    cx, cy, cz = volume.center
    hx, hy = (volume.radius, volume.radius) if volume.radius is not None else volume.half_extent
    sphere_c = np.array([cx, cy, cz + volume.height / 2])
    sphere_r = float(np.sqrt(hx**2 + hy**2 + (volume.height / 2) ** 2))
    for i, cam in enumerate(rig):
        w, h = cam.size
        u, v = np.meshgrid(
            np.arange(0, w, step) + step / 2 - 0.5, np.arange(0, h, step) + step / 2 - 0.5
        )
        pix = np.stack([u.ravel(), v.ravel()], axis=1)
        o, d = rig.subset([i]).rays(pix[None])
        o, d = o[0], d[0] / np.linalg.norm(d[0], axis=1, keepdims=True)
        # Sample each ray where it crosses the volume's bounding sphere (160 steps across it,
        # whatever the volume's size) and test membership of the volume.
        t0, t1 = _sphere_span(o, d, sphere_c, sphere_r)  # (n,), (n,)
        ts = t0[:, None] + (t1 - t0)[:, None] * np.linspace(0.0, 1.0, 161)[None]  # (n, S)
        p = o[:, None, :] + ts[:, :, None] * d[:, None, :]  # (n, S, 3)
        if volume.radius is not None:
            inside = ((p[..., 0] - cx) ** 2 + (p[..., 1] - cy) ** 2 <= volume.radius**2) & (
                (p[..., 2] >= cz) & (p[..., 2] <= cz + volume.height)
            )
        else:
            hx, hy = volume.half_extent
            inside = (
                (np.abs(p[..., 0] - cx) <= hx)
                & (np.abs(p[..., 1] - cy) <= hy)
                & (p[..., 2] >= cz)
                & (p[..., 2] <= cz + volume.height)
            )
        inside &= (t1 > t0)[:, None]  # rays that miss the sphere
        total += inside.any(axis=1).sum() * (w * h) / len(pix)
    return float(total / (volume.volume_m3 * 1e6))


def _sphere_span(
    o: np.ndarray, d: np.ndarray, c: np.ndarray, r: float
) -> tuple[np.ndarray, np.ndarray]:
    """Where rays ``o + t d`` (unit ``d``, ``t >= 0``) are inside a sphere: ``[t0, t1]`` per
    ray, (n,) each; ``t1 <= t0`` for a ray that misses it."""
    oc = o - c  # (n, 3)
    b = np.einsum("ij,ij->i", oc, d)  # (n,)
    disc = b**2 - (np.einsum("ij,ij->i", oc, oc) - r**2)
    root = np.sqrt(np.maximum(disc, 0.0))
    t0 = np.maximum(-b - root, 0.0)
    t1 = np.where(disc > 0, -b + root, 0.0)
    return t0, np.maximum(t1, 0.0)


def plot_coverage(
    coverage: RigCoverage, path, rig: CameraRig | None = None, density: str = "best"
) -> None:
    """Top-view maximum-intensity projections of camera count and density (the paper's Fig. 4b).

    Parameters
    ----------
    coverage : RigCoverage
    path : path-like
        PNG to write (atomically).
    rig : CameraRig, optional
        Draw the camera centres too.
    density : {"best", "sum"}
        Right panel: the best single camera's pixels on a 1 cm x 1 cm patch (px/cm², the
        counterpart of the paper's centre figure, ``density_max``) or the sum over cameras
        (``density``).
    """
    if density not in ("best", "sum"):
        raise ValidationError(f"density: expected 'best' or 'sum', got {density!r}")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .atomic import atomic_path

    xs, ys, _ = coverage.axes
    extent = (xs[0], xs[-1], ys[0], ys[-1])
    fig, axs = plt.subplots(1, 2, figsize=(11, 4.8))
    inside = coverage.count >= 0

    def top_max(a: np.ndarray) -> np.ndarray:
        m = np.where(inside, a, -np.inf).max(axis=2)
        return np.where(np.isfinite(m), m, np.nan)

    for ax, data, title, label in (
        (
            axs[0],
            top_max(coverage.count.astype(float)),
            "cameras seeing each voxel (max over height)",
            "cameras",
        ),
        (
            axs[1],
            top_max(coverage.density_max if density == "best" else coverage.density),
            "best camera, px on 1 cm² (max over height)"
            if density == "best"
            else "all cameras, px on 1 cm² (max over height)",
            "pixels per cm²",
        ),
    ):
        norm = None
        if label != "cameras" and np.nanmax(data) > 0:  # densities span decades: log scale
            lo = np.nanmin(np.where(data > 0, data, np.nan))
            norm = matplotlib.colors.LogNorm(vmin=lo, vmax=np.nanmax(data))
        im = ax.imshow(data.T, origin="lower", extent=extent, cmap="viridis", norm=norm)
        fig.colorbar(im, ax=ax, label=label)
        ax.set_title(title)
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        if rig is not None:
            ax.plot(rig.C[:, 0], rig.C[:, 1], "r^", ms=4)
            ax.set_xlim(
                min(extent[0], rig.C[:, 0].min()) - 0.2, max(extent[1], rig.C[:, 0].max()) + 0.2
            )
            ax.set_ylim(
                min(extent[2], rig.C[:, 1].min()) - 0.2, max(extent[3], rig.C[:, 1].max()) + 0.2
            )
        ax.set_aspect("equal")
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)
