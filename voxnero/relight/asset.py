"""Load an asset to relight or view: a mesh with albedo / metallic / roughness, in the scene's
input frame.

Sources (:func:`load_asset` picks by the path):

* ``model.glb`` (``voxnero.export.gltf``): positions/normals are stored +Y up with
  ``(x, y, z)_glTF = (x, z, −y)_scene``; the rotation recorded in the sidecar
  ``model.glb.json`` (``scene_to_gltf``) is undone exactly (``p_scene = Rᵀ p_glTF``). Base
  colour is an sRGB-encoded texture (decoded to linear), metallic-roughness a linear texture
  (G = perceptual roughness, B = metallic); factors multiply the textures.
* ``model.obj`` + ``.mtl`` (``voxnero.export.obj``): input frame as is; ``map_Kd`` (sRGB),
  ``map_Pr`` / ``map_Pm`` (linear grey) times ``Kd`` / ``Pr`` / ``Pm``; OBJ texture coordinates
  have v up, so ``v_glTF = 1 − vt``.
* a run folder: its ``model.glb`` (else ``model.obj``), plus the stage-1 ``mesh.ply`` when
  the run (or the stage-1 run its config names) has one, for the viewer.
* a ``voxnero reconstruct`` output folder: the asset of its ``material/`` run, with the stage-1
  mesh of its ``shape/`` run.
* ground truth: ``gt:SCENE`` or a scene folder holding ``gt/mesh.ply`` + ``gt/material.json``
  (``"kind": "uniform"``: ``base_color`` linear, ``metallic``, ``roughness``).

Texture lookup convention (glTF): texture coordinate (u, v) ∈ [0, 1]² with (0, 0) the top-left
corner of the image; texel (column i, row j) has its centre at ((i + ½)/S, (j + ½)/S);
bilinear, clamped at the borders.
"""

from __future__ import annotations

import json
import re
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from voxnero.errors import DataError

_COMPONENTS = {5126: np.float32, 5125: np.uint32, 5123: np.uint16, 5121: np.uint8}
_NCOMP = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}


# ----------------------------------------------------------------------------------------------
# materials over the surface
# ----------------------------------------------------------------------------------------------


def sample_texture(tex: Tensor, uv: Tensor) -> Tensor:
    """Bilinear texture lookup in the glTF convention (origin top-left, clamp to edge).

    Args:
        tex: (S_h, S_w, C) texture values.
        uv: (N, 2) texture coordinates; texel (i, j) is centred at ((i + ½)/S_w, (j + ½)/S_h).

    Returns:
        (N, C) interpolated values.
    """
    h, w, c = tex.shape
    x = (uv[:, 0].double() * w - 0.5).clamp(0.0, w - 1)
    y = (uv[:, 1].double() * h - 0.5).clamp(0.0, h - 1)
    x0 = torch.floor(x).clamp(max=max(w - 2, 0)).long()
    y0 = torch.floor(y).clamp(max=max(h - 2, 0)).long()
    wx = (x - x0).to(tex.dtype)[:, None]
    wy = (y - y0).to(tex.dtype)[:, None]
    x1 = (x0 + 1).clamp(max=w - 1)
    y1 = (y0 + 1).clamp(max=h - 1)
    flat = tex.reshape(h * w, c)

    def g(yy: Tensor, xx: Tensor) -> Tensor:
        return flat[yy * w + xx]

    top = g(y0, x0) * (1 - wx) + g(y0, x1) * wx
    bot = g(y1, x0) * (1 - wx) + g(y1, x1) * wx
    return top * (1 - wy) + bot * wy


