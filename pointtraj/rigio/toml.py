"""pointtraj's own ``rig.toml``: the anipose / aniposelib calibration TOML.

One table per camera, ``[cam_0]``, ``[cam_1]``, ... in rig order, each with ``name``,
``size = [w, h]``, ``matrix`` (3x3 K), ``distortions`` (OpenCV ``k1 k2 p1 p2 [k3 [k4 k5 k6]]``),
``rotation`` (Rodrigues vector, world to camera) and ``translation`` (metres), so that
``x_cam = R(rotation) X + translation``. An optional ``[metadata]`` table is kept as is.
Spec: ``data_specs/rig_toml.md``.
"""

from __future__ import annotations

import logging
import os
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from ..camera import CameraRig, rodrigues_from_rotation, rotation_from_rodrigues
from ..config import load_toml, save_toml
from ..errors import FileFormatError
from ._common import field_array, field_value, make_camera, trim_dist

__all__ = ["load_rig_toml", "save_rig_toml", "load_rig_toml_metadata", "rig_to_toml_dict"]

logger = logging.getLogger(__name__)

_CAM_TABLE = re.compile(r"^cam_(\d+)$")


def load_rig_toml(path: str | os.PathLike) -> CameraRig:
    """Read an aniposelib-compatible calibration TOML.

    Parameters
    ----------
    path : path-like
        A ``rig.toml`` (or anipose ``calibration.toml``).

    Returns
    -------
    CameraRig
        Cameras in the order of their ``cam_<i>`` index.

    Raises
    ------
    FileFormatError
        If the file is missing or malformed, naming the table and field (a missing field, a
        matrix of the wrong shape, a non-positive focal length, ...).
    """
    path = Path(path)
    return rig_from_toml_dict(load_toml(path), path)


def rig_from_toml_dict(data: Mapping[str, Any], path: str | os.PathLike) -> CameraRig:
    """Build a rig from a parsed aniposelib TOML (``path`` only names the file in errors)."""
    tables = sorted(
        ((int(m.group(1)), k) for k in data if (m := _CAM_TABLE.match(k))), key=lambda x: x[0]
    )
    if not tables:
        raise FileFormatError(path, "no [cam_<i>] camera tables")
    cams = []
    for _, key in tables:
        table = data[key]
        where = f"[{key}]"
        if not isinstance(table, Mapping):
            raise FileFormatError(path, f"{key}: expected a table, got {table!r}")
        name = str(field_value(path, table, "name", where))
        size = field_array(path, table, "size", where, ((2,),))
        K = field_array(path, table, "matrix", where, ((3, 3),))
        dist = field_array(path, table, "distortions", where, ((0,), (4,), (5,), (8,)))
        rvec = field_array(path, table, "rotation", where, ((3,),))
        t = field_array(path, table, "translation", where, ((3,),))
        if np.any(size != np.round(size)):
            raise FileFormatError(path, f"{where}.size: expected integers, got {size.tolist()}")
        R = rotation_from_rodrigues(rvec)
        cams.append(make_camera(path, where, name, K, R, t, size, dist))
    try:
        return CameraRig(cams)
    except ValueError as exc:
        raise FileFormatError(path, str(exc)) from None


def load_rig_toml_metadata(path: str | os.PathLike) -> dict[str, Any]:
    """The optional ``[metadata]`` table of a rig TOML (empty when absent)."""
    meta = load_toml(path).get("metadata", {})
    if not isinstance(meta, Mapping):
        raise FileFormatError(path, f"metadata: expected a table, got {meta!r}")
    return dict(meta)


def rig_to_toml_dict(rig: CameraRig, metadata: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The aniposelib TOML tables of ``rig`` (see :func:`save_rig_toml`)."""
    out: dict[str, Any] = {}
    for i, cam in enumerate(rig):
        out[f"cam_{i}"] = {
            "name": cam.name,
            "size": [int(cam.width), int(cam.height)],
            "matrix": cam.K.tolist(),
            "distortions": trim_dist(cam.dist),
            "rotation": rodrigues_from_rotation(cam.R).tolist(),
            "translation": cam.t.tolist(),
        }
    if metadata:
        out["metadata"] = dict(metadata)
    return out


def save_rig_toml(
    rig: CameraRig, path: str | os.PathLike, metadata: Mapping[str, Any] | None = None
) -> None:
    """Write ``rig`` as an aniposelib-compatible calibration TOML, atomically.

    Distortion is written with 5 coefficients (as aniposelib does) unless ``k4..k6`` are
    non-zero, in which case all 8 are written. Floats are written exactly (``repr``).

    Parameters
    ----------
    rig : CameraRig
    path : path-like
        Destination, usually ``<capture>/rig.toml``.
    metadata : mapping, optional
        Written as a ``[metadata]`` table (strings, numbers, booleans and lists of them).
    """
    save_toml(path, rig_to_toml_dict(rig, metadata))
    logger.debug("wrote %d cameras to %s", len(rig), path)
