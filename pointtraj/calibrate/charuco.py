"""ChArUco boards: detection, metric alignment of a rig, and calibration from board corners alone.

A board seen by the cameras gives a rig metric scale and the board's world frame
(:func:`align_rig_to_charuco`). For footage where SfM cannot register the cameras (few,
textureless views of a moving board), :func:`calibrate_charuco` calibrates from ChArUco corners
alone: OpenCV's planar calibration per camera, relative poses from shared board views, then a
joint bundle adjustment of all intrinsics, camera poses and board poses with the board's known
geometry.
"""

from __future__ import annotations

import logging
import os
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..camera import Camera, CameraRig
from ..errors import FileFormatError, ValidationError
from ..geometry import mean_rotation, rodrigues_from_rotation, rotation_from_rodrigues
from ._common import Calibration, CalibrationError
from .align import transform_rig, umeyama

__all__ = [
    "CharucoBoard",
    "Detections",
    "align_rig_to_charuco",
    "calibrate_charuco",
    "detect_charuco",
]

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class CharucoBoard:
    """A ChArUco board in caliscope's ``charuco.toml`` layout.

    Attributes
    ----------
    columns, rows : int
        Squares across and down.
    square_m : float
        Square side in metres.
    marker_m : float
        ArUco marker side in metres.
    dictionary : str
        OpenCV predefined dictionary name, e.g. ``DICT_4X4_1000``.
    inverted : bool
        Printed white-on-black: images are inverted before detection.
    """

    columns: int
    rows: int
    square_m: float
    marker_m: float
    dictionary: str = "DICT_4X4_50"
    inverted: bool = False

    @classmethod
    def from_toml(cls, path: str | os.PathLike) -> CharucoBoard:
        """Read caliscope's ``charuco.toml`` (columns, rows, board_width/height and units or
        ``square_size_override_cm``, aruco_scale, dictionary, inverted)."""
        path = Path(path)
        try:
            data = tomllib.loads(path.read_text())
        except FileNotFoundError:
            raise FileFormatError(path, "no such file") from None
        except tomllib.TOMLDecodeError as exc:
            raise FileFormatError(path, f"not valid TOML: {exc}") from None
        for key in ("columns", "rows", "dictionary"):
            if key not in data:
                raise FileFormatError(path, f"missing field {key!r}")
        columns, rows = int(data["columns"]), int(data["rows"])
        if columns < 2 or rows < 2:
            raise FileFormatError(path, f"columns and rows must be >= 2, got {columns}x{rows}")
        if data.get("square_size_override_cm"):
            square = float(data["square_size_override_cm"]) / 100
        elif "board_width" in data:
            unit = {"inch": 0.0254, "cm": 0.01, "mm": 0.001, "m": 1.0}.get(
                str(data.get("units", "inch"))
            )
            if unit is None:
                raise FileFormatError(path, f"unknown units {data.get('units')!r}")
            square = (
                min(float(data["board_width"]) / columns, float(data["board_height"]) / rows) * unit
            )
        else:
            raise FileFormatError(path, "missing square_size_override_cm or board_width")
        import cv2

        if not hasattr(cv2.aruco, str(data["dictionary"])):
            raise FileFormatError(path, f"unknown ArUco dictionary {data['dictionary']!r}")
        scale = float(data.get("aruco_scale", 0.75))
        return cls(
            columns,
            rows,
            square,
            square * scale,
            str(data["dictionary"]),
            bool(data.get("inverted", False)),
        )

    def cv_board(self):
        """The ``cv2.aruco.CharucoBoard``."""
        import cv2

        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        return cv2.aruco.CharucoBoard(
            (self.columns, self.rows), self.square_m, self.marker_m, dictionary
        )

    def corners(self) -> np.ndarray:
        """(N, 3) float ndarray: inner chessboard corners in the board frame (metres, z = 0),
        indexed by ChArUco corner id."""
        return np.asarray(self.cv_board().getChessboardCorners(), float).reshape(-1, 3)


