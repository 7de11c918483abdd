"""Tests of pointtraj.rigio: every rig format, the dispatcher, the CLI, and real calibrations."""

from __future__ import annotations

import json
import logging
import os
import zipfile
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from pointtraj.camera import Camera, CameraRig
from pointtraj.config import load_toml, save_toml
from pointtraj.errors import FileFormatError, ValidationError
from pointtraj.examples import ExampleNotFoundError, download_pose2sim_wheel
from pointtraj.rigio import (
    FORMATS,
    detect_format,
    load_caliscope,
    load_colmap,
    load_panoptic,
    load_qualisys,
    load_rig,
    load_rig_toml,
    save_caliscope,
    save_colmap,
    save_panoptic,
    save_qualisys,
    save_rig,
    save_rig_toml,
)
from pointtraj.rigio.toml import load_rig_toml_metadata

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
CALISCOPE = SHARED / "data" / "caliscope_board_4cam"
needs_shared = pytest.mark.skipif(
    not (CALISCOPE / "camera_array.toml").is_file(),
    reason=f"real caliscope data not found at {CALISCOPE} (../shared is absent)",
)


def random_rig(seed: int = 0, n: int = 3, dist_len: int = 5) -> CameraRig:
    """Cameras cam_0.. with random poses, intrinsics and distortion (``dist_len`` coefficients)."""
    rng = np.random.default_rng(seed)
    cams = []
    for i in range(n):
        q, r = np.linalg.qr(rng.normal(size=(3, 3)))
        R = q * np.sign(np.diag(r))
        R = R if np.linalg.det(R) > 0 else -R
        w, h = int(rng.integers(320, 2000)), int(rng.integers(240, 1500))
        K = np.array(
            [
                [rng.uniform(300, 2000), 0.0, rng.uniform(0.4, 0.6) * w],
                [0.0, rng.uniform(300, 2000), rng.uniform(0.4, 0.6) * h],
                [0.0, 0.0, 1.0],
            ]
        )
        dist = rng.normal(scale=[0.1, 0.05, 0.002, 0.002, 0.01, 0.05, 0.02, 0.01][:dist_len])
        cams.append(Camera(f"cam_{i}", K, R, rng.normal(size=3) * 2, (w, h), dist))
    return CameraRig(cams)


def assert_same_rig(a: CameraRig, b: CameraRig, atol: float = 1e-9) -> None:
    assert a.names == b.names
    np.testing.assert_array_equal(a.sizes, b.sizes)
    np.testing.assert_allclose(a.K, b.K, atol=atol, rtol=0)
    np.testing.assert_allclose(a.R, b.R, atol=atol, rtol=0)
    np.testing.assert_allclose(a.C, b.C, atol=atol, rtol=0)
    np.testing.assert_allclose(a.dist, b.dist, atol=atol, rtol=0)


SAVE_NAMES = {
    "toml": "rig.toml",
    "caliscope": "camera_array.toml",
    "colmap": "sparse",
    "panoptic": "calibration.json",
    "qualisys": "calib.qca.txt",
}


@pytest.mark.parametrize("fmt", FORMATS)
def test_round_trip_every_format(fmt, tmp_path):
    rig = random_rig(1, n=4)
    path = tmp_path / "out" / SAVE_NAMES[fmt]
    save_rig(rig, path)
    assert detect_format(path) == fmt
    assert_same_rig(load_rig(path), rig)
    leftovers = [p.name for p in path.parent.iterdir() if p.name.startswith(".")]
    assert not leftovers, f"temporary files left: {leftovers}"


@pytest.mark.parametrize(
    ("save", "load", "name"),
    [
        (save_rig_toml, load_rig_toml, "rig.toml"),
        (save_panoptic, load_panoptic, "p.json"),
        (save_colmap, load_colmap, "model"),
    ],
)
def test_round_trip_rational_distortion(save, load, name, tmp_path):
    """Formats that hold all 8 OpenCV coefficients keep k4..k6."""
    rig = random_rig(2, dist_len=8)
    save(rig, tmp_path / name)
    assert_same_rig(load(tmp_path / name), rig)


