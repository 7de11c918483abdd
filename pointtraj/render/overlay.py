"""The OpenCV engine: points and tails projected with the full camera model (distortion
included) and drawn over an image or a blank canvas, and the annotations (legend, caption)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from ..camera import Camera, CameraRig
from ..trajectories import Trajectories
from .scene import tail_segments

if TYPE_CHECKING:
    from ..segments import Segments

__all__ = [
    "LEGEND_CORNERS",
    "draw_scene",
    "draw_overlay",
    "draw_segments",
    "draw_legend",
    "legend_origin",
    "legend_image",
    "draw_caption",
]

#: Text colour of legends and captions.
_TEXT_COLOR = (30, 30, 30)


def draw_scene(
    image: np.ndarray,
    camera: Camera,
    points: np.ndarray,
    point_colors: np.ndarray,
    segments: np.ndarray | None = None,
    segment_colors: np.ndarray | None = None,
    *,
    radius: int = 2,
    line_width: int = 1,
) -> np.ndarray:
    """Draw points and line segments seen from ``camera`` over an image (OpenCV engine).

    Projection uses the full camera model, distortion included. Segments are drawn first,
    anti-aliased; a segment with an end outside the image or behind the camera is dropped.
    Points are discs, the nearest drawn last.

    Parameters
    ----------
    image : (H, W, 3) uint8 ndarray
        RGB image of ``camera`` (or a blank canvas of its size); not modified.
    camera : Camera
    points : (N, 3) float ndarray
    point_colors : (N, 3) uint8 ndarray
    segments : (S, 2, 3) float ndarray, optional
    segment_colors : (S, 3) uint8 ndarray, optional
    radius : int
        Point radius in pixels (0 draws single pixels).
    line_width : int
        Segment thickness in pixels.

    Returns
    -------
    (H, W, 3) uint8 ndarray
        A new image.
    """
    import cv2

    out = np.ascontiguousarray(image, dtype=np.uint8).copy()
    h, w = out.shape[:2]
    rig = CameraRig([camera])
    if segments is not None and len(segments):
        proj = rig.project(np.asarray(segments, float).reshape(-1, 3))
        pix = proj.pixels[0].reshape(-1, 2, 2)
        ok = proj.in_image[0].reshape(-1, 2).all(axis=1)
        seg_col = np.asarray(segment_colors, np.uint8)[ok]
        pts = np.rint(pix[ok] * 16).astype(np.int32)  # 4 bits of sub-pixel precision
        # One polylines call per colour: few calls, many segments each. Colours are drawn in
        # the order of their first segment, so earlier segments (a floor, old tails) go under.
        uniq, inv = np.unique(seg_col, axis=0, return_inverse=True)
        inv = inv.reshape(-1)
        first = np.full(len(uniq), len(inv))
        np.minimum.at(first, inv, np.arange(len(inv)))
        order = np.argsort(inv, kind="stable")
        bounds = np.searchsorted(inv[order], np.arange(len(uniq) + 1))
        for k in np.argsort(first):
            col = uniq[k]
            sel = order[bounds[k] : bounds[k + 1]]
            color = tuple(int(c) for c in col)
            cv2.polylines(out, list(pts[sel]), False, color, int(line_width), cv2.LINE_AA, 4)
    if len(points):
        proj = rig.project(np.asarray(points, float))
        ok = proj.in_image[0]
        far_first = np.argsort(-proj.depth[0][ok], kind="stable")
        pix = np.rint(proj.pixels[0][ok][far_first]).astype(np.int64)  # (N', 2)
        col = np.asarray(point_colors, np.uint8)[ok][far_first]
        r = max(int(radius), 0)
        dy, dx = np.mgrid[-r : r + 1, -r : r + 1]
        disc = (dx**2 + dy**2) <= r**2
        off = np.stack([dx[disc], dy[disc]], axis=1)  # (D, 2)
        # Point-major order, so a nearer point's disc overwrites a farther one's.
        q = (pix[:, None, :] + off[None]).reshape(-1, 2)  # (N' D, 2)
        c = np.repeat(col, len(off), axis=0)
        inside = (q[:, 0] >= 0) & (q[:, 0] < w) & (q[:, 1] >= 0) & (q[:, 1] < h)
        out[q[inside, 1], q[inside, 0]] = c[inside]
    return out


def draw_overlay(
    image: np.ndarray,
    camera: Camera,
    trajectories: Trajectories,
    t: int,
    colors: np.ndarray,
    tail: int = 10,
    radius: int = 2,
    visible_only: bool = True,
) -> np.ndarray:
    """Draw frame ``t``'s labelled points and tails over a camera image (OpenCV engine).

    Parameters
    ----------
    image : (H, W, 3) uint8 ndarray
        RGB image of ``camera`` (or a blank canvas of its size).
    camera : Camera
    trajectories : Trajectories
    t : int
    colors : (M, 3) uint8 ndarray
        Colour per trajectory.
    tail : int
        Past frames drawn as polylines.
    radius : int
        Point radius in pixels.
    visible_only : bool
        Draw only points (and their tails) whose stored visibility in this camera is above 0.5,
        when the store has this camera; otherwise every point in front of it.

    Returns
    -------
    (H, W, 3) uint8 ndarray
        A new image.
    """
    fs = trajectories.frame(t)
    keep = np.ones(len(fs.track_id), bool)
    if visible_only and camera.name in trajectories.camera_names:
        keep = fs.visibility[:, trajectories.camera_names.index(camera.name)] > 0.5
    seg, seg_track, _ = tail_segments(trajectories, t, tail)
    seg_keep = np.isin(seg_track, fs.track_id[keep])
    return draw_scene(
        image,
        camera,
        fs.xyz[keep],
        colors[fs.track_id[keep]],
        seg[seg_keep],
        colors[seg_track[seg_keep]],
        radius=radius,
    )


# -- annotations ---------------------------------------------------------------------------------
def _text_metrics(scale: float) -> tuple[int, int, int, int]:
    """Font thickness, text height, line pitch and box padding (pixels) at ``scale``."""
    import cv2

    thick = max(1, int(round(scale * 1.6)))
    (_, th), _ = cv2.getTextSize("Hg", cv2.FONT_HERSHEY_SIMPLEX, scale, thick)
    return thick, th, int(round(th * 1.9)), max(4, th // 2)


def _default_scale(height: int, width: int) -> float:
    """Font scale from the image's shorter side: 0.6 at 1024, at least 0.4 (a portrait video
    gets the text size of the same video in landscape, not one that fills its width)."""
    return max(0.4, min(height, width) / 1700)


def _lighten(image: np.ndarray, x0: int, y0: int, x1: int, y1: int) -> None:
    """Move the box ``[x0, x1) x [y0, y1)`` of ``image`` 80 % of the way to white, in place."""
    box = image[y0:y1, x0:x1].astype(np.float32)
    image[y0:y1, x0:x1] = np.rint(box * 0.2 + 255 * 0.8).astype(np.uint8)


def _legend_box(names: Sequence[str], scale: float) -> tuple[int, int]:
    import cv2

    thick, th, pitch, pad = _text_metrics(scale)
    widths = [cv2.getTextSize(n, cv2.FONT_HERSHEY_SIMPLEX, scale, thick)[0][0] for n in names]
    return 3 * pad + th + max(widths, default=0), 2 * pad + pitch * len(names) - (pitch - th)


#: Corners a legend may take, in order of preference on a tie; the caption is bottom-left.
LEGEND_CORNERS = ("top-left", "top-right", "bottom-right", "bottom-left")
#: Distance of the legend (and caption) box from the image border, pixels.
_MARGIN = 10


def _fit_legend(
    names: list[str], colors: np.ndarray, h: int, y0: int, scale: float
) -> tuple[list[str], np.ndarray]:
    """The entries that fit in ``h - y0`` rows; the last becomes ``+N more`` if some do not."""
    _, th, pitch, pad = _text_metrics(scale)
    fit = max(1, (h - y0 - 2 * pad + (pitch - th)) // pitch)
    if len(names) > fit:
        more = len(names) - fit + 1
        names, colors = names[: fit - 1] + [f"+{more} more"], colors[: fit - 1]
    return names, colors


def legend_origin(
    size: tuple[int, int],
    names: Sequence[str],
    corner: str = "auto",
    avoid: np.ndarray | None = None,
    *,
    radius: float = 0.0,
    scale: float | None = None,
) -> tuple[int, int]:
    """Top-left corner (x, y) of the legend box, in a corner of the image.

    Parameters
    ----------
    size : (int, int)
        Image (width, height).
    names : sequence of str
        The legend's entries (they set the box's size).
    corner : str
        One of :data:`LEGEND_CORNERS`, or ``"auto"``: the corner whose box covers the fewest
        of the ``avoid`` points (the subject), among top-left, top-right and bottom-right
        (bottom-left holds the caption); top-left on a tie.
    avoid : (N, 2) float ndarray, optional
        Pixels the legend should not cover (projected points; NaN rows are ignored).
    radius : float
        Radius of the points as drawn, pixels: a point this near the box counts as covered.
    scale : float, optional
        Font scale (default from the image's shorter side, as :func:`draw_legend`).

    Returns
    -------
    (int, int)

    Raises
    ------
    ValidationError
        For an unknown corner (the message lists them).
    """
    from ..errors import ValidationError

    if corner != "auto" and corner not in LEGEND_CORNERS:
        raise ValidationError(
            f"legend corner must be 'auto' or one of {', '.join(LEGEND_CORNERS)}, got {corner!r}"
        )
    w, h = int(size[0]), int(size[1])
    scale = _default_scale(h, w) if scale is None else scale
    names, _ = _fit_legend(list(names) or [""], np.zeros((0, 3), np.uint8), h, _MARGIN, scale)
    bw, bh = _legend_box(names, scale)
    origins = {
        "top-left": (_MARGIN, _MARGIN),
        "top-right": (max(0, w - _MARGIN - bw), _MARGIN),
        "bottom-right": (max(0, w - _MARGIN - bw), max(0, h - _MARGIN - bh)),
        "bottom-left": (_MARGIN, max(0, h - _MARGIN - bh)),
    }
    if corner != "auto":
        return origins[corner]
    if avoid is None or len(avoid) == 0:
        return origins["top-left"]
    p = np.asarray(avoid, float).reshape(-1, 2)
    p = p[np.isfinite(p).all(axis=1)]
    best, fewest = origins["top-left"], None
    for name in LEGEND_CORNERS[:3]:
        x0, y0 = origins[name]
        r = radius + 1  # and the anti-aliased pixel around it
        inside = (
            (p[:, 0] >= x0 - r)
            & (p[:, 0] < x0 + bw + r)
            & (p[:, 1] >= y0 - r)
            & (p[:, 1] < y0 + bh + r)
        )
        n = int(inside.sum())
        if fewest is None or n < fewest:
            best, fewest = origins[name], n
    return best


def draw_legend(
    image: np.ndarray,
    names: Sequence[str],
    colors: np.ndarray,
    *,
    origin: tuple[int, int] = (_MARGIN, _MARGIN),
    scale: float | None = None,
) -> np.ndarray:
    """Draw a legend (a colour swatch and a name per class) in a light box.

    Entries that do not fit in the image height are replaced by a last line ``+N more``.

    Parameters
    ----------
    image : (H, W, 3) uint8 ndarray
        Not modified.
    names : sequence of n str
    colors : (n, 3) uint8 ndarray
        RGB colour per name.
    origin : (int, int)
        Top-left corner (x, y) of the box (:func:`legend_origin` chooses a corner that keeps
        the subject visible).
    scale : float, optional
        OpenCV font scale (default from the image's shorter side: 0.6 at 1024 pixels, at least
        0.4).

    Returns
    -------
    (H, W, 3) uint8 ndarray
    """
    import cv2

    out = np.ascontiguousarray(image, dtype=np.uint8).copy()
    names = list(names)
    colors = np.asarray(colors, np.uint8).reshape(-1, 3)
    if not names:
        return out
    h, w = out.shape[:2]
    scale = _default_scale(h, w) if scale is None else scale
    thick, th, pitch, pad = _text_metrics(scale)
    x0, y0 = origin
    names, colors = _fit_legend(names, colors, h, min(y0, _MARGIN), scale)
    bw, bh = _legend_box(names, scale)
    _lighten(out, x0, y0, min(w, x0 + bw), min(h, y0 + bh))
    for i, name in enumerate(names):
        top = y0 + pad + i * pitch
        if i < len(colors):
            col = tuple(int(c) for c in colors[i])
            cv2.rectangle(out, (x0 + pad, top), (x0 + pad + th, top + th), col, -1)
            cv2.rectangle(out, (x0 + pad, top), (x0 + pad + th, top + th), _TEXT_COLOR, 1)
        org = (x0 + 2 * pad + th, top + th)
        cv2.putText(
            out, name, org, cv2.FONT_HERSHEY_SIMPLEX, scale, _TEXT_COLOR, thick, cv2.LINE_AA
        )
    return out


def legend_image(names: Sequence[str], colors: np.ndarray, scale: float = 0.7) -> np.ndarray:
    """A legend on its own, as an image just large enough for it.

    Parameters
    ----------
    names : sequence of n str
    colors : (n, 3) uint8 ndarray
    scale : float
        OpenCV font scale.

    Returns
    -------
    (H, W, 3) uint8 ndarray
    """
    bw, bh = _legend_box(list(names) or [""], scale)
    canvas = np.full((bh + 2, bw + 2, 3), 255, np.uint8)
    return draw_legend(canvas, names, colors, origin=(1, 1), scale=scale)


def draw_caption(image: np.ndarray, text: str, *, scale: float | None = None) -> np.ndarray:
    """Write one line of text in a light box at the bottom-left corner.

    Parameters
    ----------
    image : (H, W, 3) uint8 ndarray
        Not modified.
    text : str
    scale : float, optional
        OpenCV font scale (default from the image's shorter side).

    Returns
    -------
    (H, W, 3) uint8 ndarray
    """
    import cv2

    out = np.ascontiguousarray(image, dtype=np.uint8).copy()
    h, w = out.shape[:2]
    scale = _default_scale(h, w) if scale is None else scale
    thick, th, _, pad = _text_metrics(scale)
    tw = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, thick)[0][0]
    x0, y1 = 10, h - 10
    _lighten(out, x0, max(0, y1 - th - 2 * pad), min(w, x0 + tw + 2 * pad), y1)
    org = (x0 + pad, y1 - pad)
    cv2.putText(out, text, org, cv2.FONT_HERSHEY_SIMPLEX, scale, _TEXT_COLOR, thick, cv2.LINE_AA)
    return out


#: Colours of a segment frame's x, y and z axes (RGB) and of joint centres.
AXIS_COLORS = np.array([[230, 30, 30], [30, 200, 30], [40, 80, 255]], np.uint8)
JOINT_COLOR = np.array([255, 230, 0], np.uint8)


def draw_segments(
    image: np.ndarray,
    camera: Camera,
    segments: Segments,
    frame: int,
    *,
    axis_length: float = 0.08,
    radius: int = 4,
    line_width: int = 2,
) -> np.ndarray:
    """Draw every segment's frame and the joint centres at ``frame`` over an image.

    A segment's frame is drawn at its centroid, its axes the world axes of its reference
    frame carried by the pose (x red, y green, z blue); joint centres are yellow discs. Parts
    without a pose and joints without a centre at ``frame`` are not drawn.

    Parameters
    ----------
    image : (H, W, 3) uint8 ndarray
        Not modified.
    camera : Camera
    segments : Segments
        :class:`pointtraj.segments.Segments`.
    frame : int
    axis_length : float
        Length of the drawn axes, metres.
    radius, line_width : int
        Joint disc radius and axis thickness, pixels.

    Returns
    -------
    (H, W, 3) uint8 ndarray
    """
    c = segments.centroids()[:, frame]  # (S, 3)
    R = segments.rotation[:, frame]  # (S, 3, 3)
    ok = np.isfinite(c).all(axis=1)
    tips = c[ok, None, :] + axis_length * np.swapaxes(R[ok], 1, 2)  # (S', 3 axes, 3)
    lines = np.stack([np.repeat(c[ok], 3, axis=0), tips.reshape(-1, 3)], axis=1)  # (3S', 2, 3)
    colors = np.tile(AXIS_COLORS, (int(ok.sum()), 1))
    joints = segments.joint_positions()[:, frame]  # (J, 3)
    joints = joints[np.isfinite(joints).all(axis=1)]
    return draw_scene(
        image,
        camera,
        joints,
        np.tile(JOINT_COLOR, (len(joints), 1)),
        lines,
        colors,
        radius=radius,
        line_width=line_width,
    )
