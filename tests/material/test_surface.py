"""Primary-hit cache and ray casts of stage 2 against an analytic sphere."""

from __future__ import annotations

import numpy as np
import open3d as o3d
import torch

from tests.material.stage2_scene import ring_cameras, sphere_geometry
from voxnero.cameras.rays import image_rays
from voxnero.material.surface import RAY_EPS, Geometry, build_cache

R = 0.5


def _analytic_hit(o: torch.Tensor, d: torch.Tensor, r: float) -> torch.Tensor:
    b = (o * d).sum(-1)
    c = (o * o).sum(-1) - r * r
    return b * b - c > 0


def test_cache_labels_points_normals_views():
    geom = sphere_geometry(R, 60)
    cams = ring_cameras(3, 40)
    imgs = torch.rand(3, 40, 40, 3)
    cache = build_cache(geom, imgs, cams, max_pixels=0)
    # every kept object pixel's centre ray hits the analytic sphere (tessellation < 1e-3 of r,
    # silhouette pixels are excluded), every kept background ray misses it
    o, d = image_rays(cams, 0)
    assert cache.x.shape[0] > 500 and cache.bg_dirs.shape[0] > 1000
    r = cache.x.norm(dim=-1)
    assert (r - R).abs().max() < 2e-3
    assert torch.allclose(cache.n, cache.x / r[:, None], atol=1e-2)
    assert ((cache.n * cache.v).sum(-1) > 0).all()
    centres = torch.stack([torch.as_tensor(cams.c2w[i, :3, 3]) for i in range(3)])
    # v points from x to one of the cameras
    to_cam = torch.nn.functional.normalize(centres[None] - cache.x[:, None], dim=-1)
    best = (to_cam * cache.v[:, None]).sum(-1).max(1).values
    assert (best > 1 - 1e-5).all()
    # background directions miss the analytic sphere from every camera they could come from
    miss = torch.stack([~_analytic_hit(centres[i].expand_as(cache.bg_dirs), cache.bg_dirs, R)
                        for i in range(3)], 1)
    assert miss.any(1).all()
    # images were copied per pixel
    assert cache.rgb.shape == cache.x.shape and cache.rgb.max() <= 1


def test_silhouette_pixels_are_excluded():
    geom = sphere_geometry(R, 60)
    cams = ring_cameras(1, 40)
    cache = build_cache(geom, torch.zeros(1, 40, 40, 3), cams, max_pixels=0)
    o, d = image_rays(cams, 0)
    hit = _analytic_hit(o.reshape(-1, 3), d.reshape(-1, 3), R).sum()
    # kept object + kept background < all pixels: the ring of silhouette pixels is dropped
    assert cache.x.shape[0] < hit
    assert cache.x.shape[0] + cache.bg_dirs.shape[0] < 40 * 40


def test_subsampling_keeps_at_most_max_pixels():
    geom = sphere_geometry(R, 30)
    cams = ring_cameras(2, 32)
    g = torch.Generator().manual_seed(0)
    cache = build_cache(geom, torch.zeros(2, 32, 32, 3), cams, max_pixels=100, generator=g,
                        max_bg_pixels=50)
    assert cache.x.shape[0] == 100 and cache.bg_dirs.shape[0] == 50
    assert cache.n_object_total > 100


def test_occlusion_between_two_spheres_and_spawned_rays_do_not_self_hit():
    a = o3d.geometry.TriangleMesh.create_sphere(0.3, 40)
    b = o3d.geometry.TriangleMesh.create_sphere(0.3, 40).translate([1.0, 0, 0])
    geom = Geometry.from_legacy(a + b)
    # leave sphere a at its +X pole toward +X: blocked by b; toward +Z: free
    o = torch.tensor([[0.3, 0.0, 0.0]] * 2)
    _, tri, bary = geom.cast(torch.tensor([[2.0, 0, 0], [0.3, 0, 2.0]]),
                             torch.tensor([[-1.0, 0, 0], [0, 0, -1.0]]))
    # ray from +2 toward -X first hits sphere b at x = 1.3
    assert np.isclose(float(geom.points_at(tri[:1], bary[:1])[0, 0]), 1.3, atol=2e-3)
    l = torch.tensor([[1.0, 0, 0], [0, 0, 1.0]])
    _, tri0, _ = geom.cast(torch.tensor([[2.0, 0, 0]]) * 0 + torch.tensor([[0.5, 0, 0]]),
                           torch.tensor([[-1.0, 0, 0]]))
    x = o
    spawned = geom.spawn(tri0.expand(2), x, l)
    assert ((spawned - x).norm(dim=-1) <= RAY_EPS * 1.001).all()
    occ = geom.occluded(spawned, l)
    assert occ.tolist() == [True, False]


def test_interpolation_reproduces_linear_functions():
    geom = sphere_geometry(R, 20)
    g = torch.Generator().manual_seed(1)
    tri = torch.randint(0, geom.triangles.shape[0], (200,), generator=g)
    w = torch.rand(200, 3, generator=g)
    bary = w / w.sum(-1, keepdim=True)
    A = torch.randn(3, 2, generator=g)
    vals = geom.vertices @ A
    got = geom.interpolate(vals, tri, bary)
    want = geom.points_at(tri, bary) @ A
    assert torch.allclose(got, want, atol=1e-5)