def test_rig_toml_is_aniposelib_layout(tmp_path):
    rig = random_rig(3)
    save_rig_toml(rig, tmp_path / "rig.toml", metadata={"source": "test", "n": 3})
    import tomllib

    data = tomllib.loads((tmp_path / "rig.toml").read_text())
    assert sorted(data) == ["cam_0", "cam_1", "cam_2", "metadata"]
    cam = data["cam_1"]
    assert sorted(cam) == ["distortions", "matrix", "name", "rotation", "size", "translation"]
    assert len(cam["distortions"]) == 5 and len(cam["rotation"]) == 3
    import cv2

    R, _ = cv2.Rodrigues(np.array(cam["rotation"]))
    np.testing.assert_allclose(R, rig[1].R, atol=1e-12)
    np.testing.assert_allclose(cam["translation"], rig[1].t, atol=1e-12)  # x_cam = R X + t
    assert load_rig_toml_metadata(tmp_path / "rig.toml") == {"source": "test", "n": 3}


def test_rig_toml_accepts_4_and_8_distortions(tmp_path):
    text = (
        '[cam_0]\nname = "left"\nsize = [640, 480]\n'
        "matrix = [[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]]\n"
        "distortions = [0.1, 0.01, 0.0, 0.0]\nrotation = [0.0, 0.0, 0.0]\n"
        "translation = [0.0, 0.0, 1.0]\n"
        '[cam_1]\nname = "right"\nsize = [640, 480]\n'
        "matrix = [[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]]\n"
        "distortions = [0.1, 0.01, 0.0, 0.0, 0.001, 0.2, 0.0, 0.0]\n"
        "rotation = [0.0, 0.1, 0.0]\ntranslation = [-0.5, 0.0, 1.0]\n"
    )
    (tmp_path / "rig.toml").write_text(text)
    rig = load_rig(tmp_path / "rig.toml")
    assert rig.names == ["left", "right"]
    np.testing.assert_allclose(rig[0].C, [0, 0, -1.0])
    np.testing.assert_allclose(rig[1].dist, [0.1, 0.01, 0, 0, 0.001, 0.2, 0, 0])


def _minimal_toml(**override: str) -> str:
    fields = {
        "name": '"a"',
        "size": "[640, 480]",
        "matrix": "[[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]]",
        "distortions": "[0.0, 0.0, 0.0, 0.0, 0.0]",
        "rotation": "[0.0, 0.0, 0.0]",
        "translation": "[0.0, 0.0, 1.0]",
    }
    fields.update(override)
    return "[cam_0]\n" + "".join(f"{k} = {v}\n" for k, v in fields.items() if v)


@pytest.mark.parametrize(
    ("override", "match"),
    [
        ({"matrix": ""}, r"\[cam_0\]: missing field 'matrix'"),
        (
            {"matrix": "[[500.0, 0.0, 320.0], [0.0, 500.0, 240.0]]"},
            r"\[cam_0\]\.matrix: expected shape \(3, 3\), got \(2, 3\)",
        ),
        (
            {"matrix": "[[-5.0, 0.0, 3.0], [0.0, 5.0, 2.0], [0.0, 0.0, 1.0]]"},
            "focal lengths must be positive",
        ),
        ({"distortions": "[0.1, 0.2, 0.3]"}, r"\[cam_0\]\.distortions: expected shape"),
        ({"rotation": "[0.0, 0.0]"}, r"\[cam_0\]\.rotation: expected shape \(3,\)"),
        ({"translation": '"far"'}, r"\[cam_0\]\.translation: expected numbers"),
        ({"size": "[640.5, 480]"}, r"\[cam_0\]\.size: expected integers"),
        ({"name": ""}, r"\[cam_0\]: missing field 'name'"),
    ],
)
def test_rig_toml_bad_input(override, match, tmp_path):
    path = tmp_path / "rig.toml"
    path.write_text(_minimal_toml(**override))
    with pytest.raises(FileFormatError, match=match) as info:
        load_rig(path)
    assert str(path) in str(info.value)


