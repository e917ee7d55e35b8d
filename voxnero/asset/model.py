"""The relightable asset in memory: a mesh in the scene's input frame and its material
(uniform, or textures addressed by per-vertex texture coordinates), as every reader in this
package returns it and ``relight``, ``view`` and ``eval`` use it.

Texture lookup convention (glTF): texture coordinate (u, v) ∈ [0, 1]² with (0, 0) the top-left
corner of the image; texel (column i, row j) has its centre at ((i + ½)/S, (j + ½)/S);
bilinear, clamped at the borders.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from torch import Tensor


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
        diffuse: the BRDF's diffuse convention the material is meant for
            (``voxnero.render.brdf.DIFFUSE_MODELS``): what renders of the asset use.
    """

    vertices: Tensor
    triangles: Tensor
    normals: Tensor
    material: UniformMaterial | TextureMaterial
    up: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    source: str = ""
    stage1_mesh: Path | None = None
    scene: Path | None = None
    diffuse: str = "weighted"

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


def material_from_maps(uv: np.ndarray | None, base_srgb: np.ndarray | None,
                       metallic: np.ndarray | None, roughness: np.ndarray | None,
                       albedo_factor, metallic_factor: float, roughness_factor: float
                       ) -> UniformMaterial | TextureMaterial:
    """A file's material: its textures (any may be absent) times its factors, as glTF and MTL
    define them; uniform (the factors) when there is no texture or no texture coordinates.

    Args:
        uv: (V, 2) texture coordinates (glTF convention), or None.
        base_srgb: (S, S, 3) sRGB-encoded base colour in [0, 1], or None.
        metallic, roughness: (S, S) linear maps in [0, 1], or None.
        albedo_factor: (3,) linear factor of the base colour; metallic_factor, roughness_factor.
    """
    from voxnero.io.color import srgb_to_linear

    if (base_srgb is None and metallic is None and roughness is None) or uv is None:
        return UniformMaterial(tuple(float(c) for c in albedo_factor), metallic_factor,
                               roughness_factor)
    size = next(t for t in (base_srgb, metallic, roughness) if t is not None).shape[:2]
    alb = (srgb_to_linear(base_srgb) if base_srgb is not None else np.ones((*size, 3))) \
        * albedo_factor
    m = metallic * metallic_factor if metallic is not None else np.full(size, metallic_factor)
    r = roughness * roughness_factor if roughness is not None else np.full(size, roughness_factor)
    return TextureMaterial(torch.as_tensor(uv, dtype=torch.float32),
                           torch.as_tensor(np.asarray(alb), dtype=torch.float32),
                           torch.as_tensor(m, dtype=torch.float32),
                           torch.as_tensor(r, dtype=torch.float32))


def make_asset(pos, idx, nrm, mat: UniformMaterial | TextureMaterial, up, source: str) -> Asset:
    """An :class:`Asset` from arrays: positions (V, 3), triangles (F, 3), normals (V, 3) (where
    any is missing or zero, area-weighted normals of the faces), the material, the up axis (3,)
    (normalised here) and the source's name."""
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
