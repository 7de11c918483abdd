"""CMU Panoptic Studio calibration JSON (``calibration_<sequence>.json``).

``{"cameras": [{"name", "type", "resolution": [w, h], "K": 3x3, "distCoef": [k1 k2 p1 p2 k3],
"R": 3x3, "t": 3x1}, ...]}`` with ``x_cam = R X + t`` and ``t`` in **centimetres** (converted
to metres here). Spec: ``data_specs/panoptic.md``.
"""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Sequence
from pathlib import Path

from ..atomic import write_text_atomic
from ..camera import CameraRig
from ..errors import FileFormatError
from ._common import field_array, field_value, make_camera, trim_dist

__all__ = ["load_panoptic", "save_panoptic", "CM_PER_M"]

logger = logging.getLogger(__name__)

#: Panoptic translations are in centimetres.
CM_PER_M = 100.0


def load_panoptic(path: str | os.PathLike, camera_types: Sequence[str] | None = None) -> CameraRig:
    """Read a Panoptic Studio calibration JSON.

    Parameters
    ----------
    path : path-like
    camera_types : sequence of str, optional
        Keep only cameras of these ``type`` values (``"vga"``, ``"hd"``, ``"kinect-color"``);
        default all.

    Returns
    -------
    CameraRig
        Cameras in file order, with translations in metres.

    Raises
    ------
    FileFormatError
        If the file is not JSON, lacks ``cameras`` or a camera field, or a field is malformed.
    """
    path = Path(path)
    if not path.is_file():
        raise FileFormatError(path, "no such file")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise FileFormatError(path, f"not valid JSON ({exc})") from None
    if not isinstance(data, dict) or not isinstance(data.get("cameras"), list):
        raise FileFormatError(path, "cameras: missing or not a list")
    cams = []
    for i, entry in enumerate(data["cameras"]):
        where = f"cameras[{i}]"
        if not isinstance(entry, dict):
            raise FileFormatError(path, f"{where}: expected an object, got {entry!r}")
        name = str(field_value(path, entry, "name", where))
        where = f"cameras[{i}] ({name})"
        if camera_types is not None and entry.get("type") not in camera_types:
            continue
        size = field_array(path, entry, "resolution", where, ((2,),))
        K = field_array(path, entry, "K", where, ((3, 3),))
        dist = field_array(path, entry, "distCoef", where, ((0,), (4,), (5,), (8,)))
        R = field_array(path, entry, "R", where, ((3, 3),))
        t = field_array(path, entry, "t", where, ((3, 1), (3,), (1, 3))).ravel() / CM_PER_M
        cams.append(make_camera(path, where, name, K, R, t, size, dist))
    if not cams:
        raise FileFormatError(path, f"cameras: no camera of type {list(camera_types or [])}")
    try:
        return CameraRig(cams)
    except ValueError as exc:
        raise FileFormatError(path, str(exc)) from None


def save_panoptic(rig: CameraRig, path: str | os.PathLike, camera_type: str = "hd") -> None:
    """Write ``rig`` as a Panoptic Studio calibration JSON (``t`` in centimetres), atomically.

    Parameters
    ----------
    rig : CameraRig
    path : path-like
    camera_type : str
        The ``type`` written for every camera.
    """
    cameras = [
        {
            "name": cam.name,
            "type": camera_type,
            "resolution": [int(cam.width), int(cam.height)],
            "K": cam.K.tolist(),
            "distCoef": trim_dist(cam.dist),
            "R": cam.R.tolist(),
            "t": [[float(v)] for v in cam.t * CM_PER_M],
        }
        for cam in rig
    ]
    # json writes floats with repr, so values read back exactly (up to the cm <-> m scaling).
    write_text_atomic(path, json.dumps({"cameras": cameras}, indent=1) + "\n")
