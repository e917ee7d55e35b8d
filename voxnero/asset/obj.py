"""Wavefront OBJ + MTL + PNG textures of a textured PBR mesh: writer and reader.

Written in the scene's input frame as is (no axis change; OBJ has no up axis). Texture
coordinates follow OBJ's convention (v up from the bottom row), so ``vt = (u, 1 − v_glTF)``.
The MTL names the base colour (``map_Kd``, sRGB PNG) and the common PBR extension keys
(``map_Pr`` roughness, ``map_Pm`` metallic: linear 8-bit grey PNGs; ``Pr``/``Pm`` = 1 so the
maps are the values). The reader takes ``map_Kd`` (sRGB), ``map_Pr`` / ``map_Pm`` (linear grey)
times ``Kd`` / ``Pr`` / ``Pm``; faces may use different v / vt / vn indices.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from voxnero.asset.model import Asset, make_asset, material_from_maps
from voxnero.errors import DataError
from voxnero.io.color import linear_to_srgb
from voxnero.io.images import read_image, write_png

if TYPE_CHECKING:  # the writers take a baked mesh; baking (Open3D) is not needed to read
    from voxnero.asset.textures import TexturedMesh


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


def _parse_mtl(path: Path) -> dict[str, str]:
    out: dict[str, str] = {}
    if not path.is_file():
        return out
    for line in path.read_text().splitlines():
        parts = line.strip().split(None, 1)
        if len(parts) == 2 and not parts[0].startswith("#"):
            out.setdefault(parts[0], parts[1].strip())
    return out


def load_obj(path: str | Path, up=(0.0, 0.0, 1.0)) -> Asset:
    """Load ``model.obj`` + ``.mtl`` + PNG textures (as :func:`write_obj` writes them; input
    frame).

    Faces may use different v / vt / vn indices: every distinct corner triple becomes a vertex.

    Args:
        path: the ``.obj`` file.
        up: up axis of the frame (OBJ has none), +Z by default.

    Returns:
        The :class:`Asset`.
    """
    path = Path(path)
    if not path.is_file():
        raise DataError("OBJ file not found", path=path, fix="check the path")
    v, vt, vn, faces, mtllib = [], [], [], [], None
    for line in path.read_text().splitlines():
        if line.startswith("v "):
            v.append(line.split()[1:4])
        elif line.startswith("vt "):
            vt.append(line.split()[1:3])
        elif line.startswith("vn "):
            vn.append(line.split()[1:4])
        elif line.startswith("f "):
            corners = [re.split("/", c) for c in line.split()[1:]]
            for k in range(1, len(corners) - 1):  # fan triangulation
                faces.append([corners[0], corners[k], corners[k + 1]])
        elif line.startswith("mtllib "):
            mtllib = line.split(None, 1)[1].strip()
    if not faces:
        raise DataError("no faces in the OBJ file", path=path, fix="pass a triangle mesh")
    V = np.asarray(v, dtype=np.float64)
    VT = np.asarray(vt, dtype=np.float64) if vt else np.zeros((1, 2))
    VN = np.asarray(vn, dtype=np.float64) if vn else None

    def ix(s: str, n: int) -> int:
        i = int(s)
        return i - 1 if i > 0 else n + i

    keys = []
    for f in faces:
        for c in f:
            keys.append((ix(c[0], len(V)),
                         ix(c[1], len(VT)) if len(c) > 1 and c[1] else -1,
                         ix(c[2], len(VN)) if VN is not None and len(c) > 2 and c[2] else -1))
    keys_a = np.asarray(keys, dtype=np.int64)
    uniq, inv = np.unique(keys_a, axis=0, return_inverse=True)
    pos = V[uniq[:, 0]]
    uv = VT[np.maximum(uniq[:, 1], 0)].copy()
    uv[:, 1] = 1.0 - uv[:, 1]  # OBJ v points up; glTF convention v down
    nrm = VN[uniq[:, 2]] if VN is not None and (uniq[:, 2] >= 0).all() else np.zeros_like(pos)
    idx = inv.reshape(-1, 3)
    mtl = _parse_mtl(path.parent / mtllib) if mtllib else {}

    def tex(key: str) -> np.ndarray | None:
        name = mtl.get(key)
        if not name:
            return None
        file = path.parent / name.split()[-1]
        if not file.is_file():
            raise DataError(f"texture file not found ({key} of {mtllib})", path=file,
                            fix=f"put the texture beside {path.name}, correct the {key} line of "
                                f"{mtllib}, or pass the model.glb (its textures are embedded)")
        return read_image(file)

    def num(key: str, default: float) -> float:
        try:
            return float(mtl.get(key, default).split()[0]) if key in mtl else default
        except ValueError:
            return default

    kd = [float(x) for x in mtl.get("Kd", "1 1 1").split()[:3]]
    pm, pr = num("Pm", 1.0), num("Pr", 1.0)
    base, met, rough = tex("map_Kd"), tex("map_Pm"), tex("map_Pr")
    mat = material_from_maps(uv, None if base is None else base[..., :3],
                             None if met is None else met[..., 0],
                             None if rough is None else rough[..., 0], kd, pm, pr)
    return make_asset(pos, idx, nrm, mat, np.asarray(up, dtype=np.float64), str(path))
