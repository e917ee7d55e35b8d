"""A small textured sphere shared by the export tests (baked once per session)."""

from __future__ import annotations

import numpy as np
import open3d as o3d
import pytest

from tests.fixtures.assets import sphere_asset_files  # noqa: F401 (a fixture)
from voxnero.asset.textures import bake_textures


@pytest.fixture(scope="session")
def sphere_textured():
    """Sphere r = 0.5 at (0.1, 0.2, 0.3) with albedo = position-derived colour, metallic = x ramp,
    roughness = z ramp (per vertex), baked at 128 px. Returns (legacy mesh, TexturedMesh)."""
    m = o3d.geometry.TriangleMesh.create_sphere(0.5, 24).translate([0.1, 0.2, 0.3])
    m.compute_vertex_normals()
    v = np.asarray(m.vertices) - [0.1, 0.2, 0.3]
    albedo = np.clip(v + 0.5, 0, 1)
    metallic = np.clip(v[:, 0] + 0.5, 0, 1)
    rough = np.clip(v[:, 2] + 0.5, 0, 1)
    return m, bake_textures(m, albedo, metallic, rough, size=128)
