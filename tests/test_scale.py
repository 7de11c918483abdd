"""The rig's length scale and the length defaults that follow it (pointtraj.scale; issue 17)."""

from __future__ import annotations

import dataclasses
import pickle

import numpy as np
import pytest

from pointtraj.affinity import AffinityConfig
from pointtraj.config import from_mapping
from pointtraj.reconstruct.config import ReconstructConfig
from pointtraj.scale import (
    HUMAN_EXTENT_M,
    REFERENCE_EXTENT_M,
    SMALL_EXTENT_M,
    SceneLength,
    scale_factor,
    scale_lengths,
    scene_scale,
)
from pointtraj.semantics.semantic_map import SemanticsConfig
from pointtraj.synth.presets import make_rig, scale_rig

#: Every length default of the reconstruction, at its human-scale value.
RECONSTRUCT_LENGTHS = {
    "occlusion_depth_m": 0.05,
    "occlusion_min_m": 0.01,
    "chunk_join_m": 0.005,
    "densify.depth_range_m": 0.08,
    "views.min_depth_range_m": 0.01,
    "views.max_depth_range_m": 0.08,
    "stitch.radius_m": 0.015,
    "survive.radius_m": 0.15,
    "survive.max_fit_m": 0.01,
}


def _get(cfg, dotted: str) -> float:
    for part in dotted.split("."):
        cfg = getattr(cfg, part)
    return cfg


def test_scale_factor_is_one_on_human_rigs_proportional_on_small_ones_and_continuous():
    assert scale_factor(HUMAN_EXTENT_M) == 1.0
    assert scale_factor(3.44) == 1.0
    assert scale_factor(0.0116) == pytest.approx(0.0116 / REFERENCE_EXTENT_M)
    assert scale_factor(SMALL_EXTENT_M) == pytest.approx(SMALL_EXTENT_M / REFERENCE_EXTENT_M)
    # no jump at either end of the interpolation, and monotone in between
    for edge in (SMALL_EXTENT_M, HUMAN_EXTENT_M):
        assert scale_factor(edge * (1 - 1e-9)) == pytest.approx(scale_factor(edge), rel=1e-6)
    xs = np.geomspace(1e-3, 5.0, 200)
    assert np.all(np.diff([scale_factor(x) for x in xs]) >= 0)


@pytest.mark.parametrize("preset", ["ring8", "tiny4", "ring12", "lab4", "paper69"])
def test_human_sized_rigs_keep_every_length_exactly(preset):
    rig = make_rig(preset)
    scale = scene_scale(rig)
    assert scale.factor == 1.0 and scale.extent_m > HUMAN_EXTENT_M
    cfg = ReconstructConfig().for_rig(rig, log=False)
    for key, value in RECONSTRUCT_LENGTHS.items():
        assert _get(cfg, key) == value, key  # bit for bit
    assert scale_lengths(AffinityConfig(), scale) == AffinityConfig()


def test_a_small_rig_scales_every_length_default_and_logs_them(caplog, monkeypatch):
    import pointtraj.scale

    # Each line is logged once per process: an earlier test may have logged these already.
    monkeypatch.setattr(pointtraj.scale, "_logged", set())
    rig = make_rig("narrow7")
    with caplog.at_level("INFO", logger="pointtraj.scale"):
        scale = scene_scale(rig, log=True)
        cfg = ReconstructConfig().for_rig(rig)
    # narrow7's common view is about 11 x 11 x 13 mm
    assert 0.009 < scale.extent_m < 0.015
    assert scale.factor == pytest.approx(scale.extent_m / REFERENCE_EXTENT_M)
    for key, value in RECONSTRUCT_LENGTHS.items():
        assert _get(cfg, key) == pytest.approx(value * scale.factor), key
        assert isinstance(_get(cfg, key), SceneLength)
    text = caplog.text
    assert "reconstruct.densify.depth_range_m" in text and "scene scale" in text
    # Idempotent: a resolved config resolved again (a chunk's tracker) is the same.
    assert cfg.for_rig(rig, log=False) == cfg
    aff = scale_lengths(AffinityConfig(), scale)
    assert aff.epsilon == pytest.approx(0.05 * scale.factor)
    assert aff.tau == pytest.approx(0.005 * scale.factor)
    sem = scale_lengths(SemanticsConfig(), scale)
    assert sem.occlusion_depth_m == pytest.approx(0.05 * scale.factor)


def test_the_same_rig_at_a_thousandth_of_the_size_gives_a_thousandth_of_the_extent():
    rig = make_rig("ring8")
    small = scale_rig(rig, 0.001, (0.0, 0.0, 0.9))
    a, b = scene_scale(rig, log=False), scene_scale(small, log=False)
    assert b.extent_m == pytest.approx(a.extent_m * 0.001, rel=1e-6)
    assert b.factor == pytest.approx(b.extent_m / REFERENCE_EXTENT_M)


def test_a_set_value_always_wins_in_python_and_in_toml():
    rig = make_rig("narrow7")
    cfg = ReconstructConfig(occlusion_depth_m=0.05).for_rig(rig, log=False)
    assert cfg.occlusion_depth_m == 0.05 and not isinstance(cfg.occlusion_depth_m, SceneLength)
    assert cfg.occlusion_min_m < 0.001  # left out: scaled
    toml = from_mapping(
        ReconstructConfig, {"densify": {"depth_range_m": 0.08}}, where="[reconstruct]"
    )
    assert toml.for_rig(rig, log=False).densify.depth_range_m == 0.08


def test_a_set_capture_volume_gives_the_scale():
    rig = make_rig("ring8")  # human-sized cameras, but the user says the volume is 3 cm across
    scale = scene_scale(rig, [[-0.015, -0.015, 0.0], [0.015, 0.015, 0.03]], log=False)
    assert scale.source == "capture_volume"
    assert scale.extent_m == pytest.approx(0.03)
    assert scale.factor == pytest.approx(0.01)
    cfg = ReconstructConfig(capture_volume=((-0.015, -0.015, 0.0), (0.015, 0.015, 0.03))).for_rig(
        rig, log=False
    )
    assert cfg.densify.depth_range_m == pytest.approx(0.0008)


def test_scene_lengths_survive_pickling_and_replace():
    x = SceneLength(0.08 * 0.004, 0.08)
    y = pickle.loads(pickle.dumps(x))
    assert isinstance(y, SceneLength) and y == x and y.human == 0.08
    cfg = scale_lengths(ReconstructConfig(), 0.5, log=False)
    again = pickle.loads(pickle.dumps(cfg))
    assert again == cfg and again.densify.depth_range_m.human == 0.08
    # a plain dataclasses.replace keeps the others derived
    assert isinstance(dataclasses.replace(cfg, sigma_px=2.0).views.max_depth_range_m, SceneLength)
