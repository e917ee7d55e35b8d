"""Fixtures of the viewer tests."""

from __future__ import annotations

import pytest

from tests.fixtures.assets import textured_sphere, write_assets


@pytest.fixture(scope="session")
def viewer_glb(tmp_path_factory):
    """model.glb of the textured test sphere (albedo from position, metallic / roughness
    ramps), written with voxnero.asset."""
    _, tm, _ = textured_sphere()
    glb, _ = write_assets(tmp_path_factory.mktemp("viewer_asset"), tm)
    return glb