def test_bad_files(tmp_path):
    (tmp_path / "broken.toml").write_text("[cam_0\nname = 1")
    with pytest.raises(FileFormatError, match="invalid TOML"):
        load_rig(tmp_path / "broken.toml")
    (tmp_path / "empty.toml").write_text('title = "nothing"\n')
    with pytest.raises(FileFormatError, match=r"no \[cam_<i>\] camera tables"):
        load_rig(tmp_path / "empty.toml")
    with pytest.raises(FileFormatError, match="no such file"):
        load_rig(tmp_path / "missing.toml")
    (tmp_path / "notes.csv").write_text("a,b\n")
    with pytest.raises(FileFormatError, match="unknown rig format"):
        load_rig(tmp_path / "notes.csv")
    (tmp_path / "folder").mkdir()
    with pytest.raises(FileFormatError, match="folder holds no COLMAP model"):
        load_rig(tmp_path / "folder")
    with pytest.raises(ValidationError, match="unknown rig format 'yaml'"):
        load_rig(tmp_path / "empty.toml", fmt="yaml")
    with pytest.raises(ValidationError, match="cannot tell the rig format"):
        save_rig(random_rig(), tmp_path / "rig.yaml")
    (tmp_path / "dup.toml").write_text(_minimal_toml() + _minimal_toml().replace("cam_0", "cam_1"))
    with pytest.raises(FileFormatError, match="duplicate camera names in rig: a"):
        load_rig(tmp_path / "dup.toml")


def test_non_rotation_is_rejected(tmp_path):
    rig = random_rig(4, n=2)
    save_caliscope(rig, tmp_path / "camera_array.toml")
    doc = load_toml(tmp_path / "camera_array.toml")
    doc["cameras"]["1"]["rotation"] = (2 * rig[1].R).tolist()
    save_toml(tmp_path / "camera_array.toml", doc)
    with pytest.raises(FileFormatError, match=r"\[cameras\.1\]: .*not a rotation matrix"):
        load_rig(tmp_path / "camera_array.toml")


# -- caliscope ---------------------------------------------------------------------------------
@pytest.mark.shared
@needs_shared
def test_caliscope_real_file():
    rig = load_rig(CALISCOPE / "camera_array.toml")
    assert rig.names == ["cam_0", "cam_1", "cam_2", "cam_3"]
    assert rig.sizes.tolist() == [[1280, 720]] * 4
    np.testing.assert_allclose(
        rig[0].dist[:5],
        [
            -0.3320992998866297,
            0.04641968621160267,
            -0.004295771569519648,
            0.004113240100199701,
            0.0665682301495769,
        ],
    )
    np.testing.assert_allclose(
        rig[0].t, [0.17125994082321383, -0.03234536459937444, 1.208386461814154]
    )
    # the older config.toml ([cam_N] tables among other settings) holds the same cameras
    assert_same_rig(load_caliscope(CALISCOPE / "config.toml"), rig, atol=1e-12)


@pytest.mark.shared
@needs_shared
def test_caliscope_real_projection():
    """Project caliscope's triangulated ChArUco corners and compare with its 2D detections.

    Median distance measured: 1.146 px (2175 detections, 4 cameras).
    """
    rig = load_rig(CALISCOPE / "camera_array.toml")
    folder = CALISCOPE / "calibration" / "extrinsic" / "CHARUCO"
    xy = np.genfromtxt(folder / "xy_CHARUCO.csv", delimiter=",", names=True)
    xyz = np.genfromtxt(folder / "xyz_CHARUCO.csv", delimiter=",", names=True)
    # join on (sync_index, keypoint_id) with a sorted key, vectorised
    key3 = xyz["sync_index"].astype(np.int64) * 100_000 + xyz["keypoint_id"].astype(np.int64)
    key2 = xy["sync_index"].astype(np.int64) * 100_000 + xy["keypoint_id"].astype(np.int64)
    order = np.argsort(key3)
    pos = np.searchsorted(key3, key2, sorter=order).clip(0, len(key3) - 1)
    found = key3[order[pos]] == key2
    assert found.mean() > 0.95
    point = order[pos[found]]
    cam = xy["cam_id"].astype(np.int64)[found]
    X = np.stack([xyz["x_coord"], xyz["y_coord"], xyz["z_coord"]], axis=1)
    proj = rig.project(X)
    obs = np.stack([xy["img_loc_x"], xy["img_loc_y"]], axis=1)[found]
    err = np.linalg.norm(proj.pixels[cam, point] - obs, axis=1)
    assert len(err) > 2000
    assert proj.in_image[cam, point].all()
    assert np.median(err) < 1.5, f"median reprojection distance {np.median(err):.3f} px"


