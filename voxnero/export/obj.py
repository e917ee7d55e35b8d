"""Wavefront OBJ + MTL + PNG textures for a textured PBR mesh.

Written in the scene's input frame as is (no axis change; OBJ has no up axis). Texture
coordinates follow OBJ's convention (v up from the bottom row), so ``vt = (u, 1 − v_glTF)``.
The MTL names the base colour (``map_Kd``, sRGB PNG) and the common PBR extension keys
(``map_Pr`` roughness, ``map_Pm`` metallic: linear 8-bit grey PNGs; ``Pr``/``Pm`` = 1 so the
maps are the values).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from voxnero.export.textures import TexturedMesh
from voxnero.io.color import linear_to_srgb
from voxnero.io.images import write_png


def write_obj(path: str | Path, tm: TexturedMesh, name: str = "voxnero") -> Path:
    """Write ``model.obj``, ``model.mtl`` and ``<stem>_albedo/_roughness/_metallic.png``.

    Args:
        path: the ``.obj`` file; the MTL and textures go beside it.
        tm: textured mesh (input frame).
        name: material name.

    Returns:
        The OBJ path.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    stem = path.stem
    tex = {"albedo": f"{stem}_albedo.png", "roughness": f"{stem}_roughness.png",
           "metallic": f"{stem}_metallic.png"}
    write_png(path.parent / tex["albedo"],
              np.asarray(linear_to_srgb(np.clip(tm.albedo, 0, 1).astype(np.float32))))
    write_png(path.parent / tex["roughness"], tm.roughness)
    write_png(path.parent / tex["metallic"], tm.metallic)
    mtl = path.with_suffix(".mtl")
    mtl.write_text(
        f"# VoxNeRO stage 2: PBR metallic-roughness material\nnewmtl {name}\n"
        "Ka 0 0 0\nKd 1 1 1\nKs 0 0 0\nd 1\nillum 2\n"
        f"map_Kd {tex['albedo']}\nPr 1\nPm 1\nmap_Pr {tex['roughness']}\n"
        f"map_Pm {tex['metallic']}\n")
    uv = tm.uvs.astype(np.float64).copy()
    uv[:, 1] = 1.0 - uv[:, 1]
    f = tm.indices.astype(np.int64) + 1
    with open(path, "w") as fh:
        fh.write(f"# VoxNeRO stage 2 mesh, input frame\nmtllib {mtl.name}\no {name}\n")
        np.savetxt(fh, tm.positions, fmt="v %.7g %.7g %.7g")
        np.savetxt(fh, uv, fmt="vt %.7g %.7g")
        np.savetxt(fh, tm.normals, fmt="vn %.6g %.6g %.6g")
        fh.write(f"usemtl {name}\n")
        np.savetxt(fh, np.repeat(f, 3, axis=1), fmt="f %d/%d/%d %d/%d/%d %d/%d/%d")
    return path
