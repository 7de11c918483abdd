"""Checking a calibration with detected body landmarks (MediaPipe Pose)."""

from __future__ import annotations

import numpy as np

from ..camera import CameraRig

# -- verification with detected body landmarks ----------------------------------------------


def detect_landmarks(
    capture: object,
    frames: object,
    *,
    min_visibility: float = 0.5,
    threads: int = 1,
) -> np.ndarray:
    """MediaPipe Pose body landmarks of the most prominent person, per camera and frame.

    Uses :class:`pointtraj.semantics.recognizers.bodyparts.BodyPartRecognizer` (the
    ``body-parts`` model must be in the cache: ``pointtraj models fetch body-parts``).

    Parameters
    ----------
    capture : pointtraj.session.Capture
    frames : sequence of int
        F frame indices.
    min_visibility : float
        Landmarks with a lower MediaPipe visibility are NaN.
    threads : int
        LiteRT threads.

    Returns
    -------
    (C, F, 33, 2) float ndarray
        Pixels in each camera's stored frames; NaN where nobody was found or a landmark is
        not visible enough.
    """
    from ..semantics.recognizers.bodyparts import BodyPartRecognizer

    frames = [int(f) for f in frames]  # type: ignore[attr-defined]
    rec = BodyPartRecognizer(["person"], mapping={}, threads=threads)
    names = capture.camera_names  # type: ignore[attr-defined]
    out = np.full((len(names), len(frames), 33, 2), np.nan)
    for c, cam in enumerate(names):
        for i, t in enumerate(frames):
            poses = rec.estimate_poses(capture.read(cam, t))  # type: ignore[attr-defined]
            if poses:
                p = poses[0]
                ok = p.visibility >= min_visibility  # (33,)
                out[c, i, ok] = p.landmarks[ok]
    return out


def landmark_reprojection_errors(
    rig: CameraRig, landmarks: np.ndarray, *, leave_one_out: bool = False
) -> np.ndarray:
    """Reprojection errors of landmarks triangulated over the rig's cameras.

    Parameters
    ----------
    rig : CameraRig
        C cameras.
    landmarks : (C, ...) float ndarray
        Pixel observations ``(C, F, L, 2)`` or ``(C, N, 2)``; NaN where missing.
    leave_one_out : bool
        Triangulate each point from the other cameras only (at least 2) and measure the error
        in the left-out camera: a test of each camera's calibration that its own observations
        cannot absorb.

    Returns
    -------
    (C, N) float ndarray
        Pixel errors (N = all points), NaN where not measurable.
    """
    from ..reconstruct.triangulate import triangulate_points

    obs = np.asarray(landmarks, float).reshape(len(rig), -1, 2)  # (C, N, 2)
    if not leave_one_out:
        X = triangulate_points(rig, obs)  # (N, 3)
        return rig.reprojection_errors(X, obs)
    err = np.full(obs.shape[:2], np.nan)
    for c in range(len(rig)):
        others = [i for i in range(len(rig)) if i != c]
        X = triangulate_points(rig.subset(others), obs[others])  # (N, 3)
        err[c] = rig.subset([c]).reprojection_errors(X, obs[c : c + 1])[0]
    return err
