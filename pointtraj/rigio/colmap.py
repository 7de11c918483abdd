"""COLMAP sparse models (``cameras``/``images`` ``.bin`` or ``.txt``), through pycolmap.

Every registered image becomes one camera, named after the image file's stem. COLMAP puts the
origin of pixel coordinates at the top-left *corner* of the image, OpenCV (and pointtraj) at the
centre of the top-left pixel, so principal points differ by half a pixel:
``c_pointtraj = c_colmap - 0.5``. Spec: ``data_specs/colmap.md``.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

import numpy as np

from ..camera import Camera, CameraRig
from ..errors import FileFormatError, ValidationError
from ._common import replace_folder_files, temp_folder_beside

__all__ = ["load_colmap", "save_colmap", "SUPPORTED_MODELS", "find_colmap_model"]

logger = logging.getLogger(__name__)

#: COLMAP camera models we read, and how their parameters map to (fx, fy, cx, cy, dist).
SUPPORTED_MODELS = (
    "SIMPLE_PINHOLE",
    "PINHOLE",
    "SIMPLE_RADIAL",
    "RADIAL",
    "OPENCV",
    "FULL_OPENCV",
)
#: Half a pixel: COLMAP's pixel-centre convention minus OpenCV's.
PIXEL_OFFSET = 0.5


def find_colmap_model(path: str | os.PathLike) -> Path | None:
    """The folder holding ``cameras.bin``/``cameras.txt`` at ``path`` or ``path/sparse/0``."""
    path = Path(path)
    for cand in (path, path / "sparse" / "0", path / "sparse", path / "0"):
        if (cand / "cameras.bin").is_file() or (cand / "cameras.txt").is_file():
            return cand
    return None


def _has_pose(image: object) -> bool:
    """Whether a pycolmap image is registered (``has_pose`` since 3.12, ``registered`` before)."""
    flag = getattr(image, "has_pose", None)
    if flag is None:
        flag = getattr(image, "registered", True)
    return bool(flag() if callable(flag) else flag)


def _intrinsics(model: str, params: np.ndarray) -> tuple[float, float, float, float, np.ndarray]:
    """(fx, fy, cx, cy, dist) in COLMAP's pixel convention from a model's parameter vector."""
    p = [float(v) for v in params]
    if model == "SIMPLE_PINHOLE":
        f, cx, cy = p
        return f, f, cx, cy, np.zeros(0)
    if model == "PINHOLE":
        fx, fy, cx, cy = p
        return fx, fy, cx, cy, np.zeros(0)
    if model == "SIMPLE_RADIAL":
        f, cx, cy, k = p
        return f, f, cx, cy, np.array([k, 0.0, 0.0, 0.0])
    if model == "RADIAL":
        f, cx, cy, k1, k2 = p
        return f, f, cx, cy, np.array([k1, k2, 0.0, 0.0])
    if model == "OPENCV":
        fx, fy, cx, cy, k1, k2, p1, p2 = p
        return fx, fy, cx, cy, np.array([k1, k2, p1, p2])
    if model == "FULL_OPENCV":
        fx, fy, cx, cy = p[:4]
        return fx, fy, cx, cy, np.array(p[4:12])
    raise KeyError(model)


def load_colmap(path: str | os.PathLike) -> CameraRig:
    """Read a COLMAP sparse model folder as a rig of one camera per registered image.

    Parameters
    ----------
    path : path-like
        The model folder (with ``cameras.bin`` and ``images.bin``, or the ``.txt`` files), or a
        COLMAP project folder holding ``sparse/0``.

    Returns
    -------
    CameraRig
        Cameras named after the image names' stems (or, if stems repeat, the image names
        without extension with ``/`` replaced by ``_``), sorted by name.

    Raises
    ------
    FileFormatError
        If there is no model, pycolmap cannot read it, an image uses an unsupported camera
        model, or no image is registered.
    """
    import pycolmap

    path = Path(path)
    folder = find_colmap_model(path)
    if folder is None:
        raise FileFormatError(path, "no COLMAP model (cameras.bin or cameras.txt) here")
    try:
        rec = pycolmap.Reconstruction(str(folder))
    except (RuntimeError, ValueError) as exc:
        raise FileFormatError(folder, f"pycolmap cannot read this model ({exc})") from None
    images = [im for im in rec.images.values() if _has_pose(im)]
    skipped = rec.num_images() - len(images)
    if skipped:
        logger.warning("%s: skipping %d image(s) without a pose", folder, skipped)
    if not images:
        raise FileFormatError(folder, "images: no registered image")
    stems = [Path(im.name).stem for im in images]
    if len(set(stems)) != len(stems):
        stems = [str(Path(im.name).with_suffix("")).replace("/", "_") for im in images]
    cams = []
    for name, im in sorted(zip(stems, images), key=lambda x: x[0]):
        cam = rec.cameras[im.camera_id]
        model = cam.model.name
        where = f"image {im.name!r} (camera {im.camera_id})"
        if model not in SUPPORTED_MODELS:
            raise FileFormatError(
                folder,
                f"{where}: camera model {model} is not supported "
                f"(supported: {', '.join(SUPPORTED_MODELS)})",
            )
        fx, fy, cx, cy, dist = _intrinsics(model, cam.params)
        K = np.array([[fx, 0.0, cx - PIXEL_OFFSET], [0.0, fy, cy - PIXEL_OFFSET], [0.0, 0.0, 1.0]])
        pose = im.cam_from_world
        pose = pose() if callable(pose) else pose  # a method since pycolmap 3.12, a property before
        M = np.asarray(pose.matrix())  # (3, 4) world-to-camera [R | t]
        try:
            cams.append(
                Camera.from_extrinsics(name, K, M[:, :3], M[:, 3], (cam.width, cam.height), dist)
            )
        except ValidationError as exc:
            raise FileFormatError(folder, f"{where}: {exc}") from None
    try:
        return CameraRig(cams)
    except ValidationError as exc:
        raise FileFormatError(folder, str(exc)) from None


def save_colmap(
    rig: CameraRig, path: str | os.PathLike, *, text: bool = False, image_ext: str = ".jpg"
) -> None:
    """Write ``rig`` as a COLMAP sparse model (no 3D points) in folder ``path``.

    Each camera becomes a COLMAP camera of model ``OPENCV`` (``FULL_OPENCV`` when its
    ``k3..k6`` are non-zero) and one image ``<name><image_ext>`` posed at the camera. The files
    are written to a temporary folder beside ``path`` and each moved into place atomically;
    other files in ``path`` are left alone.

    Parameters
    ----------
    rig : CameraRig
    path : path-like
        The model folder (created if needed).
    text : bool
        Write ``.txt`` files instead of ``.bin``.
    image_ext : str
        Extension of the image names.

    Raises
    ------
    ValidationError
        If a camera has skew (COLMAP's models have none).
    """
    import pycolmap

    path = Path(path)
    rec = pycolmap.Reconstruction()
    if not hasattr(rec, "add_image_with_trivial_frame"):
        raise ValidationError(
            f"writing COLMAP models needs pycolmap >= 3.12 (rigs and frames); "
            f"this is pycolmap {getattr(pycolmap, '__version__', '?')}"
        )
    for i, cam in enumerate(rig, start=1):
        if cam.K[0, 1] != 0:
            raise ValidationError(f"camera {cam.name!r}: COLMAP models cannot hold skew K[0, 1]")
        full = bool(np.any(cam.dist[4:]))
        model = "FULL_OPENCV" if full else "OPENCV"
        ccam = pycolmap.Camera.create_from_model_name(i, model, 1.0, cam.width, cam.height)
        fx, fy = cam.K[0, 0], cam.K[1, 1]
        cx, cy = cam.K[0, 2] + PIXEL_OFFSET, cam.K[1, 2] + PIXEL_OFFSET
        ccam.params = [fx, fy, cx, cy, *cam.dist[: 8 if full else 4]]
        rec.add_camera_with_trivial_rig(ccam)
        image = pycolmap.Image(name=f"{cam.name}{image_ext}", camera_id=i, image_id=i)
        pose = pycolmap.Rigid3d(pycolmap.Rotation3d(cam.R), cam.t)
        rec.add_image_with_trivial_frame(image, pose)
    tmp = temp_folder_beside(path)
    try:
        (rec.write_text if text else rec.write)(str(tmp))
        replace_folder_files(tmp, path)
    finally:
        if tmp.exists():
            import shutil

            shutil.rmtree(tmp, ignore_errors=True)
    logger.debug("wrote %d cameras to COLMAP model %s", len(rig), path)
