"""model.obj + .mtl + textures reload in Open3D with the same surface and uvs."""

from __future__ import annotations

import numpy as np
import open3d as o3d
from PIL import Image

from voxnero.asset.obj import write_obj


def test_obj_roundtrip(tmp_path, sphere_textured):
    _, tm = sphere_textured
    path = write_obj(tmp_path / "model.obj", tm)
    mtl = (tmp_path / "model.mtl").read_text()
    for key in ("map_Kd model_albedo.png", "map_Pr model_roughness.png",
                "map_Pm model_metallic.png"):
        assert key in mtl
    mesh = o3d.io.read_triangle_mesh(str(path), enable_post_processing=True)
    assert len(mesh.triangles) == tm.indices.shape[0]
    tri = np.asarray(mesh.triangles)
    v = np.asarray(mesh.vertices)[tri]
    assert np.allclose(v, tm.positions[tm.indices.astype(int)], atol=1e-5)
    # OBJ (and Open3D) texture coordinates have v up: vt = (u, 1 - v_glTF)
    uv = np.asarray(mesh.triangle_uvs).reshape(-1, 3, 2)
    want = tm.uvs[tm.indices.astype(int)].copy()
    want[..., 1] = 1 - want[..., 1]
    assert np.allclose(uv, want, atol=1e-5)
    assert mesh.has_textures()
    rough = np.asarray(Image.open(tmp_path / "model_roughness.png"))
    assert np.abs(rough / 255.0 - tm.roughness).max() <= 0.5 / 255 + 1e-6
