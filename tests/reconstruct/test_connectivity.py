"""Tests of the camera connectivity graph (pointtraj.reconstruct.connectivity)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from helpers.rigs import ring_rig

from pointtraj.camera import Camera, CameraRig
from pointtraj.errors import FileFormatError, ValidationError
from pointtraj.reconstruct.connectivity import (
    ConnectivityGraph,
    build_connectivity,
    common_view,
    confirm_connectivity,
    estimate_capture_volume,
    working_depths,
)
from pointtraj.synth.presets import make_rig


def test_build_connectivity_angles_and_degrees():
    rig = ring_rig(12)  # neighbours every 30 degrees
    g = build_connectivity(rig, max_angle_deg=90.0)
    assert g.camera_names == rig.names
    assert g.edges.dtype == np.int64 and g.edges.shape == (g.num_edges, 2)
    assert np.all(g.edges[:, 0] < g.edges[:, 1])
    # Pairs up to 90 degrees apart: 3 steps either way, so degree 6 and 36 edges.
    np.testing.assert_array_equal(g.degree(), np.full(12, 6))
    assert g.num_edges == 36
    assert np.all(g.angles_deg <= 90.0 + 1e-9)
    np.testing.assert_allclose(np.sort(np.unique(np.round(g.angles_deg, 6))), [30, 60, 90])
    assert g.overlap is not None and np.all(g.overlap >= 0.05)
    # A tighter angle keeps only the nearest neighbours.
    g30 = build_connectivity(rig, max_angle_deg=45.0)
    assert g30.num_edges == 12
    np.testing.assert_array_equal(g30.neighbors("c0"), [1, 11])
    assert set(g30.pairs()) <= set(g.pairs())
    A = g.adjacency()
    assert A.shape == (12, 12) and np.array_equal(A, A.T) and not A.diagonal().any()


def test_build_connectivity_shared_view_check():
    rig = ring_rig(8, outward=(0,))  # camera 0 looks away from the capture volume
    g = build_connectivity(rig, max_angle_deg=180.0, min_overlap=0.05)
    assert g.degree()[0] == 0
    assert "isolated cameras" in g.summary() and "c0" in g.summary()
    # Without the overlap check the angle alone would connect camera 0 to its neighbours.
    g0 = build_connectivity(rig, max_angle_deg=180.0, min_overlap=0.0)
    assert g0.degree()[0] > 0
    # An explicit volume outside every view connects nothing.
    far = np.array([[50.0, 50.0, 50.0], [51.0, 51.0, 51.0]])
    assert build_connectivity(rig, volume=far).num_edges == 0


def test_estimate_capture_volume_ring():
    """A ring aimed at its centre: the common view is centred there and reaches about 1.5 times
    the working distance (the radius) from each camera, and it scales with the rig."""
    rig = ring_rig(8, radius=3.0)
    np.testing.assert_allclose(working_depths(rig), 3.0, rtol=1e-9)
    view = common_view(rig)
    assert view.min_cameras == 3 and view.samples > 1000
    np.testing.assert_allclose(view.box.mean(axis=0)[:2], [0.0, 0.0], atol=0.15)
    size = view.box[1] - view.box[0]
    assert np.all(size[:2] > 2.5) and np.all(size[:2] < 5.0)  # within the ring and its fields
    assert np.all(view.box[0] < [0, 0, 1]) and np.all(view.box[1] > [0, 0, 1])  # the target
    assert 0 < view.volume_m3 < np.prod(size)
    np.testing.assert_array_equal(estimate_capture_volume(rig), view.box)
    # The same rig at a thousandth of the size: the same region at a thousandth of the size.
    small = ring_rig(8, radius=0.003, target=(0.0, 0.0, 0.001), heights=(0.001,))
    np.testing.assert_allclose(common_view(small).box, view.box / 1000, rtol=1e-6, atol=1e-9)
    assert "mm" in common_view(small).summary() and " m " in view.summary()


def test_estimate_capture_volume_parallel_axes():
    """A row of cameras looking the same way: the volume lies in front of the row."""
    cams = [
        Camera.look_at(f"p{i}", [0.5 * i, 0.0, 1.0], [0.5 * i, 5.0, 1.0], (640, 480), 500.0)
        for i in range(4)
    ]
    rig = CameraRig(cams)
    box = estimate_capture_volume(rig)
    center = box.mean(axis=0)
    assert center[1] > 0.5 and np.all(box[1] > box[0])
    g = build_connectivity(rig)
    assert g.num_edges == 6 and np.allclose(g.angles_deg, 0.0, atol=1e-4)


def test_build_connectivity_bad_arguments():
    rig = ring_rig(4)
    with pytest.raises(ValueError, match="max_angle_deg"):
        build_connectivity(rig, max_angle_deg=200)
    with pytest.raises(ValueError, match="min_overlap"):
        build_connectivity(rig, min_overlap=1.5)
    with pytest.raises(ValueError, match="volume"):
        build_connectivity(rig, volume=np.array([[1.0, 1, 1], [0, 0, 0]]))
    with pytest.raises(ValueError, match="edges"):
        ConnectivityGraph(["a", "b"], np.array([[1, 0]]), np.array([10.0]))


def test_confirm_connectivity_edge_and_matrix_counts():
    g = build_connectivity(ring_rig(8))
    E = g.num_edges
    counts = np.arange(E) * 10
    kept = confirm_connectivity(g, counts, min_matches=50)
    assert kept.num_edges == int(np.sum(counts >= 50))
    assert np.all(kept.match_counts >= 50)
    assert kept.overlap.shape == (kept.num_edges,)
    # The same counts as a camera matrix, filled in the lower triangle only.
    M = np.zeros((8, 8), int)
    M[g.edges[:, 1], g.edges[:, 0]] = counts
    kept2 = confirm_connectivity(g, M, min_matches=50)
    np.testing.assert_array_equal(kept2.edges, kept.edges)
    np.testing.assert_array_equal(kept2.match_counts, kept.match_counts)
    with pytest.raises(ValidationError, match="counts"):
        confirm_connectivity(g, np.zeros(E + 1), 1)
    with pytest.raises(ValidationError, match=">= 0"):
        confirm_connectivity(g, -np.ones(E), 1)
    assert "confirming matches" in kept.summary()


def test_save_load_round_trip(tmp_path):
    g = build_connectivity(ring_rig(6))
    g = confirm_connectivity(g, np.full(g.num_edges, 7), min_matches=1)
    path = tmp_path / "sub" / "connectivity.json"
    g.save(path)
    data = json.loads(path.read_text())
    assert data["format"] == "pointtraj-connectivity" and data["version"] == 1
    h = ConnectivityGraph.load(path)
    assert h.camera_names == g.camera_names
    for name in ("edges", "angles_deg", "match_counts", "overlap", "centers", "directions"):
        np.testing.assert_array_equal(getattr(h, name), getattr(g, name))
    assert h.summary() == g.summary()


def test_load_errors(tmp_path):
    with pytest.raises(FileFormatError, match="not found"):
        ConnectivityGraph.load(tmp_path / "missing.json")
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(FileFormatError, match="bad.json: not a readable JSON"):
        ConnectivityGraph.load(bad)
    bad.write_text(json.dumps({"format": "something-else"}))
    with pytest.raises(FileFormatError, match="format"):
        ConnectivityGraph.load(bad)
    good = build_connectivity(ring_rig(4)).to_dict()
    del good["edges"]
    bad.write_text(json.dumps(good))
    with pytest.raises(FileFormatError, match="missing field 'edges'"):
        ConnectivityGraph.load(bad)
    good = build_connectivity(ring_rig(4)).to_dict()
    good["edges"] = [[0, 9]]
    good["angles_deg"] = [1.0]
    bad.write_text(json.dumps(good))
    with pytest.raises(FileFormatError, match="edges"):
        ConnectivityGraph.load(bad)


def test_plot_writes_png(tmp_path):
    import matplotlib.image

    g = build_connectivity(ring_rig(8))
    out = tmp_path / "graph.png"
    g.plot(out)
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    img = matplotlib.image.imread(out)
    assert img.ndim == 3 and img.shape[0] > 100
    bare = ConnectivityGraph(g.camera_names, g.edges, g.angles_deg)
    with pytest.raises(ValidationError, match="pass the rig"):
        bare.plot(tmp_path / "x.png")
    bare.plot(tmp_path / "y.png", rig=ring_rig(8))
    assert (tmp_path / "y.png").exists()


def test_summary_text():
    g = build_connectivity(ring_rig(12))
    text = g.summary()
    assert "12 cameras, 36 edges" in text
    assert "degree min 6, mean 6.0, max 6" in text
    assert len(text.splitlines()) == 12 + 4


def _wide_volume_rule_pairs(rig: CameraRig) -> int:
    """The pairs the earlier rule kept: a cube of half the median camera distance around the
    point nearest the optical axes, and a fixed shared-view cut-off of 0.05."""
    d = rig.R[:, 2]
    proj = np.eye(3) - d[:, :, None] * d[:, None, :]
    center = np.linalg.solve(proj.sum(axis=0), np.einsum("cij,cj->i", proj, rig.C))
    half = 0.5 * float(np.median(np.linalg.norm(rig.C - center, axis=1)))
    box = np.stack([center - half, center + half])
    g = build_connectivity(rig, min_overlap=0.0, volume=box)  # every pair within 90 degrees
    return int(np.sum(g.overlap >= 0.05))


def _room_sized(rig: CameraRig, scale: float, focal: float) -> CameraRig:
    """The same camera layout ``scale`` times larger, with wide fields of view."""
    return CameraRig(
        [Camera.look_at(c.name, scale * c.C, [0.0, 0.0, 0.0], tuple(c.size), focal) for c in rig]
    )


def test_narrow_field_rig_keeps_its_pairs(caplog):
    """Issue 17's narrow-field rig: 7 cameras with a 3.4 degree field of view, 11.8 cm from a
    subject a few mm across. The defaults keep at least 80 % of the pairs that the earlier
    wide-volume rule keeps on the same layout at room size with wide fields of view; that rule
    on the narrow rig itself keeps almost none (the finding: 1 of 21)."""
    narrow = make_rig("narrow7")
    room = _room_sized(narrow, 2.4 / 0.118, 640.0 / np.tan(np.radians(40.0)))  # 80 deg FOV
    reference = _wide_volume_rule_pairs(room)
    assert reference >= 15  # of 21; the 3 opposite pairs are 100 degrees apart
    assert _wide_volume_rule_pairs(narrow) <= 0.2 * reference  # the finding reproduced
    with caplog.at_level("INFO", logger="pointtraj.reconstruct.connectivity"):
        g = build_connectivity(narrow)
    assert g.num_edges >= 0.8 * reference
    assert "most of the rig is unused" not in caplog.text
    assert "mm" in common_view(narrow).summary()  # the volume in the rig's scale
    # The same rig forced into the earlier volume: the relative cut-off still keeps most
    # pairs (the fixed one kept none), and a warning says the volume is too large.
    caplog.clear()
    box = np.array([[-0.059] * 3, [0.059] * 3])  # the +-5.8 cm cube of the finding
    with caplog.at_level("WARNING", logger="pointtraj.reconstruct.connectivity"):
        forced = build_connectivity(narrow, volume=box)
    assert forced.num_edges >= 0.8 * reference
    assert "share little of the capture volume" in caplog.text and "capture_volume" in caplog.text


def test_most_of_the_rig_unused_warns(caplog):
    rig = ring_rig(8, outward=(0, 1, 2, 3, 4))  # five cameras look away from the volume
    with caplog.at_level("WARNING", logger="pointtraj.reconstruct.connectivity"):
        g = build_connectivity(rig)
    assert g.num_edges <= 3
    assert "most of the rig is unused" in caplog.text
    assert "see none of the capture volume" in caplog.text or "shared view" in caplog.text


def test_dropped_pairs_are_logged_with_their_reason(caplog):
    rig = ring_rig(8)
    with caplog.at_level("WARNING", logger="pointtraj.reconstruct.connectivity"):
        g = build_connectivity(rig, max_angle_deg=90.0)
    assert g.num_edges == 16
    assert "12 of 28 camera pairs not matched" in caplog.text
    assert "max_angle_deg = 90" in caplog.text and "c0-c3 (135 deg" in caplog.text
    assert "most of the rig is unused" not in caplog.text


def test_presets_edges_unchanged_by_the_relative_cut_off():
    """The relative cut-off keeps the demo's and paper69's pairs (as the fixed 0.05 did)."""
    for name, pairs in (("ring8", 16), ("tiny4", 4), ("ring12", 36), ("paper69", 1266)):
        assert build_connectivity(make_rig(name)).num_edges == pairs, name
