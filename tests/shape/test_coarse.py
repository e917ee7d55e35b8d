"""Tests of voxnero/shape/coarse.py (the free-space density stage) and voxnero/shape/hull.py
(its occupancy → the SDF's start), against closed forms."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from voxnero.fields.grid import grid_points
from voxnero.fields.lights import EnvLight
from voxnero.shape import hull
from voxnero.shape.coarse import CoarseModel, render_coarse
from voxnero.shape.sampler import ray_sphere


def _ball(res: int, bound: float, radius: float) -> np.ndarray:
    b = torch.tensor([[-bound] * 3, [bound] * 3])
    return (grid_points(res, b).norm(dim=-1) <= radius).numpy()


def test_solid_fills_a_closed_shell_and_not_an_open_one():
    res, bound = 40, 1.0
    voxel = 2 * bound / (res - 1)
    b = torch.tensor([[-bound] * 3, [bound] * 3])
    r = grid_points(res, b).norm(dim=-1).numpy()
    shell = np.abs(r - 0.6) < 1.0 * voxel  # a closed shell two voxels thick
    alpha = np.where(shell, 0.9, 0.0)
    filled = hull.solid(alpha, 0.5)
    assert filled[r < 0.55].all()          # the cavity is filled
    assert not filled[r > 0.65 + voxel].any()
    cut = shell & ~(np.abs(grid_points(res, b)[..., 0].numpy()) < 0.2)  # two holes through it
    assert not hull.solid(np.where(cut, 0.9, 0.0), 0.5)[r < 0.4].any()  # the fill leaks out


def test_closing_shuts_narrow_tunnels_and_keeps_thin_rods():
    """``close``: a tunnel one voxel wide through a closed box's wall is shut (the cavity is
    filled), one nine voxels wide stays open (no fill), and a rod one voxel thin is kept
    whole (a closing never removes an occupied voxel; a blur would have)."""
    n = 32
    box = np.zeros((n, n, n), bool)
    box[4:28, 4:28, 4:28] = True
    box[6:26, 6:26, 6:26] = False  # a hollow box, walls 2 voxels thick
    narrow, wide = box.copy(), box.copy()
    narrow[15, 15, 4:6] = False             # a 1-voxel tunnel through one wall
    wide[11:20, 11:20, 4:6] = False          # a 9-voxel hole through it
    inner = (slice(8, 24),) * 3
    assert not hull.solid(narrow.astype(float), 0.5)[inner].any()       # leaks without closing
    assert hull.solid(narrow.astype(float), 0.5, close=1)[inner].all()   # shut and filled
    assert not hull.solid(wide.astype(float), 0.5, close=1)[inner].any()  # a real hole stays
    rod = np.zeros((n, n, n), bool)
    rod[16, 16, 2:30] = True
    out = hull.solid(rod.astype(float), 0.5, close=1)
    assert out[rod].all() and out.sum() == rod.sum()


@settings(max_examples=15, deadline=None)
@given(radius=st.floats(0.25, 0.8))
def test_signed_distance_of_a_voxel_ball_is_the_ball_sdf(radius):
    res, bound = 48, 1.0
    voxel = 2 * bound / (res - 1)
    inside = _ball(res, bound, radius)
    sdf = hull.signed_distance(inside, voxel)
    b = torch.tensor([[-bound] * 3, [bound] * 3])
    true = grid_points(res, b).norm(dim=-1).numpy() - radius
    near = np.abs(true) < 0.3
    # the voxel boundary lies within half a voxel of the sphere, the EDT within ~1 voxel of it
    assert np.abs(sdf - true)[near].max() < 1.2 * voxel
    assert (np.sign(sdf[np.abs(true) > voxel]) == np.sign(true[np.abs(true) > voxel])).all()


def test_signed_distance_of_empty_and_full_grids_is_finite():
    e = hull.signed_distance(np.zeros((8, 8, 8), bool), 0.1)
    f = hull.signed_distance(np.ones((8, 8, 8), bool), 0.1)
    assert np.isfinite(e).all() and (e > 0).all()
    assert np.isfinite(f).all() and (f < 0).all()


def _uniform_env():
    env = EnvLight(8, init=0.25)
    return lambda o, d: env.background(d)


def test_empty_grid_renders_the_environment():
    model = CoarseModel(16, 1.05, alpha_init=1e-9)
    o = torch.tensor([[0.0, -3.0, 0.0], [0.0, -3.0, 2.0]])
    d = torch.tensor([[0.0, 1.0, 0.0], [0.0, 1.0, 0.0]])
    out = render_coarse(model, _uniform_env(), o, d, samples=64, train=False)
    assert torch.allclose(out["rgb"], torch.full((2, 3), 0.25), atol=1e-6)
    assert out["acc"].max() < 1e-6


def test_partly_opaque_ray_composites_over_the_background_it_is_given():
    """The background is the caller's (a near field depends on the ray's origin, not only its
    direction): pixel = acc·surface + (1 − acc)·background(o, d), so two backgrounds behind
    the same rays change the pixels by exactly (1 − acc)·(difference)."""
    model = CoarseModel(16, 1.05, alpha_init=0.05)
    o = torch.tensor([[0.0, -3.0, 0.0], [0.3, -3.0, 0.1]])
    d = torch.tensor([[0.0, 1.0, 0.0], [0.0, 1.0, 0.0]])

    def near(o_, d_):
        return o_.abs() + 0.1  # differs between the two parallel rays

    def far(o_, d_):
        return torch.full_like(o_, 0.7)

    a = render_coarse(model, near, o, d, samples=64, train=False)
    b = render_coarse(model, far, o, d, samples=64, train=False)
    acc = a["acc"][:, None]
    assert 0.05 < float(acc.min().detach()) and float(acc.max().detach()) < 0.95
    assert torch.allclose(a["rgb"] - b["rgb"], (1 - acc) * (near(o, d) - far(o, d)), atol=1e-6)


@pytest.mark.parametrize("alpha_init", [1e-3, 0.02, 0.3])
def test_constant_density_opacity_is_beer_lambert(alpha_init):
    """A uniform density σ (per voxel length) over the bounding sphere: the opacity of a ray is
    1 − exp(−σ·chord/voxel) whatever the sample count (the quadrature of a constant is exact)."""
    model = CoarseModel(24, 1.05, alpha_init=alpha_init)
    gen = torch.Generator().manual_seed(0)
    o = torch.randn(64, 3, generator=gen)
    o = 3.0 * o / o.norm(dim=-1, keepdim=True)
    target = torch.nn.functional.normalize(torch.randn(64, 3, generator=gen), dim=-1)
    target = 0.9 * torch.rand(64, 1, generator=gen) * target  # inside the sphere: every ray hits
    d = torch.nn.functional.normalize(target - o, dim=-1)
    out = render_coarse(model, _uniform_env(), o, d, samples=17, train=True, generator=gen)
    near, far, hit = ray_sphere(o, d, 1.0)
    sigma = -math.log1p(-alpha_init)  # per voxel length
    expect = 1.0 - torch.exp(-sigma * (far - near) / model.density_grid.voxel)
    assert hit.all()
    assert torch.allclose(out["acc"], expect, rtol=1e-4, atol=1e-6)


def test_opaque_ball_covers_exactly_its_silhouette():
    """A high density inside a ball of radius 0.5: acc ≈ 1 for rays through it, ≈ 0 for rays that
    miss it by more than a voxel (closed-form ray–sphere distances)."""
    res, bound = 64, 1.05
    model = CoarseModel(res, bound)
    b = model.density_grid.bounds
    r = grid_points(res, b).norm(dim=-1)
    with torch.no_grad():
        model.density_grid.grid[0] = torch.where(r < 0.5, 20.0, -20.0)
    n = 200
    gen = torch.Generator().manual_seed(1)
    u = torch.rand(n, generator=gen) * 0.9  # impact parameters 0 .. 0.9
    o = torch.stack([u, torch.full((n,), -3.0), torch.zeros(n)], -1)
    d = torch.tensor([0.0, 1.0, 0.0]).expand(n, 3)
    acc = render_coarse(model, _uniform_env(), o, d, samples=256, train=False)["acc"]
    voxel = model.density_grid.voxel
    assert (acc[u < 0.5 - 2 * voxel] > 0.99).all()
    assert (acc[u > 0.5 + 2 * voxel] < 0.01).all()


def test_solid_drops_specks_but_keeps_parts_of_similar_size():
    res, bound = 40, 1.0
    b = torch.tensor([[-bound] * 3, [bound] * 3])
    p = grid_points(res, b)
    a = ((p - torch.tensor([0.4, 0.0, 0.0])).norm(dim=-1) < 0.3) \
        | ((p - torch.tensor([-0.4, 0.0, 0.0])).norm(dim=-1) < 0.25)  # two parts
    speck = (p - torch.tensor([0.0, 0.8, 0.8])).norm(dim=-1) < 0.06
    alpha = np.where((a | speck).numpy(), 0.9, 0.0)
    out = hull.solid(alpha, 0.5)
    assert (out == a.numpy()).all()


def test_fitted_box_is_the_cube_around_the_solid_with_its_margin():
    res, bound = 41, 1.0
    b = np.array([[-bound] * 3, [bound] * 3])
    inside = np.zeros((res, res, res), bool)
    inside[10:21, 5:31, 15:26] = True  # z 10..20, y 5..30, x 15..25 (voxel 0.05)
    box = hull.fitted_box(inside, b, margin=0.1, limit=1.0)
    lo = -1 + 0.05 * np.array([15, 5, 10]) - 0.1
    hi = -1 + 0.05 * np.array([25, 30, 20]) + 0.1
    assert np.allclose(box[1] - box[0], (hi - lo).max())         # a cube of the longest side
    assert np.allclose(0.5 * (box[0] + box[1]), 0.5 * (lo + hi))  # centred on the solid
    assert hull.fitted_box(np.zeros_like(inside), b, 0.1, 1.0) is None
    big = hull.fitted_box(np.ones_like(inside), b, 0.5, 1.0)      # never beyond the limit
    assert np.allclose(big, b)


def test_coarse_env_is_a_finer_copy_that_area_averages_back():
    from voxnero.render import latlong
    from voxnero.render.mip import resample_area
    from voxnero.shape.starts import coarse_env

    env = EnvLight(16)
    d = latlong.pixel_dirs(16, 32)
    with torch.no_grad():  # a smooth map: log radiance linear in the direction
        env.log_radiance.copy_(0.5 * d[..., :1] + 0.3 * d[..., 2:] + torch.tensor([0.0, -0.2, 0.1]))
    assert coarse_env(env, 0) is env and coarse_env(env, 16) is env
    fine = coarse_env(env, 64)
    assert fine is not env and fine.height == 64 and fine.max_log == env.max_log
    # the same radiance along any direction (bilinear lookups of a smooth map)
    dirs = torch.nn.functional.normalize(torch.randn(500, 3, generator=torch.Generator()
                                                     .manual_seed(0)), dim=-1)
    assert torch.allclose(fine.background(dirs), env.background(dirs), rtol=0.03)
    # area-averaged back to 16 rows (as the SDF stage receives it) the map is the original
    # (within 1.5 % away from the pole rows, whose cells average over the cap)
    rel = (resample_area(fine.image(), 16, 32) / env.image() - 1.0).abs()
    assert float(rel[1:-1].max().detach()) < 0.015 and float(rel.mean().detach()) < 0.01