def detect_charuco(image: np.ndarray, board: CharucoBoard) -> tuple[np.ndarray, np.ndarray]:
    """Detect ChArUco corners.

    Parameters
    ----------
    image : (H, W, 3) uint8 ndarray
        RGB image (or (H, W) grey).
    board : CharucoBoard

    Returns
    -------
    ids : (n,) int ndarray
        Corner ids (rows of :meth:`CharucoBoard.corners`).
    corners : (n, 2) float ndarray
        Sub-pixel corner positions (OpenCV pixels).
    """
    import cv2

    img = np.asarray(image)
    grey = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY) if img.ndim == 3 else img
    if board.inverted:
        grey = 255 - grey
    detector = cv2.aruco.CharucoDetector(board.cv_board())
    corners, ids, _, _ = detector.detectBoard(grey)
    if ids is None or len(ids) == 0:
        return np.zeros(0, int), np.zeros((0, 2))
    return ids.ravel().astype(int), corners.reshape(-1, 2).astype(float)


Detections = Mapping[tuple[int, int], tuple[np.ndarray, np.ndarray]]


def _observations(
    detections: Detections, num_cameras: int, num_corners: int
) -> tuple[np.ndarray, list[int]]:
    """(C, F * n, 2) pixel array (NaN where unseen) and the frame of each block of n rows."""
    frames = sorted({f for _, f in detections})
    fi = {f: i for i, f in enumerate(frames)}
    obs = np.full((num_cameras, len(frames) * num_corners, 2), np.nan)
    for (c, f), (ids, xy) in detections.items():
        if len(ids):
            obs[c, fi[f] * num_corners + np.asarray(ids)] = xy
    return obs, frames


def align_rig_to_charuco(
    rig: CameraRig, detections: Detections, board: CharucoBoard, min_corners: int = 6
) -> tuple[CameraRig, dict[str, float]]:
    """Give a rig metric scale and the board's frame from ChArUco detections.

    Corners seen by >= 2 cameras are triangulated frame by frame; each frame's triangulated
    board is fitted to the board's geometry by a similarity. The scale is the median over
    frames; the world frame is the board (x along columns, y along rows, z out of the board)
    in the frame with the most triangulated corners.

    Parameters
    ----------
    rig : CameraRig
    detections : mapping (camera index, frame) -> (ids (n,), corners (n, 2))
    board : CharucoBoard
    min_corners : int
        Triangulated corners for a frame to be used.

    Returns
    -------
    rig : CameraRig
    stats : dict
        ``frames`` used, ``reference_frame`` (the frame whose board defines the world),
        ``board_rms_mm`` (RMS distance of triangulated corners to the fitted
        board, metric), ``scale_spread`` (relative MAD of the per-frame scales).

    Raises
    ------
    CalibrationError
        If no frame has ``min_corners`` corners seen by two cameras.
    """
    from ..reconstruct.triangulate import triangulate_points

    ref_pts = board.corners()
    n = len(ref_pts)
    obs, frames = _observations(detections, len(rig), n)
    X = triangulate_points(rig, obs).reshape(len(frames), n, 3)
    fits = []
    for k in range(len(frames)):
        ok = np.all(np.isfinite(X[k]), axis=1)
        if ok.sum() < min_corners:
            continue
        try:
            s, R, t = umeyama(ref_pts[ok], X[k][ok])
        except ValidationError:
            continue
        fits.append((int(ok.sum()), k, s, R, t))
    if not fits:
        raise CalibrationError(
            f"ChArUco: no frame has {min_corners} corners detected in two registered cameras"
        )
    scales = np.array([f[2] for f in fits])
    s_med = float(np.median(scales))
    _, k_ref, _, R_ref, t_ref = max(fits, key=lambda f: f[0])
    # Board frame of the reference frame: X_board = R_ref^T (X - t_ref) / s_med.
    aligned = transform_rig(rig, 1.0 / s_med, R_ref.T, -R_ref.T @ t_ref / s_med)
    resid = []
    for _, k, s, R, t in fits:
        ok = np.all(np.isfinite(X[k]), axis=1)
        fitted = (s * ref_pts[ok] @ R.T + t) / s_med
        resid.append(np.linalg.norm(X[k][ok] / s_med - fitted, axis=1))
    r = np.concatenate(resid)
    stats = {
        "frames": float(len(fits)),
        "reference_frame": float(frames[k_ref]),
        "board_rms_mm": float(1e3 * np.sqrt(np.mean(r**2))),
        "scale_spread": float(np.median(np.abs(scales - s_med)) / s_med),
    }
    logger.info("ChArUco alignment: %s", stats)
    return aligned, stats


