"""The ``pose2sim`` and ``pose2sim-multi`` examples: Pose2Sim's ``Demo_SinglePerson`` and
``Demo_MultiPerson`` from the PyPI wheel."""

from __future__ import annotations

import logging
import os
import shutil
import zipfile
from collections.abc import Mapping
from pathlib import Path

from ..atomic import write_text_atomic
from ..camera import CameraRig
from ..errors import FileFormatError, ValidationError
from ..fetch import cache_root, fetch_verified_wheel
from ..images import read_rgb
from .common import (
    EXAMPLES,
    POSE2SIM_DEMO,
    POSE2SIM_DEMOS,
    POSE2SIM_REQUIREMENT,
    ExampleCapture,
    ExampleNotFoundError,
    _finish_output,
    _first_frame,
    _save_capture_toml,
    _start_output,
    _video_info,
)
from .mapping import ImageMapping, choose_image_mapping

logger = logging.getLogger(__name__)


#: SHA-256 of ``pose2sim-0.10.49-py3-none-any.whl`` (the only file of that release on PyPI).
POSE2SIM_SHA256 = "403e0dc4065898ba6a595e72a8970950310979253d60e24c2e00b16b36bf21e1"
POSE2SIM_FPS = 60.0

# -- pose2sim -------------------------------------------------------------------------------


def download_pose2sim_wheel(cache: str | os.PathLike | None = None) -> Path:
    """The ``pose2sim==0.10.49`` wheel, from the cache or downloaded with pip.

    Parameters
    ----------
    cache : path-like, optional
        Folder for the wheel (default ``<cache root>/examples``,
        :func:`pointtraj.fetch.cache_root`).

    Returns
    -------
    pathlib.Path
        The wheel file.

    Raises
    ------
    ExampleNotFoundError
        If pip cannot download it (with pip's last lines), or it fails its pinned SHA-256
        (:func:`pointtraj.fetch.fetch_verified_wheel`).
    """
    folder = Path(cache) if cache is not None else cache_root() / "examples"
    return fetch_verified_wheel(
        POSE2SIM_REQUIREMENT,
        folder,
        POSE2SIM_SHA256,
        options=["--timeout", "30", "--retries", "2"],
        error=ExampleNotFoundError,
    )


def _extract(z: zipfile.ZipFile, member: str, dest: Path) -> Path:
    dest.parent.mkdir(parents=True, exist_ok=True)
    with z.open(member) as src, open(dest, "wb") as dst:
        shutil.copyfileobj(src, dst, 1 << 20)
    return dest


def _match_cameras(rig: CameraRig, videos: list[str], calib: Path) -> CameraRig:
    """Rename rig cameras to the video names (by name, else in sorted order as Pose2Sim does)."""
    if sorted(rig.names) == sorted(videos):
        return rig.subset(sorted(videos))
    if len(rig) != len(videos):
        raise FileFormatError(
            calib,
            f"{len(rig)} calibrated cameras ({', '.join(rig.names)}) but {len(videos)} "
            f"videos ({', '.join(videos)})",
        )
    logger.warning(
        "%s: camera names %s differ from the videos %s; matching them in sorted order",
        calib,
        rig.names,
        videos,
    )
    return CameraRig([c.with_name(v) for c, v in zip(rig, sorted(videos))])


