"""Settings derived from the rig: matching, densification and the capture volume
(pointtraj.reconstruct.config.ReconstructConfig.for_rig, rig_choices; issue 17)."""

from __future__ import annotations

import numpy as np
import pytest

from pointtraj.camera import Camera, CameraRig
from pointtraj.errors import FileFormatError, ValidationError
from pointtraj.reconstruct.config import ReconstructConfig, rig_choices
from pointtraj.reconstruct.densify import DensifyConfig
from pointtraj.reconstruct.matching import GMS_THRESHOLD, MatchingConfig
from pointtraj.reconstruct.track import Tracker
from pointtraj.stages import load_reconstruct_config
from pointtraj.synth.presets import make_rig


@pytest.mark.parametrize(
    "preset, guided, gms, densify, cover, window",
    [
        # the demo's 640x512 and ring12's 800x640, 44 and 35 degrees apart: densified at the
        # medium images' NCC from every point; 4 cm of the subject is 6.2-6.4 px there: 7
        ("ring8", False, GMS_THRESHOLD, (0.8, "all"), "off", 7),
        ("ring12", False, GMS_THRESHOLD, (0.8, "all"), "off", 7),
        ("tiny4", False, GMS_THRESHOLD, None, "off", 7),  # 320x256, 87 degrees apart
        ("paper69q", True, GMS_THRESHOLD, None, "on", 7),  # 320x256: small images
        ("paper69", True, GMS_THRESHOLD, (0.9, "moving"), "on", 15),  # pipelines/paper69.toml's
        # large images, not a dense rig: the lower NCC, from new and moving points
        ("lab4", True, 2.0, (0.8, "moving"), "off", 13),
        # a 4 mm scene: its window follows the scaled subject, as on its human-sized original
        ("narrow7", True, 2.0, (0.8, "moving"), "off", 21),
    ],
)
def test_for_rig_chooses_from_baselines_and_resolution(
    preset, guided, gms, densify, cover, window, caplog
):
    rig = make_rig(preset)
    with caplog.at_level("INFO", logger="pointtraj.reconstruct.config"):
        cfg = ReconstructConfig().for_rig(rig)
    assert cfg.matching.guided is guided
    assert cfg.matching.gms_threshold == gms
    assert cfg.densify.enabled is (densify is not None)
    if densify is not None:
        assert (cfg.densify.min_ncc, cfg.densify.seeds) == densify
        assert f"min_ncc {densify[0]:g} (from the rig), seeds {densify[1]}" in caplog.text
    assert cfg.cover_visible == cover
    # matching skips the features on live trajectories only where they cover every camera
    assert cfg.match_skip_px == (0.5 * cfg.cover_px if cover == "on" else 0.0)
    # ... and match the whole images every other frame there (the moving regions in between)
    assert cfg.match_every == (2 if cover == "on" else 1)
    assert cfg.lk_window == window and f"lk_window {window} (from the rig)" in caplog.text
    assert "rig-derived settings" in caplog.text and "from the rig" in caplog.text
    # `rig info` shows the same lines, taken from the same messages without logging them
    logged = [
        (r.levelno, r.getMessage())
        for r in caplog.records
        if r.name == "pointtraj.reconstruct.config"
    ]
    assert ReconstructConfig().rig_notes(rig) == logged
    # what densification does on the frames between is said where there are such frames
    between = "densification between from points moving over 4 px" in caplog.text
    assert between is (cover == "on" and densify is not None)
    # Resolved once: nothing is left to choose, nothing is logged again.
    caplog.clear()
    with caplog.at_level("INFO", logger="pointtraj.reconstruct.config"):
        assert cfg.for_rig(rig) is cfg
    assert caplog.text == ""


def test_for_rig_keeps_what_is_set(caplog):
    rig = make_rig("lab4")
    set_cfg = ReconstructConfig(
        matching=MatchingConfig(guided=False, gms_threshold=6.0),
        densify=DensifyConfig(enabled=False),
    )
    with caplog.at_level("INFO", logger="pointtraj.reconstruct.config"):
        cfg = set_cfg.for_rig(rig)
    assert cfg.matching.guided is False and cfg.matching.gms_threshold == 6.0
    assert cfg.densify.enabled is False
    assert "guided off (set)" in caplog.text and "densification off (set)" in caplog.text
    # a window set in the file is kept
    assert ReconstructConfig(lk_window=21).for_rig(make_rig("ring8")).lk_window == 21
    # densification's threshold and seeds set in the file are kept on a medium-image rig
    kept = ReconstructConfig(densify=DensifyConfig(min_ncc=0.85, seeds="new"))
    kept = kept.for_rig(make_rig("ring8")).densify
    assert kept.min_ncc == 0.85 and kept.seeds == "new"
    assert ReconstructConfig(match_skip_px=2.0).for_rig(make_rig("ring8")).match_skip_px == 2.0
    with pytest.raises(ValidationError, match="match_skip_px"):
        ReconstructConfig(match_skip_px=-1.0)
    assert ReconstructConfig(match_every=1).for_rig(make_rig("paper69")).match_every == 1
    assert ReconstructConfig(match_every=3).for_rig(make_rig("ring8")).match_every == 3
    with pytest.raises(ValidationError, match="match_every"):
        ReconstructConfig(match_every=0)


