"""A mesh seen from test views: pixel rays, full-coverage masks, Open3D ray casts.

Shared by the view-based metrics (:mod:`voxnero.eval.chamfer`, :mod:`voxnero.eval.normals`).
Rays come from :func:`voxnero.cameras.rays.image_rays` (OpenCV cameras, rays through pixel
centres); everything here is numpy float64 on the CPU because Open3D casts on the CPU.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import TYPE_CHECKING

import numpy as np
import open3d as o3d
import torch

if TYPE_CHECKING:
    from voxnero.cameras.cameras import Cameras


def as_numpy(a: torch.Tensor | np.ndarray) -> np.ndarray:
    """Any tensor or array as a float64 numpy array on the CPU."""
    if isinstance(a, torch.Tensor):
        return a.detach().to("cpu", torch.float64).numpy()
    return np.asarray(a, dtype=np.float64)


def full_coverage(mask: torch.Tensor | np.ndarray) -> np.ndarray:
    """Pixels fully covered by the object: ``mask == 255`` for 8-bit masks.

    Args:
        mask: ``(..., H, W)`` coverage; integer arrays are 8-bit values (255 = covered), floating
            arrays are fractions in [0, 1] (``voxnero.data`` divides the PNG by 255).

    Returns:
        Boolean array of the same shape: True where the coverage is 255/255.
    """
    if isinstance(mask, torch.Tensor):
        mask = mask.detach().cpu().numpy()
    mask = np.asarray(mask)
    if mask.dtype == bool:
        return mask.copy()
    if np.issubdtype(mask.dtype, np.integer):
        return mask == 255
    return mask >= 1.0 - 0.5 / 255.0


def partial_coverage(mask: torch.Tensor | np.ndarray) -> np.ndarray:
    """Silhouette pixels, partly covered by the object (0 < coverage < 1)."""
    full = full_coverage(mask)
    m = mask.detach().cpu().numpy() if isinstance(mask, torch.Tensor) else np.asarray(mask)
    return (m > 0) & ~full


def view_rays(cameras: Cameras, index: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rays through the pixel centres of one view.

    Returns:
        ``origins (H, W, 3)``, unit ``dirs (H, W, 3)`` in the cameras' world frame, and
        ``forward (3,)``, the camera's +z (viewing) axis in that frame (OpenCV convention).
    """
    from voxnero.cameras.rays import image_rays

    o, d = image_rays(cameras, index)
    forward = as_numpy(cameras.c2w[index, :3, 2])
    return as_numpy(o), as_numpy(d), forward / np.linalg.norm(forward)


RayList = list[tuple[int, np.ndarray, np.ndarray, np.ndarray]]
"""``list(iter_view_rays(cameras))``: precomputed rays shared between metrics."""


def iter_view_rays(cameras: Cameras, max_rays: int = 1 << 20
                   ) -> Iterator[tuple[int, np.ndarray, np.ndarray, np.ndarray]]:
    """Rays through the pixel centres of every view, generated several views at a time.

    Same rays as :func:`view_rays` (``voxnero.cameras.rays.pixel_rays`` at
    ``pixel_centers``), but one batched call per group of views is several times faster than
    one call per view when the CPU is busy.

    Args:
        cameras: V cameras.
        max_rays: rays per batch (memory: about 50 bytes per ray).

    Yields:
        ``(index, origins (H, W, 3), dirs (H, W, 3) unit, forward (3,))`` per view, in order.
    """
    from voxnero.cameras.rays import pixel_centers, pixel_rays

    h, w = cameras.height, cameras.width
    pix = pixel_centers(h, w, device=cameras.device).reshape(-1, 2)
    per = max(1, max_rays // (h * w))
    fwd = as_numpy(cameras.c2w[:, :3, 2])
    fwd = fwd / np.linalg.norm(fwd, axis=1, keepdims=True)
    for start in range(0, len(cameras), per):
        stop = min(start + per, len(cameras))
        idx = torch.arange(start, stop, device=cameras.device).repeat_interleave(h * w)
        o, d = pixel_rays(cameras, idx, pix.repeat(stop - start, 1))
        o = as_numpy(o).reshape(stop - start, h, w, 3)
        d = as_numpy(d).reshape(stop - start, h, w, 3)
        for k in range(stop - start):
            yield start + k, o[k], d[k], fwd[start + k]


class MeshCaster:
    """An Open3D ``RaycastingScene`` holding one mesh (built once, cast many times)."""

    def __init__(self, mesh: o3d.geometry.TriangleMesh):
        """Args:
            mesh: legacy Open3D triangle mesh (any frame; rays must be in the same frame).
        """
        if len(mesh.triangles) == 0:
            raise ValueError("MeshCaster: the mesh has no triangles")
        self.mesh = mesh
        self.scene = o3d.t.geometry.RaycastingScene()
        self.scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
        self._vn = np.asarray(mesh.vertex_normals) if mesh.has_vertex_normals() else None
        self._tri = np.asarray(mesh.triangles)

    def cast(self, origins: np.ndarray, dirs: np.ndarray) -> dict[str, np.ndarray]:
        """Cast rays; the first hit of each.

        Args:
            origins: ``(..., 3)`` ray origins.
            dirs: ``(..., 3)`` ray directions (unit, so ``t`` is a distance).

        Returns:
            dict with ``t (...)`` hit distance (inf on a miss), ``tri (...)`` triangle index
            (−1 on a miss), ``uv (..., 2)`` barycentric coordinates (u, v) of the hit, the point
            being ``(1−u−v)·v0 + u·v1 + v·v2``, and ``face_normal (..., 3)`` (unit, from the
            winding).
        """
        shape = origins.shape[:-1]
        rays = np.concatenate([origins.reshape(-1, 3), dirs.reshape(-1, 3)], 1).astype(np.float32)
        ans = self.scene.cast_rays(o3d.core.Tensor(rays))
        t = ans["t_hit"].numpy().astype(np.float64)
        tri = ans["primitive_ids"].numpy().astype(np.int64)
        tri[~np.isfinite(t)] = -1
        return {"t": t.reshape(shape), "tri": tri.reshape(shape),
                "uv": ans["primitive_uvs"].numpy().astype(np.float64).reshape(*shape, 2),
                "face_normal": ans["primitive_normals"].numpy().astype(np.float64)
                .reshape(*shape, 3)}

    def vertex_normal_at(self, tri: np.ndarray, uv: np.ndarray) -> np.ndarray:
        """Barycentric interpolation of the vertex normals at hits, renormalised.

        Args:
            tri: ``(N,)`` hit triangle indices (all valid, >= 0).
            uv: ``(N, 2)`` barycentric (u, v) from :meth:`cast`.

        Returns:
            ``(N, 3)`` unit normals.
        """
        if self._vn is None:
            raise ValueError("the mesh has no vertex normals; call compute_vertex_normals()")
        f = self._tri[tri]
        u, v = uv[:, :1], uv[:, 1:2]
        n = (1 - u - v) * self._vn[f[:, 0]] + u * self._vn[f[:, 1]] + v * self._vn[f[:, 2]]
        return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
