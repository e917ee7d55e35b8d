"""Occlusion targets from Open3D ray casts against the current surface.

NeRO ray-marches its SDF along reflected directions to get the target occlusion ``s_march``;
here the surface is extracted periodically (marching cubes of the SDF grid) into an Open3D
``RaycastingScene`` and ``test_occlusions`` answers whether a ray from just above the surface
along the reflected direction hits the object again (millions of rays per second on one core).

What makes the targets right on a tessellated, slightly bumpy surface (docs/STAGE1.md finding 5:
a bumpy 96³ mesh of a *convex* sphere reported self-hits):

* only rays that leave the surface count, ``d·n > 0`` (a ray into the surface is not a
  reflection; such rays come from back-facing or noisy normals and are marked invalid);
* the ray starts ``offset`` mesh edge lengths above the surface along the normal and ignores hits
  closer than ``t_near`` edge lengths: both are in units of the mesh's own mean edge length, so
  the same values work for a 48³ or a 96³ extraction (a fixed unit-frame offset is ~4 facets on
  a coarse mesh but 8 on a fine one);
* the mesh can be Taubin-smoothed first (volume preserving), which removes voxel-scale bumps
  that a grazing reflected ray would clip.
"""

from __future__ import annotations

import numpy as np
import open3d as o3d
import torch

OFFSET_EDGES = 1.0
"""Default start offset along the normal, in mean edge lengths of the mesh."""
T_NEAR_EDGES = 2.0
"""Default: hits closer than this many mean edge lengths are the facet the ray starts on."""


def mean_edge_length(mesh: o3d.geometry.TriangleMesh) -> float:
    """Mean length of the triangle edges of ``mesh`` (each edge counted once per triangle).

    Args:
        mesh: Open3D legacy triangle mesh with at least one triangle.

    Returns:
        Mean edge length in the mesh's units (0 for a mesh without triangles).
    """
    v = np.asarray(mesh.vertices)
    t = np.asarray(mesh.triangles)
    if len(t) == 0:
        return 0.0
    e = np.concatenate([v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 1]],
                        v[t[:, 0]] - v[t[:, 2]]])
    return float(np.linalg.norm(e, axis=1).mean())


def smooth_mesh(mesh: o3d.geometry.TriangleMesh, iterations: int) -> o3d.geometry.TriangleMesh:
    """Taubin-smoothed copy of ``mesh`` (λ/μ filter, keeps the volume; 0 iterations = copy)."""
    out = o3d.geometry.TriangleMesh(mesh)
    if iterations > 0:
        out = out.filter_smooth_taubin(number_of_iterations=int(iterations))
    out.compute_vertex_normals()
    return out


def trim_mesh(mesh: o3d.geometry.TriangleMesh, radius: float = 1.0,
              min_fraction: float = 0.01) -> o3d.geometry.TriangleMesh:
    """The part of an extracted surface that the renderer can see.

    Marching cubes of the whole grid cube also finds surfaces outside the sampling sphere (the
    renderer never samples there, so nothing carves them) and small floaters; both would
    "occlude" reflected rays that the rendered images never saw blocked.

    Args:
        mesh: Open3D legacy triangle mesh (unit frame).
        radius: keep triangles whose three vertices lie inside this sphere around the origin
            (``sampling.radius``).
        min_fraction: then drop connected components with fewer than this fraction of the
            remaining triangles.

    Returns:
        A new mesh (possibly empty).
    """
    out = o3d.geometry.TriangleMesh(mesh)
    v = np.asarray(out.vertices)
    t = np.asarray(out.triangles)
    if len(t) == 0:
        return out
    inside = np.linalg.norm(v, axis=1) <= radius
    out.remove_triangles_by_mask(~inside[t].all(1))
    if len(out.triangles) and min_fraction > 0:
        labels, counts, _ = out.cluster_connected_triangles()
        counts = np.asarray(counts)
        small = counts < min_fraction * counts.sum()
        out.remove_triangles_by_mask(small[np.asarray(labels)])
    out.remove_unreferenced_vertices()
    return out


