"""``pointtraj calibrate``: calibrate a capture's rig with pycolmap (or from ChArUco corners)."""

from __future__ import annotations

import tempfile
from pathlib import Path

import click
import numpy as np

__all__ = ["calibrate"]


def _parse_frames(text: str | None, num_frames: int) -> list[int]:
    """``"0,10,20"`` -> [0, 10, 20]; None -> up to 3 frames spread over the capture."""
    if text is None:
        return sorted({int(round(v)) for v in np.linspace(0, num_frames - 1, min(3, num_frames))})
    try:
        frames = sorted({int(v) for v in text.split(",") if v.strip()})
    except ValueError:
        raise click.BadParameter(
            f"expected comma-separated frame indices, got {text!r}", param_hint="--frames"
        ) from None
    if not frames:
        raise click.BadParameter("no frames given", param_hint="--frames")
    bad = [f for f in frames if not 0 <= f < num_frames]
    if bad:
        raise click.BadParameter(
            f"frame(s) {bad} outside the capture (0..{num_frames - 1})", param_hint="--frames"
        )
    return frames


def _placeholder_rig(capture: Path):
    """A rig of uncalibrated cameras named after the capture's frame folders or videos, so a
    capture without ``rig.toml`` can be opened (only names and image sizes are used)."""
    import cv2

    from ..camera import Camera, CameraRig

    cams = []
    frames = capture / "frames"
    videos = capture / "videos"
    if frames.is_dir():
        for sub in sorted(p for p in frames.iterdir() if p.is_dir()):
            first = next(
                (p for p in sorted(sub.iterdir()) if p.suffix.lower() in (".jpg", ".png")), None
            )
            img = cv2.imread(str(first)) if first is not None else None
            if img is not None:
                h, w = img.shape[:2]
                cams.append(Camera.look_at(sub.name, [0, -3.0, 1], [0, 0, 1], (w, h), float(w)))
    elif videos.is_dir():
        for vid in sorted(videos.glob("*.mp4")):
            cap = cv2.VideoCapture(str(vid))
            w, h = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
            cap.release()
            if w > 0 and h > 0:
                cams.append(Camera.look_at(vid.stem, [0, -3.0, 1], [0, 0, 1], (w, h), float(w)))
    if len(cams) < 2:
        raise click.ClickException(
            f"missing images: {capture} has no rig.toml and fewer than 2 cameras under "
            "frames/<camera>/ or videos/<camera>.mp4"
        )
    return CameraRig(cams)


