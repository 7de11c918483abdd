"""The 3D error against the ground-truth surface, checked against the scene's meshes (#17)."""

from __future__ import annotations

import numpy as np
import pytest

from pointtraj.camera import Camera, CameraRig
from pointtraj.errors import FileFormatError
from pointtraj.evaluate.groundtruth import (
    SceneSurface,
    frame_surface_errors,
    smallest_eigenpairs,
    surface_distance,
)
from pointtraj.session import Capture
from pointtraj.synth.groundtruth import load_ground_truth


def _step_scene(near: float = 2.0, far: float = 2.08):
    """A camera looking down +z at two fronto-parallel planes: depth ``near`` left of column
    32, ``far`` from it on (an edge whose depths differ by under 5 %)."""
    cam = Camera.look_at("c", [0, 0, 0], [0, 0, 1], (64, 48), 380.0, up=(0, -1, 0))
    depth = np.full((48, 64), far, np.float32)
    depth[:, :32] = near
    labels = np.zeros((48, 64), np.int16)
    labels[:, 32:] = -1
    return cam, depth, labels


def test_surface_distance_does_not_take_depth_across_a_silhouette():
    """Regression (issue #17): the 3x3 window across an edge whose depths spread under 5 % was
    fitted as one plane, so a point 5 mm off the near surface got the distance to a tilted
    plane through both surfaces."""
    cam, depth, labels = _step_scene()
    rig = CameraRig([cam])
    # Points 5 mm in front of the near plane, projecting on its last column (the edge).
    pix = np.array([[31.0, 20.0], [31.0, 30.0]])
    ray = rig.normalized(pix[None])[0]  # (2, 2) x/z, y/z
    xyz = np.c_[ray, np.ones(2)] * (2.0 - 0.005)  # camera frame = world frame here
    xyz = xyz @ cam.R + cam.C
    proj = rig.project(xyz)
    assert np.allclose(proj.pixels[0], pix, atol=1e-6)
    for lm in (None, labels):  # the depth test alone suffices here; labels add to it
        err = surface_distance(cam, depth, xyz, proj.pixels[0], lm)
        assert err == pytest.approx([0.005, 0.005], abs=2e-4)
    # On a smooth surface the plane removes the sampling bias of the nearest pixel.
    flat = np.full_like(depth, 2.0)
    xyz_mid = (np.c_[rig.normalized(np.array([[[10.3, 10.4]]]))[0], [1.0]] * 1.99) @ cam.R + cam.C
    e = surface_distance(cam, flat, xyz_mid, rig.project(xyz_mid).pixels[0])
    assert e == pytest.approx([0.01], abs=1e-4)


def test_closed_form_eigenpairs_match_lapack():
    """The plane fit's closed-form 3x3 eigen-solver against numpy's LAPACK ``eigh``: scatter
    matrices of 3x3 windows on planes (one eigenvalue near 0), on lines (two), isotropic
    blobs, and the degenerate zero matrix."""
    rng = np.random.default_rng(3)
    S = 4000
    pts = rng.normal(size=(S, 9, 3)) * rng.uniform(1e-4, 1e-2, (S, 1, 3))  # anisotropic blobs
    basis = np.linalg.qr(rng.normal(size=(S, 3, 3)))[0]
    pts = pts @ basis  # random orientation
    pts[: S // 4, :, 2] = 0.0  # planar before the rotation...
    pts[: S // 4] = pts[: S // 4] @ basis[: S // 4]  # ...then rotated again
    pts[S // 4 : S // 2, :, 1:] = 0.0  # on a line
    pts[S // 2 : S // 2 + 10] = 0.0  # the zero matrix
    q = pts - pts.mean(axis=1, keepdims=True)
    A = np.einsum("ski,skj->sij", q, q)
    values, vector = smallest_eigenpairs(
        A[:, 0, 0], A[:, 1, 1], A[:, 2, 2], A[:, 0, 1], A[:, 1, 2], A[:, 0, 2]
    )
    ref_values, ref_vectors = np.linalg.eigh(A)
    scale = ref_values[:, 2:] + 1e-300
    # relative to the largest: a double root (a line) is found to about sqrt(eps), far finer
    # than the flatness test's 1 %
    assert np.allclose(values / scale, ref_values / scale, atol=1e-7)
    assert np.all(np.diff(values, axis=1) >= 0)
    # where the smallest eigenvalue is simple, the vectors agree up to sign
    simple = ref_values[:, 1] - ref_values[:, 0] > 1e-6 * ref_values[:, 2]
    assert simple.sum() > S // 2
    dot = np.abs(np.einsum("si,si->s", vector[simple], ref_vectors[simple, :, 0]))
    assert np.all(dot > 1 - 1e-6)
    # every vector is a unit eigenvector of its smallest eigenvalue (or zero for zero)
    some = np.linalg.norm(A, axis=(1, 2)) > 0
    resid = np.einsum("sij,sj->si", A, vector) - values[:, :1] * vector
    assert np.all(np.linalg.norm(resid[some], axis=1) <= 1e-8 * ref_values[some, 2])
    assert np.allclose(np.linalg.norm(vector[some], axis=1), 1.0)


def test_surface_distance_without_surface_is_nan():
    cam, depth, _ = _step_scene()
    depth[:] = np.nan
    xyz = np.array([[0.0, 0.0, 2.0]]) @ cam.R + cam.C
    assert np.isnan(surface_distance(cam, depth, xyz, CameraRig([cam]).project(xyz).pixels[0]))


def test_scene_surface_needs_a_synthetic_capture(tmp_path):
    with pytest.raises(FileFormatError, match="synth.toml: no such file"):
        SceneSurface(tmp_path)


def test_depth_map_errors_agree_with_the_scene_meshes(tiny_reference):
    """The depth-map 3D error against an independent one: the exact distance to the scene's
    posed meshes (Open3D ``RaycastingScene.compute_distance``)."""
    cap = tiny_reference / "cap"
    surface = SceneSurface(cap)
    gt = load_ground_truth(cap)
    rig = Capture.open(cap).rig
    rng = np.random.default_rng(0)
    diffs, mesh = [], []
    for t in range(gt.xyz.shape[1]):
        x = gt.xyz[:, t].astype(np.float64)
        x = x[np.isfinite(x).all(axis=1)]
        # The rebuilt scene is the rendered one: its points lie on the meshes.
        assert surface.distance(t, x).max() < 1e-4
        off = rng.normal(size=x.shape)
        moved = x + off / np.linalg.norm(off, axis=1, keepdims=True) * rng.uniform(
            0, 0.03, (len(x), 1)
        )
        d_mesh = surface.distance(t, moved)
        d_map = frame_surface_errors(cap, rig, t, moved)
        ok = np.isfinite(d_map)
        assert ok.mean() > 0.99
        diffs.append(d_map[ok] - d_mesh[ok])
        mesh.append(d_mesh[ok])
    diff = np.concatenate(diffs)
    # 12 mm pixels on this 320x256 rig and 1 mm depth steps: the two agree within 2 mm for most
    # points (measured: median |difference| 1.2 mm, 74 % within 2 mm, 1.3 % more than 3 mm
    # lower); the depth maps see only visible surfaces and sample them, so they err high.
    assert np.median(np.abs(diff)) < 0.0015
    assert np.mean(np.abs(diff) < 0.002) > 0.65
    assert np.mean(diff < -0.003) < 0.03
    assert np.percentile(np.concatenate(mesh), 90) > 0.01  # the points were moved off