def test_caliscope_ignore_and_intrinsic_only(tmp_path, caplog):
    rig = random_rig(5, n=3)
    save_caliscope(rig, tmp_path / "camera_array.toml")
    text = (tmp_path / "camera_array.toml").read_text()
    text = text.replace(
        "[cameras.1]\ncam_id = 1\nrotation_count = 0\nignore = false",
        "[cameras.1]\ncam_id = 1\nrotation_count = 0\nignore = true",
    )
    (tmp_path / "camera_array.toml").write_text(text)
    with caplog.at_level(logging.WARNING, logger="pointtraj.rigio.caliscope"):
        loaded = load_rig(tmp_path / "camera_array.toml")
    assert loaded.names == ["cam_0", "cam_2"]
    assert "skipping camera 1 marked ignore = true" in caplog.text
    assert_same_rig(loaded, rig.subset(["cam_0", "cam_2"]))
    # a config.toml after intrinsic calibration only: no rotation yet
    (tmp_path / "config.toml").write_text(
        "[cam_0]\ncam_id = 0\nsize = [640, 480]\n"
        "matrix = [[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]]\n"
        "distortions = [0.0, 0.0, 0.0, 0.0, 0.0]\nrotation_count = 0\n"
    )
    with pytest.raises(FileFormatError, match=r"config.toml: \[cam_0\]: missing field 'rotation'"):
        load_rig(tmp_path / "config.toml")


def test_caliscope_names_without_ids(tmp_path):
    rig = CameraRig([c.with_name(n) for c, n in zip(random_rig(6, n=2), ["left", "right"])])
    save_caliscope(rig, tmp_path / "camera_array.toml")
    back = load_caliscope(tmp_path / "camera_array.toml")
    assert back.names == ["cam_0", "cam_1"]
    np.testing.assert_allclose(back.P, rig.P, atol=1e-9)


# -- COLMAP ------------------------------------------------------------------------------------
COLMAP_PARAMS = {
    "SIMPLE_PINHOLE": [800.0, 330.0, 250.0],
    "PINHOLE": [800.0, 780.0, 330.0, 250.0],
    "SIMPLE_RADIAL": [800.0, 330.0, 250.0, -0.1],
    "RADIAL": [800.0, 330.0, 250.0, -0.1, 0.02],
    "OPENCV": [800.0, 780.0, 330.0, 250.0, -0.1, 0.02, 0.001, -0.002],
    "FULL_OPENCV": [800.0, 780.0, 330.0, 250.0, -0.1, 0.02, 0.001, -0.002, 0.01, 0.05, 0.01, 0.002],
}