def fetch_pose2sim(
    out: str | os.PathLike,
    *,
    wheel: str | os.PathLike | None = None,
    cache: str | os.PathLike | None = None,
    overwrite: bool = False,
    example: str = "pose2sim",
) -> ExampleCapture:
    """Lay out Pose2Sim's ``Demo_SinglePerson`` (or ``Demo_MultiPerson``) as a pointtraj capture.

    Writes ``rig.toml`` (from ``calibration/Calib.qca.txt``, cameras named like the videos,
    intrinsics adapted to the stored video size where it differs, logged as a warning),
    ``videos/<camera>.mp4``, ``capture.toml`` (fps 60), ``labels.toml``
    (:meth:`LabelSet.default`), ``README.md``, ``LICENSE`` (Pose2Sim's, BSD-3-Clause) and
    ``source/`` (the Qualisys file, Pose2Sim's ``Config.toml`` and the 1088 px
    ``extrinsics/*.png`` frames used to measure the size correction).

    Parameters
    ----------
    out : path-like
        The capture folder to write (new or empty).
    wheel : path-like, optional
        A downloaded ``pose2sim-0.10.49-*.whl``; default :func:`download_pose2sim_wheel`.
    cache : path-like, optional
        Wheel cache folder for :func:`download_pose2sim_wheel`.
    overwrite : bool
        Replace ``out`` if it holds a capture written by this module.
    example : {"pose2sim", "pose2sim-multi"}
        Which demo: one person, or two (the same cameras, calibration and size correction;
        the reference frames for the correction are ``Demo_SinglePerson``'s).

    Returns
    -------
    ExampleCapture

    Raises
    ------
    ExampleNotFoundError
        If the wheel cannot be downloaded.
    FileFormatError
        If the wheel lacks the demo's videos or calibration.
    """
    from ..labelset import LabelSet
    from ..rigio.qualisys import load_qualisys
    from ..rigio.toml import save_rig_toml

    if example not in POSE2SIM_DEMOS:
        raise ValidationError(
            f"unknown Pose2Sim example {example!r}; valid: {', '.join(POSE2SIM_DEMOS)}"
        )
    folder = POSE2SIM_DEMOS[example]
    out = Path(out)
    tmp = _start_output(out, overwrite)
    try:
        wheel = Path(wheel) if wheel is not None else download_pose2sim_wheel(cache)
        try:
            z = zipfile.ZipFile(wheel)
        except (OSError, zipfile.BadZipFile) as exc:
            raise FileFormatError(wheel, f"not a readable wheel ({exc})") from None
        with z:
            names = z.namelist()
            demo = [n for n in names if n.startswith(folder) and not n.endswith("/")]
            videos = sorted(
                n for n in demo if n.startswith(folder + "videos/") and n.endswith(".mp4")
            )
            calibs = sorted(
                n for n in demo if n.startswith(folder + "calibration/") and n.endswith(".qca.txt")
            )
            if not videos or not calibs:
                raise FileFormatError(
                    wheel, f"no {folder}videos/*.mp4 or calibration/*.qca.txt inside"
                )
            src = tmp / "source"
            calib = _extract(z, calibs[0], src / Path(calibs[0]).name)
            for n in demo:
                if n[len(folder) :] == "Config.toml":
                    _extract(z, n, src / "Config.toml")
            for n in names:  # the size correction's reference frames (the same cameras)
                rel = n[len(POSE2SIM_DEMO) :]
                if n.startswith(POSE2SIM_DEMO + "calibration/extrinsics/") and not n.endswith("/"):
                    _extract(z, n, src / rel.removeprefix("calibration/"))
            for n in videos:
                _extract(z, n, tmp / "videos" / Path(n).name)
            lic = [n for n in names if n.endswith(".dist-info/licenses/LICENSE")]
            if lic:
                _extract(z, lic[0], tmp / "LICENSE")
            shipped = sorted({n[len(folder) :].split("/")[0] for n in demo})
        cams = [Path(n).stem for n in videos]
        rig = _match_cameras(load_qualisys(calib), cams, calib)
        counts, corrections, evidence, fixed = {}, {}, {}, []
        for cam in rig:
            vpath = tmp / "videos" / f"{cam.name}.mp4"
            count, size, _ = _video_info(vpath)
            counts[cam.name] = count
            if tuple(size) == tuple(cam.size):
                fixed.append(cam)
                continue
            ref_path = src / "extrinsics" / f"{cam.name}_ext.png"
            ref = read_rgb(ref_path) if ref_path.is_file() else None
            if ref is not None and tuple(ref.shape[1::-1]) != tuple(cam.size):
                ref = None
            mapping, why = choose_image_mapping(cam.name, cam.size, _first_frame(vpath), ref)
            corrections[cam.name] = mapping
            evidence[cam.name] = why
            fixed.append(mapping.apply(cam))
        if corrections:
            logger.warning(
                "pose2sim: video size differs from the calibration for camera(s) %s; adapted "
                "their intrinsics: %s",
                ", ".join(corrections),
                "; ".join(f"{k}: {m.describe()}" for k, m in corrections.items()),
            )
        rig = CameraRig(fixed)
        save_rig_toml(rig, tmp / "rig.toml")
        spec = EXAMPLES[example]
        _save_capture_toml(
            tmp / "capture.toml",
            POSE2SIM_FPS,
            f"{spec.source} (https://pypi.org/project/pose2sim/0.10.49/, "
            "https://github.com/perfanalytics/pose2sim)",
            f"{spec.description}. Licence: {spec.licence} (LICENSE, Copyright (c) 2022, "
            "perfanalytics).",
        )
        LabelSet.default().save(tmp / "labels.toml")
        notes = [f"{k}: {evidence[k]}" for k in corrections]
        reference = [s for s in shipped if s.startswith("pose")]
        notes.append(
            "reference pose outputs shipped in the wheel: "
            + (", ".join(reference) if reference else "none (only " + ", ".join(shipped) + ")")
        )
        _write_pose2sim_readme(tmp, rig, counts, corrections, notes, example)
        _finish_output(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    logger.info("wrote %s: %d cameras, %s frames", out, len(rig), counts)
    return ExampleCapture(example, out, rig.names, counts, POSE2SIM_FPS, corrections, notes)


def _write_pose2sim_readme(
    folder: Path,
    rig: CameraRig,
    counts: Mapping[str, int],
    corrections: Mapping[str, ImageMapping],
    notes: list[str],
    example: str = "pose2sim",
) -> None:
    demo = POSE2SIM_DEMOS[example]
    who = (
        "a man balancing on a treadmill"
        if example == "pose2sim"
        else "a man balancing on a treadmill and a woman beside it"
    )
    rows = "\n".join(
        f"| {c.name} | {c.size[0]}x{c.size[1]} | {counts[c.name]} | "
        + (corrections[c.name].describe() if c.name in corrections else "none")
        + " |"
        for c in rig
    )
    text = (
        f"""# Pose2Sim {demo.split("/")[1]}, as a pointtraj capture

Written by `pointtraj examples fetch {example}`.

- **Origin**: folder `{demo}` of the PyPI wheel `{POSE2SIM_REQUIREMENT}`
  (<https://github.com/perfanalytics/pose2sim>), by David Pagnon / perfanalytics.
- **Licence**: BSD-3-Clause, Copyright (c) 2022, perfanalytics (`LICENSE`). Keep the licence
  with any copy of these files.
- **Content**: {len(rig)} static cameras filming {who}, portrait
  1088x1920, 60 fps; calibration by a Qualisys system (`source/Calib.qca.txt`), converted to
  `rig.toml` by `pointtraj.rigio.load_qualisys`.
- `labels.toml` is pointtraj's default label set (14 body parts, ball, racket).
- `source/extrinsics/*.png` are 1088 px frames of the same static cameras that Pose2Sim ships
  with its calibration; they are the reference for the size correction below.

| camera | stored size | frames | calibration adapted |
|---|---|---|---|
{rows}

Notes:

"""
        + "\n".join(f"- {n}" for n in notes)
        + "\n"
    )
    write_text_atomic(folder / "README.md", text)