class OcclusionTargets:
    """Ray-cast occlusion targets against a triangle mesh (unit frame).

    Args:
        mesh: Open3D legacy ``TriangleMesh`` in the unit frame.
        offset: start the test ray this many **mean edge lengths** above the surface, along
            the normal.
        t_near: ignore hits closer than this many mean edge lengths along the ray.
        smooth: Taubin smoothing iterations applied to the mesh first (0 = none).
    """

    def __init__(self, mesh: o3d.geometry.TriangleMesh, offset: float = OFFSET_EDGES,
                 t_near: float = T_NEAR_EDGES, smooth: int = 0):
        mesh = smooth_mesh(mesh, smooth) if smooth > 0 else mesh
        self.edge = mean_edge_length(mesh)
        self.offset = offset * self.edge
        """Start offset in unit-frame length."""
        self.t_near = t_near * self.edge
        """Minimum hit distance in unit-frame length."""
        self.scene = o3d.t.geometry.RaycastingScene()
        self.scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))

    def test(self, x: torch.Tensor, n: torch.Tensor, d: torch.Tensor
             ) -> tuple[torch.Tensor, torch.Tensor]:
        """Whether rays from surface points along ``d`` hit the mesh, and which rays count.

        Args:
            x: ``(N, 3)`` surface points (unit frame).
            n: ``(N, 3)`` unit outward normals at ``x``.
            d: ``(N, 3)`` unit directions leaving the surface (e.g. reflected view directions).

        Returns:
            ``(occ (N, 1) float32, valid (N,) bool)`` on ``x``'s device: ``occ`` is 1 where the
            ray hits the mesh farther than ``t_near``, else 0; ``valid`` is ``d·n > 0`` (rays
            into the surface are not reflections; their ``occ`` is 0 and must not be used).
        """
        valid = (d * n).sum(-1) > 0
        start = (x + self.offset * n).detach().cpu().numpy().astype(np.float32)
        rays = np.concatenate([start, d.detach().cpu().numpy().astype(np.float32)], 1)
        occ = self.scene.test_occlusions(o3d.core.Tensor(rays), tnear=self.t_near).numpy()
        occ = torch.from_numpy(occ.astype(np.float32))[:, None].to(x.device)
        return occ * valid[:, None].to(occ.dtype), valid

    def __call__(self, x: torch.Tensor, n: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
        """Occlusion targets ``(N, 1)`` (1 occluded, 0 free or invalid); see :meth:`test`."""
        return self.test(x, n, d)[0]


def camera_surface_rays(mesh: o3d.geometry.TriangleMesh, origins: np.ndarray, dirs: np.ndarray
                        ) -> dict[str, np.ndarray]:
    """Cast view rays at a mesh: the surface points the cameras see and their reflections.

    Args:
        mesh: Open3D legacy triangle mesh (unit frame).
        origins: ``(R, 3)`` ray origins; dirs: ``(R, 3)`` unit view directions (camera → scene).

    Returns:
        dict with, for the rays that hit (H of them): ``x (H, 3)`` hit points, ``n (H, 3)``
        unit facet normals oriented against the view ray, ``refl (H, 3)`` reflected directions
        ``d − 2(d·n)n`` (``refl·n > 0``), and ``hit (R,)`` bool.
    """
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
    rays = np.concatenate([origins, dirs], 1).astype(np.float32)
    ans = scene.cast_rays(o3d.core.Tensor(rays))
    t = ans["t_hit"].numpy()
    hit = np.isfinite(t)
    n = ans["primitive_normals"].numpy()[hit].astype(np.float64)
    d = dirs[hit].astype(np.float64)
    x = origins[hit] + t[hit, None] * d
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    n = np.where(((n * d).sum(1) > 0)[:, None], -n, n)  # face the camera
    refl = d - 2.0 * (d * n).sum(1, keepdims=True) * n
    return {"x": x, "n": n, "refl": refl, "hit": hit}


def reflected_hit_fraction(mesh: o3d.geometry.TriangleMesh, origins: np.ndarray,
                           dirs: np.ndarray, offset: float = OFFSET_EDGES,
                           t_near: float = T_NEAR_EDGES, smooth: int = 0
                           ) -> tuple[float, int]:
    """Fraction of the cameras' reflected rays that hit the object again (self-occlusion).

    Casts the view rays at ``mesh``, reflects them at the visible surface about the facet normal
    and tests the reflected rays with :class:`OcclusionTargets` (same offset / ``t_near`` /
    smoothing rules as the training targets).

    Args:
        mesh: Open3D legacy triangle mesh (unit frame).
        origins: ``(R, 3)`` view-ray origins; dirs: ``(R, 3)`` unit view directions.
        offset, t_near: in mean edge lengths (see :class:`OcclusionTargets`).
        smooth: Taubin iterations before testing.

    Returns:
        ``(fraction in [0, 1], number of reflected rays tested)``; ``(0.0, 0)`` if no view ray
        hits the mesh.
    """
    mesh = smooth_mesh(mesh, smooth) if smooth > 0 else mesh
    s = camera_surface_rays(mesh, origins, dirs)
    if len(s["x"]) == 0:
        return 0.0, 0
    tg = OcclusionTargets(mesh, offset, t_near)
    occ, valid = tg.test(torch.from_numpy(s["x"]).float(), torch.from_numpy(s["n"]).float(),
                         torch.from_numpy(s["refl"]).float())
    k = int(valid.sum())
    return (float(occ[valid].sum()) / k if k else 0.0), k
