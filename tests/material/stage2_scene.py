"""Shared test helpers for stage 2: an analytic-sphere scene rendered by the stage-2 estimator."""

from __future__ import annotations

import math

import numpy as np
import open3d as o3d
import torch

from tests.fixtures.cameras import look_at
from voxnero.cameras.cameras import Cameras
from voxnero.material.surface import Geometry


def sphere_geometry(radius: float = 0.5, resolution: int = 40) -> Geometry:
    """A UV-sphere mesh (unit frame) wrapped as a stage-2 Geometry."""
    m = o3d.geometry.TriangleMesh.create_sphere(radius, resolution)
    m.compute_vertex_normals()
    return Geometry.from_legacy(m)


def smooth_env(height: int = 32, seed: int = 0) -> torch.Tensor:
    """A known HDR env map: sky gradient, darker ground and a few bright soft lights.

    Returns:
        (H, 2H, 3) linear radiance.
    """
    from voxnero.render.latlong import pixel_dirs

    g = torch.Generator().manual_seed(seed)
    d = pixel_dirs(height, 2 * height)
    z = d[..., 2:3]
    img = torch.where(z > 0, 0.3 + 0.4 * z * torch.tensor([0.6, 0.8, 1.0]),
                      0.15 * torch.tensor([1.0, 0.9, 0.7]) + 0 * z)
    for _ in range(4):
        c = torch.nn.functional.normalize(torch.randn(3, generator=g), dim=0)
        col = 0.5 + torch.rand(3, generator=g)
        img = img + 6.0 * col * torch.exp(((d * c).sum(-1, keepdim=True) - 1) / 0.02)
    return img.float()


def ring_cameras(n: int, size: int = 48, dist: float = 2.5, fov_deg: float = 40.0) -> Cameras:
    """n OpenCV cameras on a Fibonacci band looking at the origin, +Z up."""
    f = 0.5 * size / math.tan(math.radians(fov_deg) / 2)
    K = np.array([[f, 0, size / 2], [0, f, size / 2], [0, 0, 1]])
    c2w = []
    for i in range(n):
        z = -0.3 + 1.2 * (i + 0.5) / n
        z = min(z, 0.95)
        phi = i * math.pi * (3 - math.sqrt(5))
        r = math.sqrt(1 - z * z)
        c2w.append(look_at(dist * np.array([r * math.cos(phi), r * math.sin(phi), z])))
    return Cameras(np.repeat(K[None], n, 0), np.stack(c2w), size, size)
