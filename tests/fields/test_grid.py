"""Tests of voxnero/fields/grid.py against closed forms, grid_sample and finite differences."""

from __future__ import annotations

import math

import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from voxnero.fields.grid import (
    DenseGrid,
    SDFGrid,
    grid_points,
    grid_sample_points,
    resample,
    trilinear_value_grad,
)


def _rand_grid(res=(5, 6, 7), seed=0):
    g = torch.Generator().manual_seed(seed)
    return torch.randn(*res, generator=g, dtype=torch.float64)


def test_value_matches_grid_sample():
    grid = _rand_grid()
    b = torch.tensor([[-1.0, -0.5, -2.0], [1.0, 0.7, 1.5]], dtype=torch.float64)
    pts = torch.rand(500, 3, dtype=torch.float64) * (b[1] - b[0]) + b[0]
    v, _ = trilinear_value_grad(grid, pts, b)
    ref = grid_sample_points(grid[None], pts, b)[:, 0]
    assert torch.allclose(v, ref, atol=1e-10)


def test_exact_at_corners_and_xyz_order():
    grid = _rand_grid()
    b = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]], dtype=torch.float64)
    p = grid_points(grid.shape, b)  # (D, H, W, 3) x,y,z
    v, _ = trilinear_value_grad(grid, p.reshape(-1, 3), b)
    assert torch.allclose(v, grid.reshape(-1), atol=1e-12)


def test_linear_field_reproduced_with_exact_gradient():
    # a trilinear grid reproduces any affine field exactly, value and gradient
    b = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]], dtype=torch.float64)
    a = torch.tensor([0.3, -1.2, 2.0], dtype=torch.float64)
    p = grid_points((9, 8, 7), b)
    grid = (p @ a) + 0.25
    q = torch.rand(300, 3, dtype=torch.float64) * 2 - 1
    v, g = trilinear_value_grad(grid, q, b)
    assert torch.allclose(v, q @ a + 0.25, atol=1e-10)
    assert torch.allclose(g, a.expand_as(g), atol=1e-10)


@settings(max_examples=30, deadline=None)
@given(st.floats(-0.99, 0.99), st.floats(-0.99, 0.99), st.floats(-0.99, 0.99))
def test_gradient_matches_finite_difference(x, y, z):
    grid = _rand_grid((6, 6, 6), seed=3)
    b = torch.tensor([[-1.0] * 3, [1.0] * 3], dtype=torch.float64)
    p = torch.tensor([[x, y, z]], dtype=torch.float64)
    # stay inside one cell for the central difference (cell size 0.4)
    u = (p + 1) / 0.4
    frac = u - torch.floor(u)
    if ((frac < 1e-3) | (frac > 1 - 1e-3)).any():
        return
    _, g = trilinear_value_grad(grid, p, b)
    h = 1e-6
    fd = []
    for i in range(3):
        e = torch.zeros(1, 3, dtype=torch.float64)
        e[0, i] = h
        fp = trilinear_value_grad(grid, p + e, b, with_grad=False)[0]
        fm = trilinear_value_grad(grid, p - e, b, with_grad=False)[0]
        fd.append((fp - fm) / (2 * h))
    assert torch.allclose(g[0], torch.cat(fd), atol=1e-6)


def test_sphere_init_is_sdf_and_gradients_flow():
    g = SDFGrid(48, bound=1.0, radius=0.6)
    pts = torch.randn(1000, 3)
    pts = pts / pts.norm(dim=-1, keepdim=True) * torch.empty(1000, 1).uniform_(0.3, 0.9)
    v, grad = g.sdf_grad(pts)
    assert (v - (pts.norm(dim=-1) - 0.6)).abs().max() < 0.02  # ≈ voxel²/(2r)
    assert ((grad.norm(dim=-1) - 1).abs().mean()) < 0.02
    vf, gf = g.sdf_grad(pts, mode="fd")
    assert torch.allclose(vf, v, atol=1e-5)
    assert (gf - grad).norm(dim=-1).mean() < 0.03
    (v.sum() + grad.sum()).backward()
    assert g.grid.grad is not None and g.grid.grad.abs().sum() > 0


def test_upsample_keeps_field():
    grid = DenseGrid(1, 9, 1.0, init=_rand_grid((9, 9, 9)).float()[None])
    q = torch.rand(200, 3) * 2 - 1
    before = grid(q)
    grid.upsample(17)  # 17 = 2·9 − 1: old corners are new corners, field is identical
    assert grid.res == 17
    assert torch.allclose(grid(q), before, atol=1e-5)
    assert resample(grid.grid.data, 17).shape == (1, 17, 17, 17)


def test_gaussian_blur_constant_linear_and_mass():
    from voxnero.fields.grid import gaussian_blur3d

    c = torch.full((9, 10, 11), 2.5, dtype=torch.float64)
    assert torch.allclose(gaussian_blur3d(c, 1.0), c)
    # a linear ramp is preserved away from the borders (symmetric kernel)
    b = torch.tensor([[-1.0] * 3, [1.0] * 3], dtype=torch.float64)
    ramp = grid_points((12, 12, 12), b) @ torch.tensor([0.2, -0.5, 0.7], dtype=torch.float64)
    out = gaussian_blur3d(ramp, 1.0)
    assert torch.allclose(out[3:-3, 3:-3, 3:-3], ramp[3:-3, 3:-3, 3:-3], atol=1e-10)
    # an impulse spreads with unit mass and the 1-D Gaussian profile
    x = torch.zeros(15, 15, 15, dtype=torch.float64)
    x[7, 7, 7] = 1
    y = gaussian_blur3d(x, 1.0)
    assert abs(float(y.sum()) - 1) < 1e-12
    ratio = float(y[7, 7, 8] / y[7, 7, 7])
    assert abs(ratio - math.exp(-0.5)) < 1e-9
