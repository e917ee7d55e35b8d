"""The fixed surface of stage 2: Open3D ray casts and the cache of primary hits.

Everything here is in the **unit frame** of the scene (the mesh is mapped there on load).
Open3D casts on the CPU in float32; results are returned as torch tensors.

Primary rays go through the pixel centres of every training view (OpenCV cameras,
:func:`voxnero.cameras.rays.image_rays`) and are cast once. Pixels whose centre ray hits the
mesh train the materials; the others see the environment at infinity and train the env map
directly (pixel = env(dir)). Pixels on the silhouette (a 4-neighbour has the other label) are
mixtures of object and background under the box filter and are left out of both sets.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import open3d as o3d
import torch
from torch import Tensor

RAY_EPS = 2e-3
"""Offset (unit frame) of secondary-ray origins along the geometric normal: avoids hitting the
own triangle or a neighbour of a tessellated curved surface."""


@dataclass
class Geometry:
    """A triangle mesh in the unit frame with an Open3D ray-casting scene.

    Attributes:
        vertices: (V, 3) float32 positions.
        triangles: (F, 3) long vertex indices (counter-clockwise seen from outside).
        vertex_normals: (V, 3) float32 unit normals.
        face_normals: (F, 3) float32 unit normals from the winding.
        scene: Open3D ``RaycastingScene`` holding the mesh.
    """

    vertices: Tensor
    triangles: Tensor
    vertex_normals: Tensor
    face_normals: Tensor
    scene: o3d.t.geometry.RaycastingScene

    @classmethod
    def from_legacy(cls, mesh: o3d.geometry.TriangleMesh) -> Geometry:
        """Build from a legacy Open3D mesh (vertex normals are computed if missing)."""
        if len(mesh.triangles) == 0:
            raise ValueError("Geometry: the mesh has no triangles")
        mesh = o3d.geometry.TriangleMesh(mesh)
        if not mesh.has_vertex_normals():
            mesh.compute_vertex_normals()
        mesh.compute_triangle_normals()
        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
        vn = np.asarray(mesh.vertex_normals, dtype=np.float64)
        vn = vn / np.maximum(np.linalg.norm(vn, axis=1, keepdims=True), 1e-12)
        return cls(torch.as_tensor(np.asarray(mesh.vertices), dtype=torch.float32),
                   torch.as_tensor(np.asarray(mesh.triangles), dtype=torch.long),
                   torch.as_tensor(vn, dtype=torch.float32),
                   torch.as_tensor(np.asarray(mesh.triangle_normals), dtype=torch.float32),
                   scene)

    @property
    def n_vertices(self) -> int:
        return int(self.vertices.shape[0])

    @property
    def device(self) -> torch.device:
        return self.vertices.device

    def to(self, device: torch.device | str) -> Geometry:
        """A copy whose tensors live on ``device`` (casts still run on the CPU in Open3D)."""
        return Geometry(self.vertices.to(device), self.triangles.to(device),
                        self.vertex_normals.to(device), self.face_normals.to(device), self.scene)

    def cast(self, origins: Tensor, dirs: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """First hit of each ray.

        Args:
            origins: (N, 3) ray origins.
            dirs: (N, 3) unit directions (so ``t`` is a distance).

        Returns:
            t (N,) hit distance (inf on a miss), tri (N,) long triangle index (−1 on a miss),
            bary (N, 3) barycentric weights of the triangle's three vertices; on the
            geometry's device.
        """
        rays = torch.cat([origins, dirs], -1).detach().to("cpu", torch.float32).numpy()
        ans = self.scene.cast_rays(o3d.core.Tensor(np.ascontiguousarray(rays)))
        t = torch.from_numpy(ans["t_hit"].numpy().astype(np.float32))
        tri = torch.from_numpy(ans["primitive_ids"].numpy().astype(np.int64))
        uv = torch.from_numpy(ans["primitive_uvs"].numpy().astype(np.float32))
        hit = torch.isfinite(t)
        tri = torch.where(hit, tri, torch.full_like(tri, -1))
        bary = torch.stack([1.0 - uv[:, 0] - uv[:, 1], uv[:, 0], uv[:, 1]], -1)
        bary = torch.where(hit[:, None], bary, torch.zeros_like(bary))
        dev = self.device
        return t.to(dev), tri.to(dev), bary.to(dev)

    def occluded(self, origins: Tensor, dirs: Tensor) -> Tensor:
        """Whether each ray hits the mesh at all (any hit, faster than :meth:`cast`).

        Args:
            origins: (N, 3); dirs: (N, 3) unit directions.

        Returns:
            (N,) bool.
        """
        rays = torch.cat([origins, dirs], -1).detach().to("cpu", torch.float32).numpy()
        occ = self.scene.test_occlusions(o3d.core.Tensor(np.ascontiguousarray(rays)))
        return torch.from_numpy(occ.numpy().astype(bool)).to(self.device)

    def interpolate(self, values: Tensor, tri: Tensor, bary: Tensor) -> Tensor:
        """Barycentric interpolation of per-vertex values at hits.

        Args:
            values: (V, C) per-vertex values.
            tri: (N,) valid triangle indices (>= 0).
            bary: (N, 3) barycentric weights.

        Returns:
            (N, C).
        """
        f = self.triangles[tri]
        return (values[f] * bary[..., None].to(values.dtype)).sum(-2)

    def points_at(self, tri: Tensor, bary: Tensor) -> Tensor:
        """(N, 3) positions of hits given by triangle and barycentrics."""
        return self.interpolate(self.vertices, tri, bary)

    def normals_at(self, tri: Tensor, bary: Tensor) -> Tensor:
        """(N, 3) unit shading normals (interpolated vertex normals) at hits."""
        n = self.interpolate(self.vertex_normals, tri, bary)
        return torch.nn.functional.normalize(n, dim=-1)

    def spawn(self, tri: Tensor, x: Tensor, l: Tensor) -> Tensor:
        """Origins of secondary rays leaving hit points: x + RAY_EPS · n_face (flipped to l's side).

        Args:
            tri: (N,) or (N, 1) triangle of each point (broadcast over samples by the caller).
            x: (..., 3) points; l: (..., 3) outgoing directions (same leading shape as x).

        Returns:
            (..., 3) offset origins.
        """
        nf = self.face_normals[tri]
        side = torch.sign((nf * l).sum(-1, keepdim=True))
        side = torch.where(side == 0, torch.ones_like(side), side)
        return x + RAY_EPS * side * nf


@dataclass
class SurfaceCache:
    """Training pixels of stage 2, cast once.

    Attributes:
        tri: (N,) long triangle hit by each object pixel's centre ray.
        bary: (N, 3) barycentric weights of the hit.
        x: (N, 3) hit points; n: (N, 3) unit shading normals; v: (N, 3) unit directions toward
            the camera (away from the surface).
        rgb: (N, 3) LINEAR target radiance of the object pixels (from 8-bit sRGB, so <= 1).
        bg_dirs: (M, 3) unit directions of background pixels (toward the environment).
        bg_rgb: (M, 3) LINEAR target radiance of background pixels.
        n_object_total: object pixels before subsampling.
        n_background_total: background pixels before subsampling.
        cam: (N,) long view of each object pixel; pix: (N, 2) its centre ``[x = column,
            y = row]`` (pixel coordinates); cameras: the views (unit frame). With them a pixel
            can be re-cast at points inside its footprint (``render.jitter``); None in caches
            built by hand.
    """

    tri: Tensor
    bary: Tensor
    x: Tensor
    n: Tensor
    v: Tensor
    rgb: Tensor
    bg_dirs: Tensor
    bg_rgb: Tensor
    n_object_total: int = 0
    n_background_total: int = 0
    cam: Tensor | None = None
    pix: Tensor | None = None
    cameras: Any = None


def _interior(hit: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Object / background pixels away from the silhouette (4-neighbourhood), (H, W) bool each."""
    pad = np.pad(hit, 1, mode="edge")
    nb = [pad[:-2, 1:-1], pad[2:, 1:-1], pad[1:-1, :-2], pad[1:-1, 2:]]
    all_hit = hit & nb[0] & nb[1] & nb[2] & nb[3]
    none_hit = ~hit & ~nb[0] & ~nb[1] & ~nb[2] & ~nb[3]
    return all_hit, none_hit


def build_cache(geom: Geometry, images: Tensor, cameras, max_pixels: int = 400000,
                generator: torch.Generator | None = None, max_bg_pixels: int | None = None
                ) -> SurfaceCache:
    """Cast every training pixel's centre ray once and keep what stage 2 trains on.

    Args:
        geom: the mesh (unit frame).
        images: (K, H, W, 3) LINEAR training images.
        cameras: :class:`voxnero.cameras.cameras.Cameras` of the K views (unit frame).
        max_pixels: keep at most this many object pixels (uniform random subset); <= 0 keeps
            all.
        generator: torch generator of the subsets.
        max_bg_pixels: the same for background pixels (None: same as ``max_pixels``).

    Returns:
        The :class:`SurfaceCache`.
    """
    from voxnero.cameras.rays import image_rays, pixel_centers

    obj = {k: [] for k in ("tri", "bary", "v", "rgb", "cam", "pix")}
    bg_d, bg_rgb = [], []
    for i in range(images.shape[0]):
        o, d = image_rays(cameras, i)
        H, W = d.shape[:2]
        o, d = o.reshape(-1, 3).cpu(), d.reshape(-1, 3).cpu()
        t, tri, bary = geom.cast(o, d)
        hit = (tri >= 0).numpy().reshape(H, W)
        keep_obj, keep_bg = _interior(hit)
        ko = torch.from_numpy(keep_obj.reshape(-1))
        kb = torch.from_numpy(keep_bg.reshape(-1))
        img = images[i].reshape(-1, 3).cpu().float()
        obj["tri"].append(tri[ko])
        obj["bary"].append(bary[ko])
        obj["v"].append(-d[ko])
        obj["rgb"].append(img[ko])
        obj["cam"].append(torch.full((int(ko.sum()),), i, dtype=torch.long))
        obj["pix"].append(pixel_centers(H, W).reshape(-1, 2)[ko])
        bg_d.append(d[kb])
        bg_rgb.append(img[kb])
    cat = {k: torch.cat(v) for k, v in obj.items()}
    bg_d, bg_rgb = torch.cat(bg_d), torch.cat(bg_rgb)
    n_obj, n_bg = cat["tri"].shape[0], bg_d.shape[0]
    if max_pixels > 0 and n_obj > max_pixels:
        sel = torch.randperm(n_obj, generator=generator)[:max_pixels]
        cat = {k: v[sel] for k, v in cat.items()}
    max_bg = max_pixels if max_bg_pixels is None else max_bg_pixels
    if max_bg > 0 and n_bg > max_bg:
        sel = torch.randperm(n_bg, generator=generator)[:max_bg]
        bg_d, bg_rgb = bg_d[sel], bg_rgb[sel]
    x = geom.points_at(cat["tri"], cat["bary"])
    n = geom.normals_at(cat["tri"], cat["bary"])
    return SurfaceCache(cat["tri"], cat["bary"], x, n, cat["v"], cat["rgb"], bg_d, bg_rgb,
                        n_obj, n_bg, cat["cam"], cat["pix"], cameras)
