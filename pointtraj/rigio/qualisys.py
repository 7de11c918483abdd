"""Qualisys Track Manager calibration export (``.qca.txt``, XML), as Pose2Sim reads it.

Per ``<camera serial=...>``:

- ``<fov_video left top right bottom>``: the video window in sensor pixels (inclusive), so the
  image is ``(right - left + 1) x (bottom - top + 1)``;
- ``<transform x y z r11 .. r33>``: the camera position in millimetres and a rotation whose
  rows ``r1*, r2*, r3*`` map world to Qualisys camera axes;
- ``<intrinsic focalLengthU/V centerPointU/V radialDistortion1..3 tangentalDistortion1..2>``:
  focal lengths and principal point in 1/64-pixel units on the full sensor (the principal point
  is made relative to the video window), distortion coefficients also divided by 64 (Pose2Sim's
  reading, see ``data_specs/qualisys.md``).

Qualisys camera axes have y up and look along -z; OpenCV's have y down and look along +z, so
the world-to-camera rotation is ``diag(1, -1, -1) @ [r_ij]`` (Pose2Sim's rotation by pi about
the camera x axis). The camera centre is unchanged.
"""

from __future__ import annotations

import logging
import os
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from ..atomic import write_text_atomic
from ..camera import CameraRig
from ..errors import FileFormatError, ValidationError
from ._common import make_camera

__all__ = ["load_qualisys", "save_qualisys", "SUBPIXELS", "FLIP_YZ"]

logger = logging.getLogger(__name__)

#: Qualisys intrinsics are in 1/64 pixel units.
SUBPIXELS = 64.0
#: Qualisys camera axes (y up, looking along -z) to OpenCV's (y down, looking along +z).
FLIP_YZ = np.diag([1.0, -1.0, -1.0])
_MM_PER_M = 1000.0


def _attr(path: Path, elem: ET.Element, key: str, where: str, alt: str | None = None) -> float:
    raw = elem.get(key, elem.get(alt) if alt else None)
    if raw is None:
        raise FileFormatError(path, f"{where}: missing attribute {key!r}")
    try:
        value = float(raw)
    except ValueError:
        raise FileFormatError(path, f"{where}.{key}: expected a number, got {raw!r}") from None
    if not np.isfinite(value):
        raise FileFormatError(path, f"{where}.{key}: not finite ({raw!r})")
    return value


def _child(path: Path, cam: ET.Element, tag: str, where: str) -> ET.Element:
    elem = cam.find(tag)
    if elem is None:
        raise FileFormatError(path, f"{where}: missing <{tag}> element")
    return elem