@dataclass
class UniformMaterial:
    """One material for the whole surface.

    Attributes:
        albedo: (3,) linear base colour; metallic, roughness: scalars (perceptual r, α = r²).
    """

    albedo: tuple[float, float, float]
    metallic: float
    roughness: float

    def at(self, triangles: Tensor, tri: Tensor, bary: Tensor
           ) -> tuple[Tensor, Tensor, Tensor]:
        """Material at hits: albedo (N, 3), metallic (N, 1), roughness (N, 1)."""
        n = tri.shape[0]
        a = torch.tensor(self.albedo, dtype=torch.float32).expand(n, 3)
        return (a, torch.full((n, 1), float(self.metallic)),
                torch.full((n, 1), float(self.roughness)))


@dataclass
class TextureMaterial:
    """Textures addressed by per-vertex texture coordinates (glTF convention).

    Attributes:
        uvs: (V, 2) texture coordinates per vertex.
        albedo: (S, S, 3) LINEAR base colour texture.
        metallic: (S, S) metallic texture; roughness: (S, S) perceptual roughness texture.
    """

    uvs: Tensor
    albedo: Tensor
    metallic: Tensor
    roughness: Tensor

    def at(self, triangles: Tensor, tri: Tensor, bary: Tensor
           ) -> tuple[Tensor, Tensor, Tensor]:
        """Material at hits (triangle ``tri`` (N,), barycentrics ``bary`` (N, 3)):
        albedo (N, 3), metallic (N, 1), roughness (N, 1)."""
        uv = (self.uvs[triangles[tri]] * bary[..., None].to(self.uvs.dtype)).sum(-2)
        a = sample_texture(self.albedo, uv)
        mr = sample_texture(torch.stack([self.metallic, self.roughness], -1), uv)
        return a, mr[:, :1], mr[:, 1:2]


