"""Rig analysis: camera counts and pixel densities per voxel."""

from __future__ import annotations

import functools

import numpy as np
import pytest
from helpers.rigs import ring_rig

from pointtraj.camera import Camera, CameraRig
from pointtraj.errors import ValidationError
from pointtraj.rig_analysis import CaptureVolume, analyze_rig, plot_coverage

#: ``n`` cameras (320x256, f = 300 px by default) on a ring of radius 2 m at height 1.2 m.
ring = functools.partial(
    ring_rig, radius=2.0, size=(320, 256), focal=300.0, heights=(1.2,), target=(0, 0, 1.2)
)


def test_counts_match_per_camera_projection():
    rig = ring(4)
    vol = CaptureVolume(radius=1.0, height=2.0)
    cov = analyze_rig(rig, vol, voxel=0.2)
    pts, idx, _ = vol.grid(0.2)
    expected = np.stack([cam.project(pts)[2] for cam in rig]).sum(axis=0)
    np.testing.assert_array_equal(cov.count[idx[:, 0], idx[:, 1], idx[:, 2]], expected)
    # Outside the cylinder is marked -1 / NaN.
    outside = cov.count < 0
    assert outside.any() and np.all(np.isnan(cov.density[outside]))


def test_density_of_a_single_camera_is_f2_over_d2():
    cam = Camera.look_at("c", [0, -2.0, 1.0], [0, 0, 1.0], (320, 256), 400.0)
    vol = CaptureVolume(center=(0, 0, 0.9), radius=None, height=0.2, half_extent=(0.1, 0.1))
    cov = analyze_rig(CameraRig([cam]), vol, voxel=0.2)
    assert cov.density.shape == (1, 1, 1)
    # Voxel centre (0, 0, 1.0) is 2 m away on the optical axis: 400² * 1e-4 / 4 = 4 px per cm².
    assert cov.density[0, 0, 0] == pytest.approx(4.0, rel=1e-9)
    assert cov.density_max[0, 0, 0] == pytest.approx(4.0, rel=1e-9)


def test_global_density_scales_with_pixel_count(tmp_path):
    vol = CaptureVolume(radius=1.0, height=2.0)
    low = analyze_rig(ring(6, size=(160, 128), focal=150.0), vol, voxel=0.25).global_density
    high = analyze_rig(ring(6, size=(320, 256), focal=300.0), vol, voxel=0.25).global_density
    assert high == pytest.approx(4 * low, rel=0.05)
    cov = analyze_rig(ring(6), vol, voxel=0.25)
    s = cov.summary()
    assert 0 < s["fraction_seen_by_5"] <= s["fraction_seen_by_2"] <= 1
    assert s["cameras_centre"] == 6
    plot_coverage(cov, tmp_path / "cov.png", ring(6))
    assert (tmp_path / "cov.png").stat().st_size > 1000


def test_bad_voxel_size():
    with pytest.raises(ValidationError, match="voxel size"):
        analyze_rig(ring(2), voxel=0.0)


def test_a_centimetre_rig_gives_the_scaled_figures_in_small_units():
    """Regression: ``rig info`` printed "capture volume 0.00 m^3, voxel 0 cm" for a small rig,
    and its mean density sampled rays every 5 cm over 0-8 m, missing a small volume (0 px).
    A rig and volume scaled by 0.01 give the same counts, densities x 1e4 (per area) and x 1e6
    (per volume), printed in cm^3 / mm and px/mm."""
    big_rig = ring(6)
    small_rig = CameraRig([Camera(c.name, c.K, c.R, 0.01 * c.C, c.size, c.dist) for c in big_rig])
    big = analyze_rig(big_rig, CaptureVolume(radius=1.0, height=2.0), voxel=0.25)
    small = analyze_rig(small_rig, CaptureVolume(radius=0.01, height=0.02), voxel=0.0025)
    np.testing.assert_array_equal(small.count, big.count)
    np.testing.assert_allclose(small.density_max, 1e4 * big.density_max, rtol=1e-6)
    assert small.global_density == pytest.approx(1e6 * big.global_density, rel=0.05)
    assert big.global_density > 0
    text = small.report()
    assert "capture volume 6.28 cm^3, voxel 2.5 mm" in text
    assert "px/mm^3" in text and "px/mm^2" in text and "0.6 px/mm^2" in text
    head = big.report().splitlines()
    assert head[0] == "capture volume 6.28 m^3, voxel 25 cm"
    # The centre figure is an area density; the paper's "> 60" is pixels seeing a 1 cm cube.
    assert "px/cm^2  (paper: > 60 pixels seeing a 1 cm cube" in head[2]
    assert "(paper: > 60 px/cm^3)" not in big.report()


def test_rig_info_prints_the_common_view(tmp_path):
    """`rig info` gives the capture volume the reconstruction uses, in the rig's scale."""
    from click.testing import CliRunner

    from pointtraj.cli import main
    from pointtraj.rigio import save_rig
    from pointtraj.synth.presets import make_rig

    save_rig(make_rig("narrow7"), tmp_path / "narrow.toml")
    res = CliRunner().invoke(main, ["rig", "info", str(tmp_path / "narrow.toml")])
    assert res.exit_code == 0, res.output
    line = next(x for x in res.output.splitlines() if x.startswith("common view"))
    assert "seen by >= 2 cameras" in line and " mm " in line and "mm^3" in line
    # ... and what the reconstruction's defaults choose for it, before any run
    line = next(x for x in res.output.splitlines() if x.startswith("reconstruction: "))
    assert "rig-derived settings: 7 cameras" in line and "min_ncc 0.8 (from the rig)" in line
    save_rig(make_rig("lab4"), tmp_path / "lab4.toml")
    res = CliRunner().invoke(main, ["rig", "info", str(tmp_path / "lab4.toml")])
    assert res.exit_code == 0, res.output
    warned = [x for x in res.output.splitlines() if x.startswith("reconstruction, warning: ")]
    assert len(warned) == 1 and "the rig has 4 cameras (fewer than 6)" in warned[0]
