"""Occlusion targets from Open3D ray casts against the current surface.

NeRO ray-marches its SDF along reflected directions to get the target occlusion ``s_march``;
here the surface is extracted periodically (marching cubes of the SDF grid) into an Open3D
``RaycastingScene`` and ``test_occlusions`` answers whether a ray from just above the surface
along the reflected direction hits the object again (millions of rays per second on one core).
"""

from __future__ import annotations

import numpy as np
import open3d as o3d
import torch


class OcclusionTargets:
    """Ray-cast occlusion targets against a triangle mesh (unit frame).

    Args:
        mesh: Open3D legacy ``TriangleMesh`` in the unit frame.
        offset: start the test ray this far along the normal (unit-frame length) to leave the
            surface it starts on.
    """

    def __init__(self, mesh: o3d.geometry.TriangleMesh, offset: float = 0.01):
        self.scene = o3d.t.geometry.RaycastingScene()
        self.scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
        self.offset = offset

    def __call__(self, x: torch.Tensor, n: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
        """Whether rays from surface points hit the mesh.

        Args:
            x: ``(N, 3)`` surface points; n: ``(N, 3)`` unit normals; d: ``(N, 3)`` unit
                directions (e.g. reflected view directions).

        Returns:
            ``(N, 1)`` float32 on ``x``'s device: 1 occluded, 0 free.
        """
        start = (x + self.offset * n).detach().cpu().numpy().astype(np.float32)
        rays = np.concatenate([start, d.detach().cpu().numpy().astype(np.float32)], 1)
        occ = self.scene.test_occlusions(o3d.core.Tensor(rays)).numpy()
        return torch.from_numpy(occ.astype(np.float32))[:, None].to(x.device)
