"""Material fields: interpolation, axis order of the grid, smoothness, activation ranges."""

from __future__ import annotations

import math

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from tests.material.stage2_scene import sphere_geometry
from voxnero.material.field import (
    GridMaterial,
    VertexMaterial,
    activate,
    edge_penalty,
    surface_materials,
)
from voxnero.render.brdf import brdf_eval
from voxnero.render.microfacet import ALPHA_MIN, ROUGHNESS_MIN


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
        assert torch.allclose(f(t, b)[2][0, 0], activate(f.raw[v])[2], atol=1e-6)
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
    r01 = (r[:, 0] - ROUGHNESS_MIN) / (1 - ROUGHNESS_MIN)
    assert torch.allclose(torch.logit(r01), x[:, 0], atol=1e-4)
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


def test_grid_total_variation_closed_form():
    """The "l1" norm of the same step: Charbonnier sqrt(J² + eps²) − eps of the RAW step on the
    crossing pairs, whatever the base (saturating the sigmoid cannot lower it)."""
    f = GridMaterial(res=4)
    with torch.no_grad():
        f.base.zero_()
        f.grid[0, 0, :, :, 2:] = 0.7
    want = torch.tensor((math.sqrt(0.7**2 + 1e-6) - 1e-3) * (16 / 48))
    assert torch.allclose(f.smoothness(norm="l1"), want, rtol=1e-5)
    with torch.no_grad():
        f.base.fill_(8.0)  # every channel deep in the sigmoid's tail
    assert torch.allclose(f.smoothness(norm="l1"), want, rtol=1e-5)
    assert float(f.smoothness(norm="l2").detach()) < 1e-6 * float(want)


@settings(max_examples=30, deadline=None)
@given(jump=st.floats(0.05, 0.9), n=st.integers(2, 50))
def test_total_variation_charges_a_ramp_like_a_step_and_squares_do_not(jump, n):
    """A ramp of height J in n equal steps: "l1" costs ~J (as the single step), "l2" J²/n.
    This is why "l1" does not let a slow albedo ramp imitate shading for free."""
    d_ramp = torch.zeros(n, 5)
    d_ramp[:, 0] = jump / n
    d_step = torch.zeros(1, 5)
    d_step[0, 0] = jump
    l1_ramp, l1_step = edge_penalty(d_ramp, "l1").sum(), edge_penalty(d_step, "l1").sum()
    l2_ramp, l2_step = edge_penalty(d_ramp, "l2").sum(), edge_penalty(d_step, "l2").sum()
    assert abs(float(l1_ramp) - jump) < n * 1e-3 + 1e-6
    assert abs(float(l1_step) - jump) < 1e-3
    assert math.isclose(float(l2_ramp), jump**2 / n, rel_tol=1e-4)
    assert math.isclose(float(l2_step), jump**2, rel_tol=1e-5)


def test_edge_penalty_names_an_unknown_norm():
    with pytest.raises(ValueError, match="l1"):
        edge_penalty(torch.zeros(2, 5), "huber")


def test_activation_ranges_and_vertex_export():
    raw = torch.tensor([[-50.0, 0.0, 50.0, -50.0, 50.0]])
    a, m, r = activate(raw)
    assert a.min() >= 0 and a.max() <= 1 and m.item() < 1e-6 and r.item() > 1 - 1e-6
    geom = sphere_geometry(0.5, 8)
    for f in (VertexMaterial(geom, 0.4, 0.1, 0.6), GridMaterial(8, 0.4, 0.1, 0.6)):
        vid, tris, a, m, r = surface_materials(f, geom)
        assert torch.equal(vid, torch.arange(geom.n_vertices))
        assert torch.equal(tris, geom.triangles.long())
        assert a.shape == (geom.n_vertices, 3) and m.shape == (geom.n_vertices, 1)
        assert torch.allclose(r, torch.full_like(r, 0.6), atol=1e-5)


@settings(max_examples=60, deadline=None)
@given(st.floats(-40.0, 40.0))
def test_roughness_has_no_dead_zone_at_the_brdf_clamp(raw_r):
    """Every raw roughness maps to r >= sqrt(ALPHA_MIN), where the BRDF's alpha clamp does not
    bite, so a mirror-ward slide can always be undone: the BRDF off the mirror direction (10°
    off the reflection) has a non-zero derivative w.r.t. the raw value. A plain sigmoid gave
    r = 0.012 (duck) with an exactly zero derivative."""
    raw = torch.tensor([0.0, 0.0, 0.0, -5.0, raw_r], dtype=torch.float64, requires_grad=True)
    _, _, r = activate(raw)
    assert float(r.detach()) >= ROUGHNESS_MIN * (1 - 1e-12)
    assert float(r.detach()) ** 2 >= ALPHA_MIN * (1 - 1e-9)
    n = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
    v = torch.tensor([math.sin(0.5), 0.0, math.cos(0.5)], dtype=torch.float64)
    off = 0.5 + math.radians(10.0)
    l = torch.tensor([-math.sin(off), 0.0, math.cos(off)], dtype=torch.float64)
    a, m, r = activate(raw)
    f = brdf_eval(n, v, l, a, m, r).sum()
    (g,) = torch.autograd.grad(f, raw)
    if raw_r < 30:  # sigmoid's own slope underflows float64 beyond (r = 1: the rough end)
        assert float(g[4]) != 0.0
