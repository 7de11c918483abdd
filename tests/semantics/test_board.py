"""The ChArUco board recogniser and the combined recogniser."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

from pointtraj.errors import FileFormatError, ValidationError
from pointtraj.labelset import LabelSet
from pointtraj.semantics.recognizers import ImageContext, make_recognizer
from pointtraj.semantics.recognizers.board import CharucoBoardRecognizer
from pointtraj.semantics.recognizers.combined import CombinedRecognizer

SHARED = Path(__file__).resolve().parents[2].parent / "shared"
CALISCOPE = SHARED / "data" / "caliscope_board_4cam"

BOARD_TOML = """columns = 4
rows = 5
dictionary = "DICT_4X4_1000"
aruco_scale = 0.75
square_size_override_cm = 5.4
inverted = true
"""

NAMES = ("head", "torso", "board")


def _warped_board(tmp_path: Path):
    """A white-on-black 4x5 ChArUco board warped into a 640x480 grey scene, its toml, and the
    outline of its squares in the image."""
    import cv2

    from pointtraj.calibrate import CharucoBoard

    toml = tmp_path / "charuco.toml"
    toml.write_text(BOARD_TOML)
    board = CharucoBoard.from_toml(toml)
    px = 100  # pixels per square in the flat board image
    flat = board.cv_board().generateImage((4 * px, 5 * px), marginSize=0)
    flat = 255 - flat  # printed inverted
    src = np.array([[0, 0], [4 * px, 0], [4 * px, 5 * px], [0, 5 * px]], np.float32)
    dst = np.array([[200, 90], [420, 110], [430, 400], [190, 380]], np.float32)
    H = cv2.getPerspectiveTransform(src, dst)
    scene = cv2.warpPerspective(flat, H, (640, 480), borderValue=128)
    return np.repeat(scene[..., None], 3, axis=2), toml, dst


def _mask_of(polygon: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    import cv2

    mask = np.zeros(size[::-1], np.uint8)
    cv2.fillConvexPoly(mask, np.rint(polygon).astype(np.int32), 1)
    return mask.astype(bool)


def test_board_area_matches_the_warped_board(tmp_path):
    import cv2

    image, toml, outline = _warped_board(tmp_path)
    rec = CharucoBoardRecognizer(NAMES, board=toml, map_size=640, margin=0.0)
    L = rec.recognize(image)
    assert L.shape == (480, 640, 3) and L.dtype == np.float32
    assert np.all(L[..., :2] == 0)
    got = L[..., 2] > 0.5
    want = _mask_of(outline, (640, 480))
    iou = (got & want).sum() / (got | want).sum()
    assert iou > 0.97
    assert L[..., 2].max() == pytest.approx(0.95)
    # A coarser map covers the same area.
    coarse = CharucoBoardRecognizer(NAMES, board=toml, map_size=160, margin=0.0).recognize(image)
    up = cv2.resize(coarse[..., 2], (640, 480), interpolation=cv2.INTER_NEAREST) > 0.5
    assert (up & want).sum() / (up | want).sum() > 0.9
    # The margin widens it; a blank image has no board.
    wide = CharucoBoardRecognizer(NAMES, board=toml, map_size=640, margin=0.5).recognize(image)
    assert (wide[..., 2] > 0.5).sum() > 1.3 * got.sum()
    assert not CharucoBoardRecognizer(NAMES, board=toml).recognize(np.zeros_like(image)).any()


def test_board_recogniser_errors(tmp_path):
    with pytest.raises(ValidationError, match="class 'board' is not in the label set"):
        CharucoBoardRecognizer(("head", "torso"))
    rec = CharucoBoardRecognizer(NAMES)
    image = np.zeros((48, 64, 3), np.uint8)
    with pytest.raises(ValidationError, match="no board file"):
        rec.recognize(image)
    with pytest.raises(FileFormatError, match="charuco.toml: no such file"):
        rec.recognize(image, ImageContext("c", 0, str(tmp_path)))
    mapped = CharucoBoardRecognizer(NAMES, mapping={"board": "torso"})
    assert mapped.channel == 1


def test_combined_takes_the_per_class_maximum_on_the_finest_grid(tmp_path):
    image, toml, outline = _warped_board(tmp_path)
    labels = LabelSet(NAMES, [(255, 0, 0), (0, 255, 0), (0, 0, 255)])
    rec = make_recognizer(
        "combined",
        labels,
        recognizers=["charuco-board", "simulated"],
        options={"charuco-board": {"board": str(toml), "map_size": 320}},
    )
    assert isinstance(rec, CombinedRecognizer) and rec.class_names == NAMES
    fine = CharucoBoardRecognizer(NAMES, board=str(toml), map_size=320)
    coarse = CharucoBoardRecognizer(NAMES, board=str(toml), map_size=80, mapping={"board": "head"})
    both = CombinedRecognizer([coarse, fine]).recognize(image)
    assert both.shape == (240, 320, 3)
    np.testing.assert_array_equal(both[..., 2], fine.recognize(image)[..., 2])
    assert both[..., 0].max() == pytest.approx(0.95) and not both[..., 1].any()
    with pytest.raises(ValidationError, match="options for 'body-parts', which is not among"):
        make_recognizer("combined", labels, recognizers=["simulated"], options={"body-parts": {}})
    with pytest.raises(ValidationError, match="unknown name 'nope'"):
        make_recognizer("combined", labels, recognizers=["nope"])


@pytest.mark.shared
@pytest.mark.skipif(not CALISCOPE.is_dir(), reason=f"needs the shared capture at {CALISCOPE}")
def test_board_found_where_caliscope_saw_it(tmp_path):
    """On the real caliscope videos the board area contains caliscope's own corner detections."""
    from pointtraj.examples import fetch_caliscope_board
    from pointtraj.session import Capture

    out = tmp_path / "board"
    fetch_caliscope_board(out, source=CALISCOPE)
    cap = Capture.open(out)
    labels = LabelSet.load(cap.labels_path)
    rec = make_recognizer("charuco-board", labels)
    k = labels.index("board")
    with open(out / "charuco" / "corners_2d.csv") as f:
        rows = list(csv.DictReader(f))
    checked = 0
    for frame in (10, 20, 40):
        for cam in cap.camera_names:
            pts = np.array(
                [
                    (float(r["x"]), float(r["y"]))
                    for r in rows
                    if int(r["frame"]) == frame and r["camera"] == cam
                ]
            )
            if len(pts) < 6:
                continue
            image = cap.read(cam, frame)
            L = rec.recognize(image, ImageContext(cam, frame, str(out)))
            H, W = image.shape[:2]
            h, w = L.shape[:2]
            cell = np.clip(
                np.rint((pts + 0.5) * [w / W, h / H] - 0.5).astype(int), 0, [w - 1, h - 1]
            )
            inside = L[cell[:, 1], cell[:, 0], k] > 0.5
            assert inside.mean() > 0.95, (cam, frame)
            checked += 1
    assert checked >= 6