@click.command("calibrate")
@click.argument("capture", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option(
    "--out",
    "out",
    required=True,
    type=click.Path(dir_okay=False, path_type=Path),
    help="Rig file to write (rig.toml).",
)
@click.option(
    "--scale-distance",
    nargs=3,
    type=(str, str, float),
    default=None,
    metavar="CAM_A CAM_B METRES",
    help="Known distance between two camera centres.",
)
@click.option(
    "--charuco",
    type=click.Path(exists=True, dir_okay=False, path_type=Path),
    help="caliscope charuco.toml: scale and world frame from the board seen in the frames.",
)
@click.option(
    "--align-to",
    type=click.Path(exists=True, path_type=Path),
    help="Existing rig (any format) whose world frame and scale to adopt.",
)
@click.option("--frames", "frames_text", help="Comma-separated frame indices (default: 3 spread).")
@click.option(
    "--method",
    type=click.Choice(["sfm", "charuco"]),
    default="sfm",
    show_default=True,
    help="sfm: pycolmap features; charuco: board corners only (needs --charuco).",
)
@click.option(
    "--camera-model",
    default="RADIAL",
    show_default=True,
    type=click.Choice(["OPENCV", "FULL_OPENCV", "RADIAL", "SIMPLE_RADIAL", "PINHOLE"]),
    help="COLMAP camera model.",
)
@click.option("--refine-principal-point", is_flag=True, help="Refine principal points in BA.")
@click.option(
    "--max-angle",
    type=float,
    default=90.0,
    show_default=True,
    help="Connectivity graph: largest angle between viewing directions.",
)
@click.option(
    "--work",
    type=click.Path(file_okay=False, path_type=Path),
    help="Keep the COLMAP database and model here (default: a temporary folder).",
)
def calibrate(
    capture: Path,
    out: Path,
    scale_distance: tuple[str, str, float] | None,
    charuco: Path | None,
    align_to: Path | None,
    frames_text: str | None,
    method: str,
    camera_model: str,
    refine_principal_point: bool,
    max_angle: float,
    work: Path | None,
) -> None:
    """Calibrate the cameras of CAPTURE (intrinsics, extrinsics, joint bundle adjustment).

    Without --scale-distance, --charuco or --align-to the rig has SfM's arbitrary scale and
    world frame. Beside OUT it writes <stem>_connectivity.png/.json: the geometric camera graph
    confirmed by verified match counts.
    """
    from .. import calibrate as cal_lib
    from ..session import Capture

    if sum(x is not None for x in (scale_distance, charuco, align_to)) > 1 and method == "sfm":
        raise click.UsageError("give only one of --scale-distance, --charuco and --align-to")
    if method == "charuco" and charuco is None:
        raise click.UsageError("--method charuco needs --charuco BOARD.toml")
    rig_file = capture / "rig.toml"
    cap = Capture.open(
        capture, rig=None if rig_file.is_file() else _placeholder_rig(capture), strict=False
    )
    frames = _parse_frames(frames_text, cap.num_frames)
    board = cal_lib.CharucoBoard.from_toml(charuco) if charuco is not None else None
    with tempfile.TemporaryDirectory(prefix="pointtraj-calib-") as tmp:
        scratch = work or Path(tmp)
        image_dir = scratch / "images"
        n = len(frames) * len(cap.camera_names)
        with click.progressbar(
            cal_lib.export_frames(cap, frames, image_dir),
            length=n,
            label=f"exporting {len(frames)} frame(s) of {len(cap.camera_names)} cameras",
        ) as bar:
            for _ in bar:
                pass
        detections = {}
        if board is not None:
            with click.progressbar(
                [(c, f) for c in range(len(cap.camera_names)) for f in frames],
                label="detecting ChArUco corners",
            ) as bar:
                for c, f in bar:
                    detections[(c, f)] = cal_lib.detect_charuco(cap.read(c, f), board)
        if method == "charuco":
            click.echo("calibrating from ChArUco corners (joint bundle adjustment)")
            sizes = [cap.image_size(c) for c in cap.camera_names]
            result, stats = cal_lib.calibrate_charuco(detections, board, cap.camera_names, sizes)
            click.echo(f"ChArUco bundle adjustment: {stats['rms_px']:.3f} px RMS")
        else:
            options = cal_lib.CalibrationOptions(
                camera_model=camera_model, refine_principal_point=refine_principal_point
            )
            result = cal_lib.calibrate_images(
                image_dir, scratch / "colmap", options, stage=click.echo
            )
            result = _set_frame(result, cal_lib, scale_distance, board, detections, align_to)
    click.echo(result.summary())
    _save(result, out, method, frames)
    _connectivity(result, out, max_angle)
    click.echo(f"wrote {len(result.rig)} cameras to {out}")


def _set_frame(result, cal_lib, scale_distance, board, detections, align_to):
    """Apply the user's metric scale / world frame to an SfM calibration."""
    if scale_distance is not None:
        a, b, metres = scale_distance
        rig = cal_lib.scale_rig_by_distance(result.rig, a, b, metres)
        return result.with_rig(rig, f"scale: |C_{a} - C_{b}| = {metres} m")
    if board is not None:
        # Detections are indexed over all capture cameras; keep the registered ones.
        index = {name: i for i, name in enumerate(result.camera_names)}
        reg = {index[n]: k for k, n in enumerate(result.rig.names)}
        dets = {(reg[c], f): v for (c, f), v in detections.items() if c in reg}
        rig, stats = cal_lib.align_rig_to_charuco(result.rig, dets, board)
        return result.with_rig(
            rig,
            f"scale and world frame from the ChArUco board: {int(stats['frames'])} frames, "
            f"board fit {stats['board_rms_mm']:.2f} mm RMS, scale spread "
            f"{100 * stats['scale_spread']:.2f} %",
        )
    if align_to is not None:
        from ..rigio import load_rig

        fit = cal_lib.estimate_rig_similarity(result.rig, load_rig(align_to))
        rig = cal_lib.transform_rig(result.rig, *fit.similarity)
        note = f"aligned to {align_to} (similarity, scale {fit.similarity[0]:.4g}"
        if fit.outliers:
            note += (
                f"; left out of the fit, centres disagree by > {fit.threshold_m:.3g}: "
                + ", ".join(f"{n} ({fit.residual_m[n]:.3g})" for n in fit.outliers)
            )
        return result.with_rig(rig, note + ")")
    click.echo(
        "warning: no --scale-distance, --charuco or --align-to: scale and world frame are "
        "arbitrary",
        err=True,
    )
    return result.with_rig(result.rig, "scale and world frame: arbitrary (SfM)")


def _save(result, out: Path, method: str, frames: list[int]) -> None:
    from ..rigio.toml import save_rig_toml

    errs = [v for v in result.errors.values() if np.isfinite(v)]
    meta = {
        "calibrated_by": "pointtraj calibrate",
        "method": method,
        "frames": frames,
        "mean_reprojection_error_px": float(np.mean(errs)) if errs else -1.0,
        "failed_cameras": sorted(result.failed),
        "notes": result.notes,
    }
    out.parent.mkdir(parents=True, exist_ok=True)
    save_rig_toml(result.rig, out, metadata=meta)


def _connectivity(result, out: Path, max_angle: float) -> None:
    """Geometric graph confirmed by the pairwise match counts; PNG + JSON beside ``out``."""
    from ..reconstruct.connectivity import build_connectivity, confirm_connectivity

    rig = result.rig
    idx = [result.camera_names.index(n) for n in rig.names]
    counts = result.match_counts[np.ix_(idx, idx)]
    graph = build_connectivity(rig, max_angle)
    confirmed = confirm_connectivity(graph, counts, min_matches=15)
    iu = np.triu_indices(len(rig), 1)
    matched = int(np.sum(np.maximum(counts, counts.T)[iu] >= 15))
    click.echo(
        f"connectivity: {confirmed.num_edges} of {graph.num_edges} geometric edges confirmed by "
        f">= 15 verified matches ({matched} camera pairs have >= 15 matches)"
    )
    stem = out.with_suffix("")
    confirmed.plot(f"{stem}_connectivity.png", rig)
    confirmed.save(f"{stem}_connectivity.json")
    click.echo(f"wrote {stem}_connectivity.png")
