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