def calibrate_charuco(
    detections: Detections,
    board: CharucoBoard,
    camera_names: Sequence[str],
    sizes: Sequence[tuple[int, int]],
    min_corners: int = 6,
    lens: str = "simple",
    min_k2_coverage: float = 0.5,
) -> tuple[Calibration, dict[str, float]]:
    """Calibrate a rig from ChArUco corners alone (when feature-based SfM cannot register).

    1. Per camera, OpenCV's planar calibration (``cv2.calibrateCamera``) on its board views
       gives K and distortion (k1 k2 p1 p2 k3) and a board pose per view.
    2. Camera poses: camera 0 is the reference; every other camera's pose relative to a camera
       already placed is the chordal mean over the frames both see the board in.
    3. Joint bundle adjustment (``scipy.optimize.least_squares``, Huber loss, sparse Jacobian)
       of all intrinsics, camera poses and one board pose per frame, with the board's known
       metric geometry, minimising corner reprojection errors.

    The world frame is the board in the frame where most cameras see it.

    Higher-order radial terms are only constrained where the board was seen: for a camera whose
    board corners stay within ``min_k2_coverage`` of the half-diagonal from the image centre,
    k2 (and k3) are held at 0. Otherwise k2 is fitted to the central part of the image and
    extrapolates wildly towards the corners (caliscope's cam_3, corners within 0.33 of the
    half-diagonal: k2 = +2.78, 761 px RMS distortion difference from caliscope's calibration
    over the image; 82 px with k1 alone).

    Parameters
    ----------
    detections : mapping (camera index, frame) -> (ids (n,), corners (n, 2))
    board : CharucoBoard
    camera_names : sequence of str
    sizes : sequence of (w, h)
    min_corners : int
        Corners for a view to be used.
    lens : {"simple", "full"}
        ``full``: fx fy cx cy k1 k2 p1 p2 k3 per camera. ``simple``: fx fy k1 k2, with the
        principal point at the image centre and p1 = p2 = k3 = 0; far better conditioned when
        the board covers little of each image.
    min_k2_coverage : float
        Board coverage (largest distance of a detected corner from the image centre, over the
        half-diagonal) below which k2 and k3 are held at 0; 0 fits them for every camera.

    Returns
    -------
    calibration : Calibration
        Its notes name the cameras calibrated with k1 alone.
    stats : dict
        ``views`` used, ``rms_px`` after the adjustment, ``rms_px_initial``, and
        ``coverage_<camera>`` per calibrated camera.
    """
    import cv2
    from scipy.optimize import least_squares

    if lens not in ("simple", "full"):
        raise ValidationError(f"lens: expected 'simple' or 'full', got {lens!r}")
    ref = board.corners().astype(np.float32)
    C = len(camera_names)
    views = {
        (c, f): (np.asarray(ids), np.asarray(xy))
        for (c, f), (ids, xy) in detections.items()
        if len(ids) >= min_corners
    }
    K0, d0, board_pose = [], [], {}
    failed: dict[str, str] = {}
    coverage: dict[int, float] = {}
    k1_only: list[int] = []
    for c in range(C):
        keys = sorted(k for k in views if k[0] == c)
        if len(keys) < 3:
            failed[camera_names[c]] = (
                f"board seen with >= {min_corners} corners in {len(keys)} frames"
            )
            K0.append(None)
            d0.append(None)
            continue
        objp = [ref[views[k][0]] for k in keys]
        imgp = [views[k][1].astype(np.float32) for k in keys]
        w, h = sizes[c]
        K_init = np.array([[w, 0.0, (w - 1) / 2], [0.0, w, (h - 1) / 2], [0.0, 0.0, 1.0]])
        flags = cv2.CALIB_USE_INTRINSIC_GUESS
        if lens == "simple":
            flags |= cv2.CALIB_FIX_PRINCIPAL_POINT | cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K3
        reach = np.linalg.norm(np.concatenate(imgp) - K_init[:2, 2], axis=1)  # (n,)
        coverage[c] = float(reach.max() / np.hypot(w / 2, h / 2))
        if coverage[c] < min_k2_coverage:
            flags |= cv2.CALIB_FIX_K2 | cv2.CALIB_FIX_K3
            k1_only.append(c)
        _, K, d, rvecs, tvecs = cv2.calibrateCamera(
            objp, imgp, (int(w), int(h)), K_init, np.zeros(5), flags=flags
        )
        K0.append(K)
        d0.append(d.ravel()[:5])
        for k, rv, tv in zip(keys, rvecs, tvecs, strict=True):
            board_pose[k] = (rotation_from_rodrigues(rv.ravel()), tv.ravel())
    ok_cams = [c for c in range(C) if K0[c] is not None]
    if len(ok_cams) < 2:
        raise CalibrationError(
            f"ChArUco: only {len(ok_cams)} camera(s) saw the board often enough; need 2"
        )
    # Relative poses: x_c = R_c X + t_c (world = camera ok_cams[0]).
    cam_pose = {ok_cams[0]: (np.eye(3), np.zeros(3))}
    frames_of = {c: {f for (cc, f) in board_pose if cc == c} for c in ok_cams}
    while len(cam_pose) < len(ok_cams):
        best = None
        for c in ok_cams:
            if c in cam_pose:
                continue
            for p in cam_pose:
                shared = frames_of[c] & frames_of[p]
                if best is None or len(shared) > len(best[2]):
                    best = (c, p, shared)
        c, p, shared = best
        if not shared:
            for cc in ok_cams:
                if cc not in cam_pose:
                    failed[camera_names[cc]] = "never sees the board together with a placed camera"
            break
        # cam_c_from_cam_p = board_in_c * board_in_p^-1.
        Rs, ts = [], []
        for f in shared:
            Rc, tc = board_pose[(c, f)]
            Rp, tp = board_pose[(p, f)]
            Rcp = Rc @ Rp.T
            Rs.append(Rcp)
            ts.append(tc - Rcp @ tp)
        Rcp = mean_rotation(np.stack(Rs))
        tcp = np.median(np.stack(ts), axis=0)
        Rp_w, tp_w = cam_pose[p]
        cam_pose[c] = (Rcp @ Rp_w, Rcp @ tp_w + tcp)
    placed = sorted(cam_pose)
    # Board pose per frame in world from the first placed camera that sees it.
    frames = sorted({f for (c, f) in board_pose if c in cam_pose})
    frame_pose = {}
    for f in frames:
        for c in placed:
            if (c, f) in board_pose:
                Rb, tb = board_pose[(c, f)]
                Rc, tc = cam_pose[c]
                frame_pose[f] = (Rc.T @ Rb, Rc.T @ (tb - tc))
                break
    obs = [(c, f, views[(c, f)]) for (c, f) in sorted(views) if c in cam_pose and f in frame_pose]
    cam_i = np.concatenate([np.full(len(v[0]), placed.index(c)) for c, f, v in obs])
    fr_i = np.concatenate([np.full(len(v[0]), frames.index(f)) for c, f, v in obs])
    pts = np.concatenate([ref[v[0]] for c, f, v in obs]).astype(float)  # (P, 3)
    uv = np.concatenate([v[1] for c, f, v in obs])  # (P, 2)
    NC, NF = len(placed), len(frames)
    n_int = 9  # fx fy cx cy k1 k2 p1 p2 k3

    def pack() -> np.ndarray:
        x = []
        for c in placed:
            K, d = K0[c], d0[c]
            x += [K[0, 0], K[1, 1], K[0, 2], K[1, 2], *d]
            R, t = cam_pose[c]
            x += [*rodrigues_from_rotation(R), *t]
        for f in frames:
            R, t = frame_pose[f]
            x += [*rodrigues_from_rotation(R), *t]
        return np.asarray(x, float)

    def unpack(x: np.ndarray):
        cam = x[: NC * (n_int + 6)].reshape(NC, n_int + 6)
        fr = x[NC * (n_int + 6) :].reshape(NF, 6)
        return cam, fr

    def rotate(rvec: np.ndarray, p: np.ndarray) -> np.ndarray:
        """Rodrigues rotation of points p (P, 3) by per-point rvec (P, 3)."""
        th = np.linalg.norm(rvec, axis=1, keepdims=True)
        k = rvec / np.where(th > 1e-12, th, 1.0)
        cos, sin = np.cos(th), np.sin(th)
        return p * cos + np.cross(k, p) * sin + k * np.sum(k * p, axis=1, keepdims=True) * (1 - cos)

    def residuals(x: np.ndarray) -> np.ndarray:
        cam, fr = unpack(x)
        Xw = rotate(fr[fr_i, :3], pts) + fr[fr_i, 3:]  # (P, 3)
        cp = cam[cam_i]
        Xc = rotate(cp[:, n_int : n_int + 3], Xw) + cp[:, n_int + 3 :]
        xn = Xc[:, :2] / Xc[:, 2:3]
        k1, k2, p1, p2, k3 = (cp[:, 4 + i] for i in range(5))
        x_, y_ = xn[:, 0], xn[:, 1]
        r2 = x_**2 + y_**2
        radial = 1 + k1 * r2 + k2 * r2**2 + k3 * r2**3
        xd = x_ * radial + 2 * p1 * x_ * y_ + p2 * (r2 + 2 * x_**2)
        yd = y_ * radial + p1 * (r2 + 2 * y_**2) + 2 * p2 * x_ * y_
        u = cp[:, 0] * xd + cp[:, 2]
        v = cp[:, 1] * yd + cp[:, 3]
        return np.concatenate([u - uv[:, 0], v - uv[:, 1]])

    P = len(pts)
    x0 = pack()
    free = np.ones_like(x0, bool)
    if lens == "simple":
        for i in range(NC):  # cx cy p1 p2 k3 stay at their initial values
            free[i * (n_int + 6) + np.array([2, 3, 6, 7, 8])] = False
    for i in range(NC):
        if placed[i] in k1_only:  # k2 k3 stay at 0
            free[i * (n_int + 6) + np.array([5, 8])] = False

    def residuals_free(z: np.ndarray) -> np.ndarray:
        x = x0.copy()
        x[free] = z
        return residuals(x)

    r0 = residuals(x0)
    scale = np.concatenate([np.tile(_CAMERA_SCALE, NC), np.full(NF * 6, 0.01)])
    # Levenberg-Marquardt with a dense finite-difference Jacobian: a few hundred parameters.
    sol = least_squares(residuals_free, x0[free], x_scale=scale[free], method="lm")
    x_opt = x0.copy()
    x_opt[free] = sol.x
    cam, fr = unpack(x_opt)
    res = sol.fun.reshape(2, P)
    err = np.hypot(res[0], res[1])
    # World frame: the board in the frame seen by the most cameras.
    seen = np.bincount(fr_i, minlength=NF)
    f_ref = int(np.argmax(seen))
    Rb = rotation_from_rodrigues(fr[f_ref, :3])
    tb = fr[f_ref, 3:]
    cams, errors, nobs = [], {}, {}
    for i, c in enumerate(placed):
        K = np.array([[cam[i, 0], 0, cam[i, 2]], [0, cam[i, 1], cam[i, 3]], [0, 0, 1.0]])
        R = rotation_from_rodrigues(cam[i, n_int : n_int + 3])
        t = cam[i, n_int + 3 :]
        # x = R (Rb Xb + tb) + t = (R Rb) Xb + (R tb + t).
        name = camera_names[c]
        cams.append(
            Camera.from_extrinsics(name, K, R @ Rb, R @ tb + t, tuple(sizes[c]), cam[i, 4:9])
        )
        errors[name] = float(err[cam_i == i].mean())
        nobs[name] = int((cam_i == i).sum())
    stats = {
        "views": float(len(obs)),
        "rms_px_initial": float(np.sqrt(np.mean(r0**2) * 2)),
        "rms_px": float(np.sqrt(np.mean(err**2))),
        **{f"coverage_{camera_names[c]}": v for c, v in coverage.items()},
    }
    cal = Calibration(
        rig=CameraRig(cams),
        camera_names=list(camera_names),
        errors=errors,
        observations=nobs,
        failed={n: failed.get(n, "not placed") for n in camera_names if n not in errors},
        match_counts=_shared_corner_counts(views, C),
        num_points=int(P),
        notes=[
            f"ChArUco calibration: {len(obs)} board views, world = board in frame {frames[f_ref]}"
        ],
    )
    if k1_only:
        cal.notes.append(
            "radial distortion k1 only (board corners within "
            f"{min_k2_coverage:g} of the half-diagonal): "
            + ", ".join(f"{camera_names[c]} ({coverage[c]:.2f})" for c in k1_only)
        )
    return cal, stats


#: Typical magnitudes of fx fy cx cy k1 k2 p1 p2 k3 rvec(3) t(3) (least-squares x_scale).
_CAMERA_SCALE = np.array([10, 10, 10, 10, 0.05, 0.05, 0.005, 0.005, 0.05] + [0.01] * 6)


def _shared_corner_counts(views: Detections, C: int) -> np.ndarray:
    """Corners seen by both cameras of each pair (summed over frames)."""
    counts = np.zeros((C, C), np.int64)
    by_frame: dict[int, dict[int, set]] = {}
    for (c, f), (ids, _) in views.items():
        by_frame.setdefault(f, {})[c] = set(np.asarray(ids).tolist())
    for cams in by_frame.values():
        for a in cams:
            for b in cams:
                if a != b:
                    counts[a, b] += len(cams[a] & cams[b])
    return counts