@dataclass
class Asset:
    """A relightable mesh in the scene's input frame.

    Attributes:
        vertices: (V, 3) float32 positions (input frame of the scene).
        triangles: (F, 3) long vertex indices, counter-clockwise seen from outside.
        normals: (V, 3) float32 unit vertex normals.
        material: :class:`UniformMaterial` or :class:`TextureMaterial`.
        up: (3,) unit world up axis of the input frame (+Z for Blender-style scenes).
        source: what was loaded (file or ``gt:...``), for logs.
        stage1_mesh: the stage-1 mesh file of the run, if any (viewer).
        scene: the scene folder named by the asset's metadata, if any.
    """

    vertices: Tensor
    triangles: Tensor
    normals: Tensor
    material: UniformMaterial | TextureMaterial
    up: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    source: str = ""
    stage1_mesh: Path | None = None
    scene: Path | None = None

    def material_at(self, tri: Tensor, bary: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """Albedo (N, 3) linear, metallic (N, 1), roughness (N, 1) at hits.

        Args:
            tri: (N,) triangle indices; bary: (N, 3) barycentric weights.
        """
        return self.material.at(self.triangles, tri.long(), bary)

    def field(self, tri: Tensor, bary: Tensor, x: Tensor | None = None
              ) -> tuple[Tensor, Tensor, Tensor]:
        """Stage-2 material-field signature ``(tri, bary, x) -> (albedo, metallic, roughness)``."""
        return self.material_at(tri, bary)

    def vertex_material(self) -> tuple[Tensor, Tensor, Tensor]:
        """Material at every vertex: albedo (V, 3), metallic (V, 1), roughness (V, 1)."""
        V = self.vertices.shape[0]
        # a triangle holding each vertex at corner k, with barycentric e_k
        f = self.triangles
        tri = torch.zeros(V, dtype=torch.long)
        corner = torch.zeros(V, dtype=torch.long)
        for k in range(3):
            tri[f[:, k]] = torch.arange(f.shape[0])
            corner[f[:, k]] = k
        bary = torch.nn.functional.one_hot(corner, 3).float()
        return self.material_at(tri, bary)

    def bounds(self) -> tuple[np.ndarray, float]:
        """Centre (3,) of the bounding box and the radius of the sphere about it holding all."""
        v = self.vertices.double().numpy()
        c = 0.5 * (v.min(0) + v.max(0))
        return c, float(np.linalg.norm(v - c, axis=1).max())

    def legacy_mesh(self, norm=None):
        """The mesh as a legacy Open3D ``TriangleMesh`` with vertex normals.

        Args:
            norm: optional :class:`voxnero.data.scene.Normalisation`; vertices are mapped with
                ``norm.to_unit`` (a similarity: normals unchanged). Default: input frame.
        """
        import open3d as o3d

        v = self.vertices.double().numpy()
        if norm is not None:
            v = norm.to_unit(v)
        m = o3d.geometry.TriangleMesh(
            o3d.utility.Vector3dVector(v),
            o3d.utility.Vector3iVector(self.triangles.numpy().astype(np.int32)))
        m.vertex_normals = o3d.utility.Vector3dVector(self.normals.double().numpy())
        return m


# ----------------------------------------------------------------------------------------------
# glTF
# ----------------------------------------------------------------------------------------------


def _decode_png(blob: bytes) -> np.ndarray:
    import io

    from PIL import Image

    with Image.open(io.BytesIO(blob)) as im:
        return np.asarray(im.convert("RGB"), dtype=np.float32) / 255.0


def _accessor(doc: dict, binary: bytes, k: int) -> np.ndarray:
    acc = doc["accessors"][k]
    view = doc["bufferViews"][acc["bufferView"]]
    dt = np.dtype(_COMPONENTS[acc["componentType"]])
    nc = _NCOMP[acc["type"]]
    off = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
    stride = view.get("byteStride", 0) or dt.itemsize * nc
    n = acc["count"]
    if stride == dt.itemsize * nc:
        a = np.frombuffer(binary, dt, n * nc, off).reshape(n, nc)
    else:
        a = np.stack([np.frombuffer(binary, dt, nc, off + i * stride) for i in range(n)])
    return a.astype(np.float64 if dt == np.float32 else np.int64)


def load_glb(path: str | Path) -> Asset:
    """Load ``model.glb`` written by ``voxnero.export.gltf`` (or any single-primitive glTF 2.0
    binary with a metallic-roughness material) back into the scene's input frame.

    Args:
        path: the ``.glb`` file; ``<path>.json`` (sidecar) gives ``scene_to_gltf`` and
            ``scene_up``; without it the glTF frame is kept (+Y up).

    Returns:
        The :class:`Asset`.

    Raises:
        DataError: unreadable file or missing parts.
    """
    from voxnero.export.gltf import read_glb
    from voxnero.io.color import srgb_to_linear

    path = Path(path)
    try:
        doc, binary = read_glb(path)
    except (OSError, ValueError, struct.error) as e:
        raise DataError(f"cannot read glTF binary ({e})", path=path,
                        fix="pass a model.glb written by 'voxnero material'") from None
    try:
        prim = doc["meshes"][0]["primitives"][0]
        att = prim["attributes"]
        pos = _accessor(doc, binary, att["POSITION"])
        idx = _accessor(doc, binary, prim["indices"]).reshape(-1, 3)
        nrm = _accessor(doc, binary, att["NORMAL"]) if "NORMAL" in att else None
        uv = _accessor(doc, binary, att["TEXCOORD_0"]) if "TEXCOORD_0" in att else None
        pbr = doc["materials"][prim["material"]].get("pbrMetallicRoughness", {}) \
            if "material" in prim else {}
    except (KeyError, IndexError) as e:
        raise DataError(f"glTF file lacks a mesh primitive part ({e})", path=path,
                        fix="export one mesh with POSITION, indices and a PBR material") from None

    def image(tex_ref: dict | None) -> np.ndarray | None:
        if tex_ref is None:
            return None
        img = doc["images"][doc["textures"][tex_ref["index"]]["source"]]
        if "bufferView" not in img:
            raise DataError("texture image is an external file (uri), not embedded", path=path,
                            fix="embed the textures (a .glb as 'voxnero material' writes it)")
        view = doc["bufferViews"][img["bufferView"]]
        off = view.get("byteOffset", 0)
        return _decode_png(binary[off:off + view["byteLength"]])

    side = path.with_suffix(path.suffix + ".json")
    meta = json.loads(side.read_text()) if side.is_file() else {}
    R = np.asarray(meta.get("scene_to_gltf", np.eye(3)), dtype=np.float64)
    # rows are row vectors in the file: p_glTF = R p_scene  =>  p_scene = R^T p_glTF
    pos = pos @ R
    if nrm is None:
        nrm = np.zeros_like(pos)
    nrm = nrm @ R
    up = np.asarray(meta.get("scene_up", R.T @ np.array([0.0, 1.0, 0.0])), dtype=np.float64)

    bcf = np.asarray(pbr.get("baseColorFactor", [1, 1, 1, 1]), dtype=np.float32)[:3]
    mf = float(pbr.get("metallicFactor", 1.0))
    rf = float(pbr.get("roughnessFactor", 1.0))
    base = image(pbr.get("baseColorTexture"))
    mr = image(pbr.get("metallicRoughnessTexture"))
    if (base is None and mr is None) or uv is None:
        mat: UniformMaterial | TextureMaterial = UniformMaterial(tuple(bcf.tolist()), mf, rf)
    else:
        size = (base if base is not None else mr).shape[:2]
        alb = srgb_to_linear(base) * bcf if base is not None else np.ones((*size, 3)) * bcf
        m = mr[..., 2] * mf if mr is not None else np.full(size, mf)
        r = mr[..., 1] * rf if mr is not None else np.full(size, rf)
        mat = TextureMaterial(torch.as_tensor(uv, dtype=torch.float32),
                              torch.as_tensor(np.asarray(alb), dtype=torch.float32),
                              torch.as_tensor(m, dtype=torch.float32),
                              torch.as_tensor(r, dtype=torch.float32))
    asset = _make(pos, idx, nrm, mat, up, str(path))
    if meta.get("scene"):
        asset.scene = Path(meta["scene"])
    return asset


# ----------------------------------------------------------------------------------------------
# OBJ
# ----------------------------------------------------------------------------------------------


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
    """Load ``model.obj`` + ``.mtl`` + PNG textures (``voxnero.export.obj`` layout; input frame).

    Faces may use different v / vt / vn indices: every distinct corner triple becomes a vertex.

    Args:
        path: the ``.obj`` file.
        up: up axis of the frame (OBJ has none), +Z by default.

    Returns:
        The :class:`Asset`.
    """
    from voxnero.io.color import srgb_to_linear
    from voxnero.io.images import read_image

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
    if base is None and met is None and rough is None:
        mat: UniformMaterial | TextureMaterial = UniformMaterial(tuple(kd), pm, pr)
    else:
        size = next(t for t in (base, met, rough) if t is not None).shape[:2]
        alb = (srgb_to_linear(base[..., :3]) if base is not None else np.ones((*size, 3))) * kd
        m = met[..., 0] * pm if met is not None else np.full(size, pm)
        r = rough[..., 0] * pr if rough is not None else np.full(size, pr)
        mat = TextureMaterial(torch.as_tensor(uv, dtype=torch.float32),
                              torch.as_tensor(np.asarray(alb), dtype=torch.float32),
                              torch.as_tensor(m, dtype=torch.float32),
                              torch.as_tensor(r, dtype=torch.float32))
    return _make(pos, idx, nrm, mat, np.asarray(up, dtype=np.float64), str(path))


# ----------------------------------------------------------------------------------------------
# ground truth of a scene
# ----------------------------------------------------------------------------------------------


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
    a = _make(np.asarray(mesh.vertices), np.asarray(mesh.triangles),
              np.asarray(mesh.vertex_normals), mat, np.asarray(up, dtype=np.float64),
              f"gt:{root}")
    a.scene = root
    return a


# ----------------------------------------------------------------------------------------------
# dispatch
# ----------------------------------------------------------------------------------------------


def _make(pos, idx, nrm, mat, up, source) -> Asset:
    pos = np.asarray(pos, dtype=np.float64)
    idx = np.asarray(idx, dtype=np.int64)
    nrm = np.asarray(nrm, dtype=np.float64)
    ln = np.linalg.norm(nrm, axis=1, keepdims=True)
    if not (ln > 1e-8).all():  # missing normals: area-weighted from the faces
        import open3d as o3d

        m = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(pos),
                                      o3d.utility.Vector3iVector(idx.astype(np.int32)))
        m.compute_vertex_normals()
        nrm = np.asarray(m.vertex_normals)
        ln = np.linalg.norm(nrm, axis=1, keepdims=True)
    return Asset(torch.as_tensor(pos, dtype=torch.float32), torch.as_tensor(idx),
                 torch.as_tensor(nrm / np.maximum(ln, 1e-12), dtype=torch.float32), mat,
                 np.asarray(up, dtype=np.float64) / np.linalg.norm(up), source)