@pytest.mark.parametrize("model", sorted(COLMAP_PARAMS))
def test_colmap_models_project_like_pycolmap(model, tmp_path):
    """Our projection of a COLMAP camera equals pycolmap's, shifted by COLMAP's half pixel."""
    import pycolmap

    rng = np.random.default_rng(7)
    rec = pycolmap.Reconstruction()
    cam = pycolmap.Camera.create_from_model_name(1, model, 1.0, 640, 480)
    cam.params = COLMAP_PARAMS[model]
    rec.add_camera_with_trivial_rig(cam)
    rvec = rng.normal(size=3)
    t = rng.normal(size=3)
    from pointtraj.camera import rotation_from_rodrigues

    R = rotation_from_rodrigues(rvec)
    image = pycolmap.Image(name="views/front.png", camera_id=1, image_id=1)
    rec.add_image_with_trivial_frame(image, pycolmap.Rigid3d(pycolmap.Rotation3d(R), t))
    rec.write(str(tmp_path))
    rig = load_rig(tmp_path)
    assert rig.names == ["front"]
    X_cam = np.c_[rng.uniform(-0.3, 0.3, size=(50, 2)), np.ones(50)] * rng.uniform(1, 5, (50, 1))
    X = (X_cam - t) @ R  # world points: R^T (x_cam - t)
    ref = cam.img_from_cam(X_cam) - 0.5
    np.testing.assert_allclose(rig.project(X).pixels[0], ref, atol=1e-8)


def test_colmap_text_and_project_folder(tmp_path):
    rig = random_rig(8, n=3)
    save_colmap(rig, tmp_path / "proj" / "sparse" / "0", text=True)
    assert (tmp_path / "proj" / "sparse" / "0" / "cameras.txt").is_file()
    assert_same_rig(load_rig(tmp_path / "proj"), rig)  # finds sparse/0


def test_colmap_unsupported_model(tmp_path):
    import pycolmap

    rec = pycolmap.Reconstruction()
    cam = pycolmap.Camera.create_from_model_name(1, "OPENCV_FISHEYE", 500.0, 640, 480)
    rec.add_camera_with_trivial_rig(cam)
    image = pycolmap.Image(name="a.jpg", camera_id=1, image_id=1)
    rec.add_image_with_trivial_frame(image, pycolmap.Rigid3d())
    rec.write(str(tmp_path))
    with pytest.raises(FileFormatError, match="camera model OPENCV_FISHEYE is not supported"):
        load_colmap(tmp_path)


def test_colmap_rejects_skew(tmp_path):
    cam = random_rig(9, n=1)[0]
    K = cam.K.copy()
    K[0, 1] = 2.0
    skewed = CameraRig([Camera(cam.name, K, cam.R, cam.C, cam.size, cam.dist)])
    with pytest.raises(ValidationError, match="skew"):
        save_colmap(skewed, tmp_path / "m")


# -- Panoptic ----------------------------------------------------------------------------------
def test_panoptic_units_and_types(tmp_path):
    R = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    entry = {
        "name": "00_00",
        "type": "hd",
        "resolution": [1920, 1080],
        "panel": 0,
        "node": 0,
        "K": [[1400.0, 0.0, 960.0], [0.0, 1400.0, 540.0], [0.0, 0.0, 1.0]],
        "distCoef": [-0.2, 0.1, 0.0, 0.0, 0.0],
        "R": R.tolist(),
        "t": [[10.0], [-20.0], [300.0]],
    }
    vga = {**entry, "name": "01_01", "type": "vga", "resolution": [640, 480]}
    path = tmp_path / "calibration_seq.json"
    path.write_text(json.dumps({"calibDataSource": "x", "cameras": [entry, vga]}))
    rig = load_rig(path)
    assert rig.names == ["00_00", "01_01"]
    np.testing.assert_allclose(rig[0].t, [0.1, -0.2, 3.0])  # centimetres -> metres
    np.testing.assert_allclose(rig[0].C, -R.T @ [0.1, -0.2, 3.0])
    assert load_panoptic(path, camera_types=["vga"]).names == ["01_01"]
    bad = {**entry, "R": [[1.0, 0.0], [0.0, 1.0]]}
    path.write_text(json.dumps({"cameras": [bad]}))
    with pytest.raises(
        FileFormatError, match=r"cameras\[0\] \(00_00\)\.R: expected shape \(3, 3\)"
    ):
        load_rig(path)
    path.write_text(json.dumps({"cameras": [{k: v for k, v in entry.items() if k != "K"}]}))
    with pytest.raises(FileFormatError, match=r"missing field 'K'"):
        load_rig(path)
    path.write_text("{not json")
    with pytest.raises(FileFormatError, match="not valid JSON"):
        load_rig(path)


