"""Material fields: interpolation, axis order of the grid, smoothness, activation ranges."""

from __future__ import annotations

import torch

from tests.material.stage2_scene import sphere_geometry
from voxnero.material.field import GridMaterial, VertexMaterial, activate, vertex_materials


def test_vertex_field_interpolates_and_initialises():
    geom = sphere_geometry(0.5, 16)
    f = VertexMaterial(geom, albedo=0.3, metallic=0.7, roughness=0.2)
    tri = torch.arange(10)
    bary = torch.full((10, 3), 1 / 3)
    a, m, r = f(tri, bary)
    assert torch.allclose(a, torch.full_like(a, 0.3), atol=1e-5)
    assert torch.allclose(m, torch.full_like(m, 0.7), atol=1e-5)
    assert torch.allclose(r, torch.full_like(r, 0.2), atol=1e-5)
    assert float(f.smoothness().detach()) < 1e-10
    # at a vertex (bary = e_k) the value is that vertex's own
    with torch.no_grad():
        f.residual[:, 4] = torch.linspace(-3, 3, geom.n_vertices)
    t = torch.tensor([5])
    for k in range(3):
        b = torch.zeros(1, 3)
        b[0, k] = 1
        v = geom.triangles[5, k]
        assert torch.allclose(f(t, b)[2][0, 0], torch.sigmoid(f.raw[v, 4]), atol=1e-6)
    assert float(f.smoothness().detach()) > 0


def test_grid_axis_order_matches_point_coordinates():
    f = GridMaterial(res=9)
    c = torch.linspace(-1, 1, 9)
    with torch.no_grad():
        f.base.zero_()
        # tensor axes are (z, y, x): make the roughness logit equal to x, metallic to z
        f.grid[0, 4] = c.view(1, 1, 9).expand(9, 9, 9)
        f.grid[0, 3] = c.view(9, 1, 1).expand(9, 9, 9)
    g = torch.Generator().manual_seed(0)
    x = torch.rand(100, 3, generator=g) * 2 - 1
    a, m, r = f(None, None, x)
    assert torch.allclose(torch.logit(r[:, 0]), x[:, 0], atol=1e-4)
    assert torch.allclose(torch.logit(m[:, 0]), x[:, 2], atol=1e-4)


def test_grid_smoothness_closed_form():
    f = GridMaterial(res=4)
    with torch.no_grad():
        f.base.zero_()
        f.grid[0, 0, :, :, 2:] = 10.0  # a step along x in albedo R: sigmoid 0.5 -> ~1
    step = torch.sigmoid(torch.tensor(10.0)) - 0.5
    # one of the 3 x-differences per row is the step; mean over 4*4*3 x-pairs
    want = step**2 * (16 / 48)
    assert torch.allclose(f.smoothness(), want, rtol=1e-5)


def test_activation_ranges_and_vertex_export():
    raw = torch.tensor([[-50.0, 0.0, 50.0, -50.0, 50.0]])
    a, m, r = activate(raw)
    assert a.min() >= 0 and a.max() <= 1 and m.item() < 1e-6 and r.item() > 1 - 1e-6
    geom = sphere_geometry(0.5, 8)
    for f in (VertexMaterial(geom, 0.4, 0.1, 0.6), GridMaterial(8, 0.4, 0.1, 0.6)):
        a, m, r = vertex_materials(f, geom)
        assert a.shape == (geom.n_vertices, 3) and m.shape == (geom.n_vertices, 1)
        assert torch.allclose(r, torch.full_like(r, 0.6), atol=1e-5)