def _stage1_of(run: Path) -> Path | None:
    """The stage-1 mesh of a run folder: its own mesh.ply or the one its config.yaml names."""
    if (run / "mesh.ply").is_file():
        return run / "mesh.ply"
    cfg = run / "config.yaml"
    if cfg.is_file():
        import yaml

        try:
            meta = (yaml.safe_load(cfg.read_text()) or {}).get("_meta", {}) or {}
        except yaml.YAMLError:
            return None
        mesh = meta.get("mesh")
        if mesh and Path(mesh).is_file():
            return Path(mesh)
    return None


def _load_run(run: Path) -> Asset | None:
    """The asset of a ``voxnero material`` run folder (model.glb, else model.obj), with its
    stage-1 mesh; None when the folder holds neither model."""
    for name, fn in (("model.glb", load_glb), ("model.obj", load_obj)):
        if (run / name).is_file():
            a = fn(run / name)
            a.stage1_mesh = _stage1_of(run)
            return a
    return None


def load_asset(target: str | Path) -> Asset:
    """Load what the user pointed at (see the module docstring for the accepted forms).

    Args:
        target: ``model.glb``, ``model.obj``, a ``material`` or ``reconstruct`` run folder,
            ``gt:SCENE`` or a scene folder with ``gt/``.

    Returns:
        The :class:`Asset` in the scene's input frame.

    Raises:
        DataError: nothing loadable there (the message lists what was looked for).
    """
    s = str(target)
    if s.startswith("gt:"):
        return load_gt(s[3:])
    p = Path(s)
    if p.is_file():
        suf = p.suffix.lower()
        if suf == ".glb":
            return load_glb(p)
        if suf == ".obj":
            return load_obj(p)
        raise DataError(f"unsupported asset file type {suf!r}", path=p,
                        fix="pass model.glb / model.obj, a run folder or gt:SCENE")
    if p.is_dir():
        a = _load_run(p)
        if a is None and (p / "material").is_dir():  # a 'voxnero reconstruct' folder
            a = _load_run(p / "material")
            if a is not None and (p / "shape" / "mesh.ply").is_file():
                a.stage1_mesh = p / "shape" / "mesh.ply"
        if a is not None:
            return a
        if (p / "gt" / "mesh.ply").is_file():
            return load_gt(p)
        raise DataError("no asset here: looked for model.glb, model.obj, material/model.glb, "
                        "material/model.obj, gt/mesh.ply", path=p,
                        fix="pass a 'voxnero material' or 'voxnero reconstruct' output folder "
                            "(after its stage 2), a model file or gt:SCENE")
    raise DataError("no such file or folder", path=p,
                    fix="pass model.glb / model.obj, a run folder or gt:SCENE")
