"""Small assets shared by the relight and viewer tests (built with voxnero.export)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import open3d as o3d

from voxnero.export.gltf import write_glb
from voxnero.export.obj import write_obj
from voxnero.export.textures import TexturedMesh, bake_textures

CENTER = np.array([0.1, 0.2, 0.3])


def textured_sphere(size: int = 64) -> tuple[o3d.geometry.TriangleMesh, TexturedMesh, dict]:
    """Sphere r = 0.5 at CENTER; albedo from the position, metallic = x ramp, roughness = z ramp
    (per vertex, baked at ``size`` px). Returns (mesh, textured mesh, per-vertex values)."""
    m = o3d.geometry.TriangleMesh.create_sphere(0.5, 20).translate(CENTER)
    m.compute_vertex_normals()
    v = np.asarray(m.vertices) - CENTER
    vals = {"albedo": np.clip(v + 0.5, 0.05, 0.95), "metallic": np.clip(v[:, 0] + 0.5, 0, 1),
            "roughness": np.clip(v[:, 2] + 0.5, 0.05, 1)}
    tm = bake_textures(m, vals["albedo"], vals["metallic"], vals["roughness"], size=size)
    return m, tm, vals


def write_assets(folder: Path, tm: TexturedMesh) -> tuple[Path, Path]:
    """model.glb (+ sidecar, scene up +Z) and model.obj in ``folder``."""
    glb = write_glb(folder / "model.glb", tm, sidecar={"scene_up": [0.0, 0.0, 1.0]})
    obj = write_obj(folder / "model.obj", tm)
    return glb, obj