def test_rig_choices_figures():
    c = rig_choices(make_rig("paper69"))
    assert c.megapixels == pytest.approx(1.31072)
    assert c.nearest_deg == pytest.approx(10.3, abs=0.1)
    assert "1.31 MP images (large" in c.reason
    # Two pairs of cameras facing each other (Pose2Sim's demo): a pair's densified points have
    # no third camera to check them, so densification keeps the strict threshold.
    facing = CameraRig(
        [
            Camera.look_at(f"cam{i}", (3.0 * np.cos(a), 3.0 * np.sin(a), 1.5), (0, 0, 0.9),
                           (1920, 1080), 1500.0)
            for i, a in enumerate(np.radians([-25.0, 25.0, 145.0, 215.0]))
        ]
    )  # fmt: skip
    c = rig_choices(facing)
    assert c.densify and c.densify_ncc == 0.9 and "1 within 90 deg" in c.reason
    assert rig_choices(make_rig("lab4")).densify_ncc == 0.8  # 2.5 partners within 90 deg
    # A smaller feature budget (for speed) does not switch the matching mode.
    small = ReconstructConfig(matching=MatchingConfig(num_features=400))
    assert small.for_rig(make_rig("ring8")).matching.guided is False


def test_capture_volume_and_overlap_keys(tmp_path, caplog):
    path = tmp_path / "r.toml"
    path.write_text(
        "[reconstruct]\ncapture_volume = [[-0.01, -0.01, -0.01], [0.01, 0.01, 0.01]]\n"
        "min_pair_overlap = 0.5\n",
        encoding="utf-8",
    )
    cfg = load_reconstruct_config(path)
    assert cfg.capture_volume == ((-0.01, -0.01, -0.01), (0.01, 0.01, 0.01))
    assert cfg.min_pair_overlap == 0.5
    # The tracker measures the pairs' shared view in that volume: the narrow rig sees it.
    with caplog.at_level("INFO", logger="pointtraj.reconstruct.connectivity"):
        tracker = Tracker(make_rig("narrow7"), cfg)
    assert len(tracker.edges) == 18 and "(set)" in caplog.text
    # A volume that no camera sees connects nothing, and says so.
    far = ReconstructConfig(capture_volume=((5.0, 5.0, 5.0), (6.0, 6.0, 6.0)))
    with caplog.at_level("WARNING"):
        assert len(Tracker(make_rig("narrow7"), far).edges) == 0
    assert "see none of the capture volume" in caplog.text
    path.write_text("[reconstruct]\ncapture_volume = [[1, 0, 0], [0, 1, 1]]\n", encoding="utf-8")
    with pytest.raises(FileFormatError, match="capture_volume"):
        load_reconstruct_config(path)
    path.write_text("[reconstruct]\nmin_pair_overlap = 1.5\n", encoding="utf-8")
    with pytest.raises(FileFormatError, match="min_pair_overlap"):
        load_reconstruct_config(path)


def test_new_presets():
    lab = make_rig("lab4")
    assert len(lab) == 4 and all(tuple(c.size) == (1280, 720) for c in lab)
    box = np.array([[x, y, z] for x in (-0.3, 0.3) for y in (-0.3, 0.3) for z in (0.05, 1.75)])
    assert lab.project(box).in_image.all()  # the figure's volume
    narrow = make_rig("narrow7")
    assert len(narrow) == 7
    dist = np.linalg.norm(narrow.C, axis=1)
    np.testing.assert_allclose(dist, 0.118, rtol=1e-3)
    width = narrow.sizes[:, 0] / narrow.K[:, 0, 0] * dist  # seen across at the subject, metres
    assert np.all((width > 0.006) & (width < 0.008))
    subject = np.array(
        [[x, y, z] for x in (-0.0015, 0.0015) for y in (-0.0015, 0.0015) for z in (-0.0015, 0.0015)]
    )
    assert narrow.project(subject).in_image.all()  # a 3 mm cube at the origin


def test_config_file_forms(tmp_path):
    """``reconstruct --config``: a ``[reconstruct]`` table, the top level, or a pipeline file
    without the table (the defaults, as the other commands' ``--config``)."""
    path = tmp_path / "r.toml"
    path.write_text("[reconstruct]\nlk_window = 9\n[semantics]\neps_e = 0.2\n", encoding="utf-8")
    assert load_reconstruct_config(path).lk_window == 9
    path.write_text("lk_window = 11\n[densify]\nenabled = false\n", encoding="utf-8")
    cfg = load_reconstruct_config(path)
    assert cfg.lk_window == 11 and cfg.densify.enabled is False
    path.write_text(
        'name = "p"\ncapture = "cap"\nwork = "w"\n[semantics]\neps_e = 0.2\n', encoding="utf-8"
    )
    assert load_reconstruct_config(path) == ReconstructConfig()
    path.write_text("lk_windw = 9\n", encoding="utf-8")  # a misspelt key is named
    with pytest.raises(FileFormatError, match="lk_windw"):
        load_reconstruct_config(path)