def load_qualisys(
    path: str | os.PathLike,
    *,
    video_only: bool = False,
    distortion_units: float = SUBPIXELS,
) -> CameraRig:
    """Read a Qualisys ``.qca.txt`` calibration.

    Parameters
    ----------
    path : path-like
    video_only : bool
        Keep only cameras whose ``model`` attribute names a video camera (contains ``video`` or
        is ``none``, as Pose2Sim does).
    distortion_units : float
        Divide the distortion coefficients by this (64 as in Pose2Sim; 1 to take them as is).

    Returns
    -------
    CameraRig
        Cameras named by their ``serial``, in file order, skipping ``active="0"`` ones.

    Raises
    ------
    FileFormatError
        If the file is not XML, has no ``<cameras>/<camera>``, or a camera lacks an element or
        attribute, or has a non-rotation transform.
    """
    path = Path(path)
    if not path.is_file():
        raise FileFormatError(path, "no such file")
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as exc:
        raise FileFormatError(path, f"not valid XML ({exc})") from None
    elems = root.findall("cameras/camera")
    if not elems:
        raise FileFormatError(path, "no <cameras>/<camera> elements")
    cams = []
    for i, cam in enumerate(elems):
        serial = cam.get("serial")
        if not serial:
            raise FileFormatError(path, f"camera {i}: missing attribute 'serial'")
        where = f"camera {serial}"
        if cam.get("active", "1") == "0":
            logger.warning("%s: skipping inactive camera %s", path, serial)
            continue
        model = cam.get("model", "none").lower()
        if video_only and not ("video" in model or model == "none"):
            continue
        if cam.get("viewrotation", "0") not in ("0", ""):
            logger.warning(
                "%s: camera %s has viewrotation=%s, which is ignored (images must be in sensor "
                "orientation)",
                path,
                serial,
                cam.get("viewrotation"),
            )
        fov = _child(path, cam, "fov_video", where)
        left, top, right, bottom = (
            _attr(path, fov, k, f"{where} <fov_video>") for k in ("left", "top", "right", "bottom")
        )
        size = (int(right - left + 1), int(bottom - top + 1))
        tr = _child(path, cam, "transform", where)
        M = np.array(
            [[_attr(path, tr, f"r{r}{c}", f"{where} <transform>") for c in "123"] for r in "123"]
        )
        C = np.array([_attr(path, tr, k, f"{where} <transform>") for k in "xyz"]) / _MM_PER_M
        intr = _child(path, cam, "intrinsic", where)
        w_in = f"{where} <intrinsic>"
        fx = _attr(path, intr, "focalLengthU", w_in) / SUBPIXELS
        fy = _attr(path, intr, "focalLengthV", w_in) / SUBPIXELS
        cx = _attr(path, intr, "centerPointU", w_in) / SUBPIXELS - left
        cy = _attr(path, intr, "centerPointV", w_in) / SUBPIXELS - top
        skew = (_attr(path, intr, "skew", w_in) if intr.get("skew") else 0.0) / SUBPIXELS
        k1, k2, k3 = (
            _attr(path, intr, f"radialDistortion{j}", w_in) / distortion_units for j in (1, 2, 3)
        )
        p1, p2 = (
            _attr(path, intr, f"tangentalDistortion{j}", w_in, alt=f"tangentialDistortion{j}")
            / distortion_units
            for j in (1, 2)
        )
        K = np.array([[fx, skew, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
        R = FLIP_YZ @ M
        cams.append(
            make_camera(path, where, serial, K, R, -R @ C, size, np.array([k1, k2, p1, p2, k3]))
        )
    if not cams:
        raise FileFormatError(path, "no active (video) camera")
    try:
        return CameraRig(cams)
    except ValueError as exc:
        raise FileFormatError(path, str(exc)) from None


def save_qualisys(
    rig: CameraRig, path: str | os.PathLike, *, distortion_units: float = SUBPIXELS
) -> None:
    """Write ``rig`` as a Qualisys ``.qca.txt`` that :func:`load_qualisys` and Pose2Sim read.

    The video window is the full image (``left = top = 0``); only fields pointtraj knows are
    written (``avg-residual`` is ``nan``: unknown). ``k4..k6`` cannot be stored and must be 0.

    Parameters
    ----------
    rig : CameraRig
    path : path-like
    distortion_units : float
        Multiply distortion coefficients by this (see :func:`load_qualisys`).

    Raises
    ------
    ValidationError
        If a camera uses the rational distortion terms ``k4..k6``.
    """
    root = ET.Element("calibration", {"source": "pointtraj", "type": "regular"})
    cameras = ET.SubElement(root, "cameras")
    for cam in rig:
        if np.any(cam.dist[5:]):
            raise ValidationError(
                f"camera {cam.name!r}: Qualisys files cannot hold distortion k4..k6"
            )
        elem = ET.SubElement(
            cameras,
            "camera",
            {
                "active": "1",
                "avg-residual": "nan",
                "model": "video",
                "serial": cam.name,
                "viewrotation": "0",
            },
        )
        window = {
            "left": "0",
            "top": "0",
            "right": str(cam.width - 1),
            "bottom": str(cam.height - 1),
        }
        ET.SubElement(elem, "fov_video", window)
        M = FLIP_YZ @ cam.R
        attrs = {f"r{r + 1}{c + 1}": repr(float(M[r, c])) for r in range(3) for c in range(3)}
        attrs.update({k: repr(float(v)) for k, v in zip("xyz", cam.C * _MM_PER_M)})
        ET.SubElement(elem, "transform", attrs)
        k1, k2, p1, p2, k3 = (float(v) * distortion_units for v in cam.dist[:5])
        ET.SubElement(
            elem,
            "intrinsic",
            {
                "focalLengthU": repr(float(cam.K[0, 0]) * SUBPIXELS),
                "focalLengthV": repr(float(cam.K[1, 1]) * SUBPIXELS),
                "centerPointU": repr(float(cam.K[0, 2]) * SUBPIXELS),
                "centerPointV": repr(float(cam.K[1, 2]) * SUBPIXELS),
                "skew": repr(float(cam.K[0, 1]) * SUBPIXELS),
                "radialDistortion1": repr(k1),
                "radialDistortion2": repr(k2),
                "radialDistortion3": repr(k3),
                "tangentalDistortion1": repr(p1),
                "tangentalDistortion2": repr(p2),
            },
        )
    ET.indent(root)
    text = ET.tostring(root, encoding="unicode", xml_declaration=False)
    write_text_atomic(path, "<?xml version='1.0' encoding='UTF-8'?>\n" + text + "\n")
