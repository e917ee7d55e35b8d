"""Fixtures of the relight tests."""

from __future__ import annotations

import pytest

from tests.relight.relight_assets import textured_sphere, write_assets


@pytest.fixture(scope="session")
def sphere_asset_files(tmp_path_factory):
    """(glb path, obj path, TexturedMesh, per-vertex values) of the textured test sphere."""
    _, tm, vals = textured_sphere()
    glb, obj = write_assets(tmp_path_factory.mktemp("asset"), tm)
    return glb, obj, tm, vals
