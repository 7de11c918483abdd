"""caliscope's calibration: ``camera_array.toml`` (``[cameras.<id>]``) or ``config.toml`` (``[cam_<id>]``).

Each camera table holds ``cam_id``, ``size = [w, h]``, ``matrix`` (3x3 K), ``distortions``
(OpenCV ``k1 k2 p1 p2 k3``), ``rotation`` (3x3 world-to-camera matrix; a Rodrigues vector is
also accepted) and ``translation`` (metres), ``x_cam = R X + t``. Cameras with
``ignore = true`` are skipped with a warning. Cameras are named ``cam_<id>``, as caliscope names
its videos. Spec: ``data_specs/caliscope.md``.
"""

from __future__ import annotations

import logging
import os
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from ..camera import CameraRig, rotation_from_rodrigues
from ..config import load_toml, save_toml
from ..errors import FileFormatError
from ._common import field_array, field_value, make_camera, trim_dist

__all__ = ["load_caliscope", "save_caliscope", "is_caliscope_dict"]

logger = logging.getLogger(__name__)

_OLD_TABLE = re.compile(r"^cam_(\d+)$")
_NAME = re.compile(r"^cam_(\d+)$")


def _camera_tables(data: Mapping[str, Any]) -> list[tuple[int, str, Mapping[str, Any]]]:
    """(id, where, table) of every camera table, in either layout, sorted by id."""
    out = []
    cameras = data.get("cameras")
    if isinstance(cameras, Mapping):
        for key, table in cameras.items():
            if isinstance(table, Mapping) and str(key).lstrip("-").isdigit():
                out.append((int(key), f"[cameras.{key}]", table))
    for key, table in data.items():
        if (m := _OLD_TABLE.match(key)) and isinstance(table, Mapping):
            out.append((int(m.group(1)), f"[{key}]", table))
    return sorted(out, key=lambda x: x[0])


def is_caliscope_dict(data: Mapping[str, Any]) -> bool:
    """Whether a parsed TOML looks like caliscope's (3x3 ``rotation`` or ``[cameras.N]`` tables)."""
    if isinstance(data.get("cameras"), Mapping):
        return True
    for _, _, table in _camera_tables(data):
        rot = table.get("rotation")
        if isinstance(rot, list) and rot and isinstance(rot[0], list):
            return True
        if "name" not in table and "cam_id" in table:
            return True
    return False


def load_caliscope(path: str | os.PathLike) -> CameraRig:
    """Read caliscope's ``camera_array.toml`` (or the camera tables of its ``config.toml``).

    Parameters
    ----------
    path : path-like

    Returns
    -------
    CameraRig
        Cameras ``cam_<id>`` in increasing id, without those marked ``ignore = true``.

    Raises
    ------
    FileFormatError
        If the file has no camera tables, a camera lacks a field (for example ``rotation`` when
        only intrinsics were calibrated), or a field has the wrong shape or value.
    """
    path = Path(path)
    data = load_toml(path)
    tables = _camera_tables(data)
    if not tables:
        raise FileFormatError(path, "no [cameras.<id>] or [cam_<id>] camera tables")
    cams = []
    for cam_id, where, table in tables:
        if table.get("ignore", False) is True:
            logger.warning("%s: skipping camera %d marked ignore = true", path, cam_id)
            continue
        if "cam_id" in table and int(field_value(path, table, "cam_id", where)) != cam_id:
            raise FileFormatError(
                path, f"{where}.cam_id: {table['cam_id']!r} disagrees with the table name"
            )
        if table.get("rotation_count", 0) not in (0, None):
            logger.warning(
                "%s: camera %d has rotation_count = %r; images are used as stored, unrotated",
                path,
                cam_id,
                table["rotation_count"],
            )
        size = field_array(path, table, "size", where, ((2,),))
        K = field_array(path, table, "matrix", where, ((3, 3),))
        dist = field_array(path, table, "distortions", where, ((0,), (4,), (5,), (8,)))
        rot = field_array(path, table, "rotation", where, ((3, 3), (3,)))
        t = field_array(path, table, "translation", where, ((3,),))
        R = rot if rot.shape == (3, 3) else rotation_from_rodrigues(rot)
        cams.append(make_camera(path, where, f"cam_{cam_id}", K, R, t, size, dist))
    if not cams:
        raise FileFormatError(path, "every camera is marked ignore = true")
    try:
        return CameraRig(cams)
    except ValueError as exc:
        raise FileFormatError(path, str(exc)) from None


def save_caliscope(rig: CameraRig, path: str | os.PathLike) -> None:
    """Write ``rig`` as caliscope's ``camera_array.toml`` (``[cameras.<id>]`` tables), atomically.

    A camera named ``cam_<id>`` keeps its id; other names get their index in the rig (caliscope
    has no camera names, so they are lost; a log message says so).

    Parameters
    ----------
    rig : CameraRig
    path : path-like
    """
    ids = []
    for i, cam in enumerate(rig):
        m = _NAME.match(cam.name)
        ids.append(int(m.group(1)) if m else i)
    if len(set(ids)) != len(ids):
        ids = list(range(len(rig)))
    if any(not _NAME.match(c.name) for c in rig):
        logger.info("caliscope has no camera names; cameras are written as cam_<index>")
    cameras = {}
    for cam_id, cam in zip(ids, rig):
        cameras[str(cam_id)] = {
            "cam_id": cam_id,
            "rotation_count": 0,
            "ignore": False,
            "size": [int(cam.width), int(cam.height)],
            "matrix": cam.K.tolist(),
            "distortions": trim_dist(cam.dist),
            "translation": cam.t.tolist(),
            "rotation": cam.R.tolist(),
        }
    save_toml(path, {"cameras": cameras})
