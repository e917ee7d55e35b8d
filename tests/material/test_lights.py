"""Env map of stage 2: initialisation from background pixels, upsampling, SH irradiance,
indirect-light estimate."""

from __future__ import annotations

import math

import torch

from voxnero.material.lights import (
    EnvLight,
    IndirectLight,
    init_from_background,
    irradiance_sh,
    sh_basis,
)
from voxnero.render.envmap import envmap_lookup, pixel_dirs


def test_init_from_background_recovers_pixel_values_and_fills_the_rest():
    H = 8
    g = torch.Generator().manual_seed(0)
    truth = torch.rand(H, 2 * H, 3, generator=g)
    d = pixel_dirs(H, 2 * H).reshape(-1, 3)
    # the upper part is seen; pole rows are left out (all their columns share one direction)
    up = (d[:, 2] > 0.1) & (d[:, 2] < 0.99)
    img = init_from_background(d[up], truth.reshape(-1, 3)[up], H)
    assert torch.allclose(img.reshape(-1, 3)[up], truth.reshape(-1, 3)[up], atol=1e-5)
    mean = truth.reshape(-1, 3)[up].mean(0)
    low = d[:, 2] <= 0.1
    assert torch.allclose(img.reshape(-1, 3)[low], mean.expand(int(low.sum()), 3), atol=1e-5)


def test_envlight_lookup_and_upsampling_keep_the_map():
    H = 16
    d = pixel_dirs(H, 2 * H)
    base = 0.5 + 0.4 * d[..., :1] * torch.tensor([1.0, 0.5, 0.2]) + 0.3 * d[..., 2:3]
    env = EnvLight(base)
    assert torch.allclose(env.lookup(d), base, rtol=1e-4)
    up = env.upsampled(32)
    assert up.log_rad.shape == (32, 64, 3)
    # a smooth map stays (nearly) the same function of direction, including across u = 0
    g = torch.Generator().manual_seed(1)
    q = torch.nn.functional.normalize(torch.randn(500, 3, generator=g), dim=-1)
    assert torch.allclose(up.lookup(q), env.lookup(q), rtol=0.02, atol=0.01)
    assert float(EnvLight(torch.ones(4, 8, 3)).smoothness().detach()) < 1e-12


def test_sh_irradiance_of_a_linear_map_is_exact():
    """L(d) = 1 + 0.5 d_z  ->  E(n) = pi + (2 pi / 3) 0.5 n_z (only orders 0 and 1)."""
    H = 64
    d = pixel_dirs(H, 2 * H)
    img = (1 + 0.5 * d[..., 2:3]).expand(H, 2 * H, 3).contiguous()
    c = irradiance_sh(img)
    g = torch.Generator().manual_seed(2)
    n = torch.nn.functional.normalize(torch.randn(100, 3, generator=g), dim=-1)
    E = sh_basis(n) @ c
    want = math.pi + 2 * math.pi / 3 * 0.5 * n[:, 2:3]
    assert torch.allclose(E, want.expand(-1, 3), rtol=2e-3)


def test_sh_irradiance_matches_brute_force_cosine_integral():
    """Smooth map: order-2 SH irradiance vs a direct sum of L max(n.l, 0) dω over pixels (the
    SH truncation error of a smooth map is small: within 3 %)."""
    from voxnero.render.envmap import pixel_solid_angles

    H = 48
    d = pixel_dirs(H, 2 * H)
    img = (1.0 + torch.exp(((d * torch.tensor([0.3, 0.4, 0.866])).sum(-1, keepdim=True) - 1)
                           / 0.5)).expand(H, 2 * H, 3).contiguous()
    om = pixel_solid_angles(H, 2 * H)
    n = torch.nn.functional.normalize(torch.tensor([[0.0, 0, 1], [1.0, 0, 0], [0, -1.0, -1]]),
                                      dim=-1)
    brute = torch.einsum("hw,nhw->n", om * img[..., 0],
                         (d[None] * n[:, None, None]).sum(-1).clamp_min(0))
    E = (sh_basis(n) @ irradiance_sh(img))[:, 0]
    assert torch.allclose(E, brute, rtol=0.03)


def test_indirect_radiance_in_a_white_furnace():
    """Constant unit env: the estimate is (1 - m)(1 - E_d) a + F0 A + B (split-sum directional
    albedo; E_d = 0.04 A + B is what the dielectric interface reflects)."""
    from voxnero.render.splitsum import split_sum_lookup

    ind = IndirectLight(torch.ones(16, 32, 3))
    n = torch.tensor([[0.0, 0.0, 1.0]] * 2)
    w = torch.nn.functional.normalize(torch.tensor([[0.3, 0.0, 1.0], [0.0, 0.0, -1.0]]), dim=-1)
    a = torch.tensor([[0.5, 0.6, 0.7]] * 2)
    m = torch.tensor([[0.3]] * 2)
    r = torch.tensor([[0.4]] * 2)
    L = ind.radiance(n, w, a, m, r)
    A, B = split_sum_lookup(w[:1, 2], r[:1, 0])
    e_d = 0.04 * A + B
    want = (1 - m[0]) * (1 - e_d) * a[0] + (0.04 * (1 - m[0]) + m[0] * a[0]) * A + B
    assert torch.allclose(L[0], want, rtol=5e-3)
    assert torch.equal(L[1], torch.zeros(3))  # seen from below the surface
    assert torch.allclose(envmap_lookup(ind.blur, w), torch.ones(2, 3))