# -- Qualisys ----------------------------------------------------------------------------------
QCA_CAMERA = """<camera active="1" avg-residual="0.4" model="none" serial="{serial}" viewrotation="0">
  <fov_video bottom="1023" left="{left}" right="{right}" top="0"/>
  <transform r11="1" r12="0" r13="0" r21="0" r22="0" r23="1" r31="0" r32="-1" r33="0"
             x="0" y="-3000" z="1000"/>
  <intrinsic centerPointU="{cu}" centerPointV="32768" focalLengthU="64000" focalLengthV="64064"
   radialDistortion1="-3.2" radialDistortion2="0.64" radialDistortion3="0"
   tangentalDistortion1="0.064" tangentalDistortion2="0" skew="0"/>
</camera>"""


def test_qualisys_conventions(tmp_path):
    """A hand-written camera at (0, -3, 1) m looking along +y, with a cropped video window."""
    cams = QCA_CAMERA.format(serial="A", left=100, right=1379, cu=(100 + 640) * 64)
    path = tmp_path / "calib.qca.txt"
    path.write_text(f"<?xml version='1.0'?>\n<calibration><cameras>{cams}</cameras></calibration>")
    assert detect_format(path) == "qualisys"
    rig = load_rig(path)
    cam = rig["A"]
    assert cam.size == (1280, 1024)
    np.testing.assert_allclose(np.diag(cam.K), [1000.0, 1001.0, 1.0])
    np.testing.assert_allclose(cam.K[:2, 2], [640.0, 512.0])  # relative to the video window
    np.testing.assert_allclose(cam.C, [0.0, -3.0, 1.0])  # millimetres -> metres
    np.testing.assert_allclose(cam.dist[:5], [-0.05, 0.01, 0.001, 0.0, 0.0])  # / 64, as Pose2Sim
    np.testing.assert_allclose(cam.viewing_direction, [0.0, 1.0, 0.0], atol=1e-12)
    pix, depth, inside = cam.project([[0.0, 0.0, 1.0], [0.0, 0.0, 1.5]])
    np.testing.assert_allclose(pix[0], [640.0, 512.0], atol=1e-9)
    assert depth[0] == pytest.approx(3.0) and inside.all()
    assert pix[1, 1] < 512.0  # world z up is image up
    save_qualisys(rig, tmp_path / "again.qca.txt")
    assert_same_rig(load_rig(tmp_path / "again.qca.txt"), rig)


def test_qualisys_bad_input(tmp_path):
    cams = QCA_CAMERA.format(serial="A", left=0, right=1279, cu=640 * 64).replace('r22="0" ', "")
    path = tmp_path / "calib.qca.txt"
    path.write_text(f"<calibration><cameras>{cams}</cameras></calibration>")
    with pytest.raises(FileFormatError, match=r"camera A <transform>: missing attribute 'r22'"):
        load_rig(path)
    path.write_text("<calibration><cameras></cameras></calibration>")
    with pytest.raises(FileFormatError, match="no <cameras>/<camera> elements"):
        load_qualisys(path)
    path.write_text("<calibration><cameras>")
    with pytest.raises(FileFormatError, match="not valid XML"):
        load_qualisys(path)
    with pytest.raises(ValidationError, match="k4..k6"):
        save_qualisys(random_rig(10, dist_len=8), tmp_path / "x.qca.txt")


@pytest.fixture(scope="session")
def pose2sim_qca() -> Path:
    """Pose2Sim's demo Qualisys calibration, fetched once with pip into a cache (skip offline)."""
    cache = Path(os.environ.get("POINTTRAJ_TEST_CACHE", Path.home() / ".cache" / "pointtraj-tests"))
    target = cache / "pose2sim-0.10.49" / "Calib.qca.txt"
    if target.is_file():
        return target
    try:
        wheel = download_pose2sim_wheel(cache / "pose2sim-wheel")
    except ExampleNotFoundError as exc:
        pytest.skip(f"cannot download pose2sim 0.10.49 with pip (offline?): {exc}")
    with zipfile.ZipFile(wheel) as z:
        data = z.read("Pose2Sim/Demo_SinglePerson/calibration/Calib.qca.txt")
    target.parent.mkdir(parents=True, exist_ok=True)
    target.write_bytes(data)
    wheel.unlink()
    return target


