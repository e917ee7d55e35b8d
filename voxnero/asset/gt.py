"""The ground truth of a dev-style scene as an asset: ``gt/mesh.ply`` and ``gt/material.json``
(``"kind": "uniform"``: ``base_color`` linear, ``metallic``, ``roughness``), world frame."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from voxnero.asset.model import Asset, UniformMaterial, make_asset
from voxnero.errors import DataError


def load_gt(scene: str | Path) -> Asset:
    """The ground-truth mesh and material of a dev-style scene (``gt/mesh.ply``,
    ``gt/material.json`` with ``"kind": "uniform"``), in the scene's world frame.

    Args:
        scene: the scene folder.

    Returns:
        The :class:`Asset` (``scene`` set to the folder; up from ``world_up``, +Z default).
    """
    import open3d as o3d

    root = Path(scene)
    mesh_p, mat_p = root / "gt" / "mesh.ply", root / "gt" / "material.json"
    for p in (mesh_p, mat_p):
        if not p.is_file():
            raise DataError("ground-truth file missing", path=p,
                            fix="gt: needs a scene folder with gt/mesh.ply and gt/material.json")
    doc = json.loads(mat_p.read_text())
    m = doc.get("material", {})
    if m.get("kind", "uniform") != "uniform":
        raise DataError(f"material kind {m.get('kind')!r} is not supported", path=mat_p,
                        fix="only 'uniform' ground-truth materials can be loaded")
    mat = UniformMaterial(tuple(float(c) for c in m["base_color"]), float(m["metallic"]),
                          float(m["roughness"]))
    mesh = o3d.io.read_triangle_mesh(str(mesh_p), enable_post_processing=False,
                                     print_progress=False)
    if len(mesh.triangles) == 0:
        raise DataError("no triangles in the ground-truth mesh", path=mesh_p, fix="check the file")
    if not mesh.has_vertex_normals():
        mesh.compute_vertex_normals()
    up = {"+Z": (0, 0, 1), "+Y": (0, 1, 0)}.get(str(doc.get("world_up", "+Z")), (0, 0, 1))
    a = make_asset(np.asarray(mesh.vertices), np.asarray(mesh.triangles),
              np.asarray(mesh.vertex_normals), mat, np.asarray(up, dtype=np.float64),
              f"gt:{root}")
    a.scene = root
    # the renderer that made the scene names its BSDF: Mitsuba's principled for the dev scenes
    # and the corpus, the project's own BRDF for `voxnero synth` scenes
    a.diffuse = "principled" if "principled" in str(doc.get("bsdf", "")) else "weighted"
    return a
