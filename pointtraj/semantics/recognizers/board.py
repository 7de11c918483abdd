"""A ChArUco board recogniser: the board's whole area as a confidence map.

Calibration boards are the objects of many lab captures (caliscope, anipose, Pose2Sim users
wave one in front of their cameras). OpenCV's ChArUco detector finds the board's inner corners;
a homography from the board plane fitted to them (RANSAC) maps the board's outer rectangle
(``columns x rows`` squares) into the image, and every map cell inside it gets the confidence.
Detection needs at least ``min_corners`` corners; otherwise the map is zero. The board layout
is caliscope's ``charuco.toml`` (:class:`pointtraj.calibrate.CharucoBoard`), read from the
``board`` option or from the capture folder.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ...errors import FileFormatError, ValidationError
from .base import ImageContext, Recognizer

__all__ = ["CharucoBoardRecognizer", "board_outline"]

logger = logging.getLogger(__name__)


def board_outline(
    ids: np.ndarray, corners: np.ndarray, board, min_corners: int = 4, margin: float = 0.0
):
    """The board's outer rectangle in the image, from its detected ChArUco corners.

    Parameters
    ----------
    ids : (n,) int ndarray
        Detected corner ids.
    corners : (n, 2) float ndarray
        Their pixel positions.
    board : pointtraj.calibrate.CharucoBoard
    min_corners : int
        Fewest corners (>= 4) to fit the homography.
    margin : float
        Widen the rectangle by this many squares on every side (the printed border).

    Returns
    -------
    (4, 2) float ndarray or None
        The outline's corners in pixels (board order), None when too few corners were found
        or the homography fails.
    """
    import cv2

    if len(ids) < max(4, min_corners):
        return None
    plane = board.corners()[np.asarray(ids, int), :2]  # (n, 2) metres, z = 0
    H, inliers = cv2.findHomography(plane, np.asarray(corners, float), cv2.RANSAC, 3.0)
    if H is None or int(inliers.sum()) < max(4, min_corners):
        return None
    w, h = board.columns * board.square_m, board.rows * board.square_m
    m = margin * board.square_m
    rect = np.array([[-m, -m], [w + m, -m], [w + m, h + m], [-m, h + m]])
    return cv2.perspectiveTransform(rect[None], H)[0]


class CharucoBoardRecognizer(Recognizer):
    """Confidence of class ``class_name`` over the area of a detected ChArUco board.

    Parameters
    ----------
    class_names : sequence of str
        The label set's K classes.
    board : path-like, optional
        caliscope-style ``charuco.toml``; default ``<capture>/charuco.toml`` of each image's
        capture (``ImageContext.capture``).
    class_name : str
        The class the board is (must be in ``class_names``).
    confidence : float
        Confidence inside the board.
    min_corners : int
        Fewest detected corners for a detection.
    map_size : int
        Longer side of the output map, in cells.
    margin : float
        Border around the squares counted as board, in squares (boards are printed or mounted
        with one).
    mapping : dict, optional
        ``{"board": class}``, as from ``[recognizers.charuco-board] map`` in labels.toml;
        overrides ``class_name``.
    """

    name = "charuco-board"

    def __init__(
        self,
        class_names: Sequence[str],
        board: str | os.PathLike | None = None,
        class_name: str = "board",
        confidence: float = 0.95,
        min_corners: int = 6,
        map_size: int = 256,
        margin: float = 0.5,
        mapping: dict | None = None,
    ) -> None:
        self.class_names = tuple(class_names)
        class_name = dict(mapping or {}).get("board", class_name)
        if class_name not in self.class_names:
            raise ValidationError(
                f"charuco-board: class {class_name!r} is not in the label set "
                f"({', '.join(self.class_names)})"
            )
        if not 0 < confidence <= 1:
            raise ValidationError(f"charuco-board: confidence must be in (0, 1], got {confidence}")
        if map_size < 8:
            raise ValidationError(f"charuco-board: map_size must be >= 8, got {map_size}")
        self.channel = self.class_names.index(class_name)
        self.confidence = float(confidence)
        self.min_corners = int(min_corners)
        self.map_size = int(map_size)
        self.margin = float(margin)
        self._board_path = None if board is None else Path(board)
        self._boards: dict[Path, object] = {}

    def _board(self, context: ImageContext | None):
        from ...calibrate import CharucoBoard

        path = self._board_path
        if path is None:
            if context is None or context.capture is None:
                raise ValidationError(
                    "charuco-board: no board file: pass board=<charuco.toml> or run it on a "
                    "capture folder that has one"
                )
            path = Path(context.capture) / "charuco.toml"
        if path not in self._boards:
            if not path.is_file():
                raise FileFormatError(path, "no such file (the ChArUco board layout)")
            self._boards[path] = CharucoBoard.from_toml(path)
        return self._boards[path]

    def recognize(self, image: np.ndarray, context: ImageContext | None = None) -> np.ndarray:
        """(h, w, K) map: ``confidence`` inside the detected board, 0 elsewhere."""
        import cv2

        from ...calibrate import detect_charuco

        H, W = image.shape[:2]
        s = self.map_size / max(H, W)
        h, w = max(1, round(H * s)), max(1, round(W * s))
        out = np.zeros((h, w, len(self.class_names)), np.float32)
        board = self._board(context)
        ids, corners = detect_charuco(image, board)
        outline = board_outline(ids, corners, board, self.min_corners, self.margin)
        if outline is None:
            return out
        # Pixel (u, v) lies at map cell ((u + 0.5) * w / W - 0.5, ...) (the sampling convention).
        cells = (outline + 0.5) * np.array([w / W, h / H]) - 0.5
        mask = np.zeros((h, w), np.uint8)
        cv2.fillConvexPoly(mask, np.rint(cells * 16).astype(np.int32), 1, cv2.LINE_8, 4)
        out[..., self.channel] = mask * self.confidence
        return out
