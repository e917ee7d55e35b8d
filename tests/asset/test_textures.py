"""UV atlas + baking: texture lookups at the exported uvs give back the per-vertex values."""

from __future__ import annotations

import numpy as np


def _sample(tex, uv):
    """Nearest texel at glTF uvs (origin top-left, v down)."""
    S = tex.shape[0]
    r = np.clip((uv[:, 1] * S).astype(int), 0, S - 1)
    c = np.clip((uv[:, 0] * S).astype(int), 0, S - 1)
    return tex[r, c]


def test_baked_textures_reproduce_vertex_values(sphere_textured):
    mesh, tm = sphere_textured
    centre = np.array([0.1, 0.2, 0.3])
    v = tm.positions - centre
    # the texel under each (split) vertex holds that vertex's values (up to texel blending)
    assert np.abs(_sample(tm.albedo, tm.uvs) - np.clip(v + 0.5, 0, 1)).mean() < 0.01
    assert np.abs(_sample(tm.metallic, tm.uvs) - (v[:, 0] + 0.5)).mean() < 0.01
    assert np.abs(_sample(tm.roughness, tm.uvs) - (v[:, 2] + 0.5)).mean() < 0.01


def test_split_mesh_is_the_same_surface(sphere_textured):
    mesh, tm = sphere_textured
    assert tm.indices.shape == (len(mesh.triangles), 3)
    assert tm.indices.max() < tm.positions.shape[0]
    # every split vertex is an original vertex; triangles keep their corner positions
    orig = np.asarray(mesh.vertices)[np.asarray(mesh.triangles)]
    assert np.allclose(tm.positions[tm.indices.astype(int)], orig, atol=1e-6)
    assert np.allclose(np.linalg.norm(tm.normals, axis=1), 1, atol=1e-5)
    assert (tm.uvs >= 0).all() and (tm.uvs <= 1).all()
