"""Rigs that several reconstruction test modules share (cameras and rigs are immutable)."""

from __future__ import annotations

import pytest
from helpers.rigs import plane_rig

from pointtraj.camera import CameraRig


@pytest.fixture(scope="session")
def narrow_rig() -> CameraRig:
    """Three 480x360 cameras 15 degrees apart (f = 400 px) facing the plane z = 0."""
    return plane_rig(3)


@pytest.fixture(scope="session")
def wide_rig() -> CameraRig:
    """Three 480x360 cameras 35 degrees apart (f = 400 px) facing the plane z = 0."""
    return plane_rig(angles=(-35.0, 0.0, 35.0))
