"""Camera rig file formats: one module per format, each with ``load_<fmt>`` and ``save_<fmt>``.

=============  =====================================================  ==========================
format         files                                                  module
=============  =====================================================  ==========================
``toml``       pointtraj ``rig.toml`` = anipose/aniposelib TOML       :mod:`.toml`
``caliscope``  caliscope ``camera_array.toml`` / ``config.toml``      :mod:`.caliscope`
``colmap``     COLMAP sparse model folder (via pycolmap)              :mod:`.colmap`
``panoptic``   CMU Panoptic Studio ``calibration_*.json``             :mod:`.panoptic`
``qualisys``   Qualisys ``.qca.txt`` XML                              :mod:`.qualisys`
=============  =====================================================  ==========================

:func:`load_rig` picks the format from the name and content; :func:`save_rig` from the name or
an explicit ``fmt``.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

from ..camera import CameraRig
from ..config import load_toml
from ..errors import FileFormatError, ValidationError
from .caliscope import is_caliscope_dict, load_caliscope, save_caliscope
from .colmap import find_colmap_model, load_colmap, save_colmap
from .panoptic import load_panoptic, save_panoptic
from .qualisys import load_qualisys, save_qualisys
from .toml import load_rig_toml, rig_from_toml_dict, save_rig_toml

__all__ = [
    "FORMATS",
    "detect_format",
    "format_from_name",
    "load_rig",
    "save_rig",
    "load_rig_toml",
    "save_rig_toml",
    "load_caliscope",
    "save_caliscope",
    "load_colmap",
    "save_colmap",
    "load_panoptic",
    "save_panoptic",
    "load_qualisys",
    "save_qualisys",
]

logger = logging.getLogger(__name__)

#: Format names accepted by :func:`load_rig` and :func:`save_rig`.
FORMATS = ("toml", "caliscope", "colmap", "panoptic", "qualisys")


def _is_xml(path: Path) -> bool:
    with open(path, "rb") as f:
        head = f.read(512).lstrip()
    return head.startswith(b"<?xml") or head.startswith(b"<calibration")


def detect_format(path: str | os.PathLike) -> str:
    """The rig format of ``path``, from its name and (for TOML and text files) its content.

    Parameters
    ----------
    path : path-like
        A file, a COLMAP model folder, or a capture folder holding ``rig.toml``.

    Returns
    -------
    str
        One of :data:`FORMATS`.

    Raises
    ------
    FileFormatError
        If the path does not exist or matches no format.
    """
    path = Path(path)
    if path.is_dir():
        if find_colmap_model(path) is not None:
            return "colmap"
        if (path / "rig.toml").is_file():
            return "toml"
        if (path / "camera_array.toml").is_file():
            return "caliscope"
        raise FileFormatError(
            path, "folder holds no COLMAP model (cameras.bin/.txt), rig.toml or camera_array.toml"
        )
    if not path.is_file():
        raise FileFormatError(path, "no such file or folder")
    name = path.name.lower()
    if name.endswith(".json"):
        return "panoptic"
    if name.endswith(".toml"):
        return "caliscope" if is_caliscope_dict(load_toml(path)) else "toml"
    if name.endswith((".qca", ".qca.txt", ".xml")) or (name.endswith(".txt") and _is_xml(path)):
        return "qualisys"
    raise FileFormatError(
        path, "unknown rig format; expected .toml, .json, .qca.txt or a COLMAP model folder"
    )


def load_rig(path: str | os.PathLike, fmt: str | None = None) -> CameraRig:
    """Read a camera rig in any supported format.

    Parameters
    ----------
    path : path-like
        A rig file, a COLMAP model folder, or a capture folder holding ``rig.toml``.
    fmt : str, optional
        Force a format (one of :data:`FORMATS`) instead of detecting it.

    Returns
    -------
    CameraRig

    Raises
    ------
    FileFormatError
        Naming the file and the field for bad input (missing field, wrong matrix shape,
        non-rotation, ...).
    ValidationError
        For an unknown ``fmt``.

    Examples
    --------
    >>> import tempfile, numpy as np
    >>> from pointtraj import Camera, CameraRig
    >>> rig = CameraRig([Camera.look_at("a", [2.0, 0, 1], [0, 0, 1], (64, 48), 50.0)])
    >>> with tempfile.TemporaryDirectory() as d:
    ...     save_rig(rig, f"{d}/rig.toml")
    ...     back = load_rig(f"{d}/rig.toml")
    >>> back.names, bool(np.allclose(back.C, rig.C))
    (['a'], True)
    """
    path = Path(path)
    fmt = detect_format(path) if fmt is None else fmt
    if fmt not in FORMATS:
        raise ValidationError(f"fmt: unknown rig format {fmt!r}; choose from {', '.join(FORMATS)}")
    if path.is_dir() and fmt == "toml":
        path = path / "rig.toml"
    elif path.is_dir() and fmt == "caliscope":
        path = path / "camera_array.toml"
    logger.debug("reading %s as %s", path, fmt)
    if fmt == "toml":
        data = load_toml(path)
        return rig_from_toml_dict(data, path)
    return {
        "caliscope": load_caliscope,
        "colmap": load_colmap,
        "panoptic": load_panoptic,
        "qualisys": load_qualisys,
    }[fmt](path)


def format_from_name(path: str | os.PathLike) -> str:
    """The format :func:`save_rig` writes for an output name (see there)."""
    name = Path(path).name.lower()
    if name == "camera_array.toml":
        return "caliscope"
    if name.endswith(".toml"):
        return "toml"
    if name.endswith(".json"):
        return "panoptic"
    if name.endswith((".qca.txt", ".qca", ".xml")):
        return "qualisys"
    if not Path(path).suffix:
        return "colmap"
    raise ValidationError(
        f"cannot tell the rig format of {str(path)!r} from its name; pass one of {', '.join(FORMATS)}"
    )


def save_rig(rig: CameraRig, path: str | os.PathLike, fmt: str | None = None) -> None:
    """Write ``rig`` in a supported format, atomically.

    Parameters
    ----------
    rig : CameraRig
    path : path-like
        ``*.toml`` -> ``toml`` (``camera_array.toml`` -> ``caliscope``), ``*.json`` ->
        ``panoptic``, ``*.qca.txt`` -> ``qualisys``, a name without extension -> a ``colmap``
        model folder.
    fmt : str, optional
        Force a format (one of :data:`FORMATS`).

    Raises
    ------
    ValidationError
        For an unknown format, or a rig the format cannot hold.
    """
    fmt = format_from_name(path) if fmt is None else fmt
    if fmt not in FORMATS:
        raise ValidationError(f"fmt: unknown rig format {fmt!r}; choose from {', '.join(FORMATS)}")
    {
        "toml": save_rig_toml,
        "caliscope": save_caliscope,
        "colmap": save_colmap,
        "panoptic": save_panoptic,
        "qualisys": save_qualisys,
    }[fmt](rig, path)