def test_qualisys_pose2sim_demo(pose2sim_qca):
    """The real demo file: four portrait 1088x1920 cameras around a person at the origin."""
    rig = load_rig(pose2sim_qca)
    assert rig.names == ["cam01", "cam02", "cam03", "cam04"]
    assert rig.sizes.tolist() == [[1088, 1920]] * 4
    np.testing.assert_allclose(rig[0].K[0, 0], 107599.671875 / 64)
    np.testing.assert_allclose(rig[0].K[0, 2], 34110.316406 / 64)
    np.testing.assert_allclose(
        rig[0].C, [1.4602323709212087, -1.9091590482454608, 1.8965058524092062]
    )
    # The person stands around the origin: chest, feet and head are in every camera's image.
    body = np.array([[0.0, 0.0, 0.9], [0.0, 0.0, 0.05], [0.0, 0.0, 1.7]])
    proj = rig.project(body)
    assert proj.in_image.all() and (proj.depth > 2.0).all()
    assert np.all(proj.pixels[:, 2, 1] < proj.pixels[:, 1, 1])  # head above feet in the image


def test_qualisys_pose2sim_demo_round_trip(pose2sim_qca, tmp_path):
    rig = load_rig(pose2sim_qca)
    save_rig(rig, tmp_path / "again.qca.txt")
    assert_same_rig(load_rig(tmp_path / "again.qca.txt"), rig)


# -- CLI ---------------------------------------------------------------------------------------
def test_cli_convert_and_show(tmp_path):
    from pointtraj.cli import main

    rig = random_rig(11)
    save_rig_toml(rig, tmp_path / "rig.toml")
    runner = CliRunner()
    res = runner.invoke(
        main, ["rig", "convert", str(tmp_path / "rig.toml"), str(tmp_path / "cal.json")]
    )
    assert res.exit_code == 0, res.output
    assert "wrote 3 cameras" in res.output
    assert_same_rig(load_panoptic(tmp_path / "cal.json"), rig)
    res = runner.invoke(
        main, ["rig", "convert", str(tmp_path / "cal.json"), str(tmp_path / "m"), "--to", "colmap"]
    )
    assert res.exit_code == 0, res.output
    res = runner.invoke(main, ["rig", "show", str(tmp_path / "m")])
    assert res.exit_code == 0, res.output
    assert "colmap, 3 cameras" in res.output and "cam_2" in res.output
    assert "\nbaselines: nearest neighbour " in res.output and "\nup (" in res.output
    (tmp_path / "bad.toml").write_text(_minimal_toml(matrix=""))
    res = runner.invoke(main, ["rig", "show", str(tmp_path / "bad.toml")])
    assert res.exit_code == 1
    assert "missing field 'matrix'" in res.output and "Traceback" not in res.output


def test_aniposelib_reads_and_writes_rig_toml(tmp_path):
    """Cross-check with aniposelib itself where it is installed (it is not a dependency)."""
    cameras = pytest.importorskip(
        "aniposelib.cameras", reason="aniposelib is not installed", exc_type=ImportError
    )
    rig = random_rig(12, n=3)
    save_rig_toml(rig, tmp_path / "rig.toml")
    group = cameras.CameraGroup.load(str(tmp_path / "rig.toml"))
    X = np.random.default_rng(13).normal(size=(40, 3)) * 0.3
    proj = rig.project(X)
    ok = proj.in_image
    theirs = np.asarray(group.project(X))
    np.testing.assert_allclose(theirs[ok], proj.pixels[ok], atol=1e-6)
    group.dump(str(tmp_path / "dumped.toml"))
    assert_same_rig(load_rig_toml(tmp_path / "dumped.toml"), rig)
