"""Tests of voxnero/render/sh.py: orthonormality, closed forms of the basis, and the SH irradiance
of maps whose convolution with the cosine lobe is known in closed form."""

from __future__ import annotations

import math

import numpy as np
import torch

from voxnero.render.latlong import pixel_dirs, pixel_solid_angles
from voxnero.render.sh import sh9_irradiance, sh9_project, sh_basis


def _sphere_quadrature(n: int = 40):
    """Gauss-Legendre in z x uniform phi: exact for polynomials of degree < 2n in z."""
    z, w = np.polynomial.legendre.leggauss(n)
    z, w = torch.from_numpy(z), torch.from_numpy(w)
    P = 2 * n
    phi = (torch.arange(P, dtype=torch.float64) + 0.5) * 2 * math.pi / P
    Z, PH = torch.meshgrid(z, phi, indexing="ij")
    s = torch.sqrt(1 - Z**2)
    d = torch.stack([s * torch.sin(PH), s * torch.cos(PH), Z], -1).reshape(-1, 3)
    wt = (w[:, None] * (2 * math.pi / P)).expand(n, P).reshape(-1)
    return d, wt


def test_sh_orthonormal_up_to_degree_16():
    d, wt = _sphere_quadrature(40)
    for dtype, tol in ((torch.float64, 1e-10), (torch.float32, 1e-4)):
        Y = sh_basis(d.to(dtype), 16).double()
        G = Y.T @ (Y * wt[:, None])
        assert torch.allclose(G, torch.eye(289, dtype=torch.float64), atol=tol)


def test_sh_low_order_closed_forms():
    g = torch.Generator().manual_seed(0)
    d = torch.nn.functional.normalize(torch.randn(50, 3, generator=g, dtype=torch.float64), dim=-1)
    x, y, z = d.unbind(-1)
    Y = sh_basis(d, 2)
    c0 = 0.5 / math.sqrt(math.pi)
    c1 = math.sqrt(3 / (4 * math.pi))
    assert torch.allclose(Y[:, 0], torch.full_like(x, c0))
    # degree 1 spans (y, z, x) up to sign
    assert torch.allclose(Y[:, 1].abs(), c1 * y.abs())
    assert torch.allclose(Y[:, 2], c1 * z)
    assert torch.allclose(Y[:, 3].abs(), c1 * x.abs())
    assert torch.allclose(Y[:, 6], math.sqrt(5 / (16 * math.pi)) * (3 * z * z - 1))
    # addition theorem: sum_m Y_lm(d)^2 = (2l + 1) / (4 pi)
    Y6 = sh_basis(d, 6)
    for l in range(7):
        band = Y6[:, l * l:(l + 1) ** 2]
        assert torch.allclose((band**2).sum(-1), torch.full_like(x, (2 * l + 1) / (4 * math.pi)))


def test_order_2_basis_is_the_usual_real_sh_table():
    # the explicit order-2 table of graphics texts (Sloan's / Ramamoorthi-Hanrahan's constants,
    # no Condon-Shortley phase), independently of the recurrence
    g = torch.Generator().manual_seed(1)
    d = torch.nn.functional.normalize(torch.randn(40, 3, generator=g, dtype=torch.float64), dim=-1)
    x, y, z = d.unbind(-1)
    table = torch.stack([torch.full_like(x, 0.282095), 0.488603 * y, 0.488603 * z, 0.488603 * x,
                         1.092548 * x * y, 1.092548 * y * z, 0.315392 * (3 * z * z - 1),
                         1.092548 * x * z, 0.546274 * (x * x - y * y)], -1)
    assert torch.allclose(sh_basis(d, 2), table, atol=2e-6)


def test_sh9_irradiance_closed_forms():
    # L(d) = 1 -> E = pi ; L(d) = max(z, 0)-free band-1 map L = 2 + z -> E = 2 pi + (2 pi / 3) n_z
    H, W = 128, 256
    d = pixel_dirs(H, W, dtype=torch.float64)
    img = (2.0 + d[..., 2:3]).expand(H, W, 3)
    c = sh9_project(img)
    n = torch.nn.functional.normalize(torch.randn(30, 3, dtype=torch.float64), dim=-1)
    E = sh9_irradiance(c, n)
    ref = 2 * math.pi + 2 * math.pi / 3 * n[:, 2:3]
    assert torch.allclose(E, ref.expand(30, 3), rtol=2e-3)


def test_sh_irradiance_matches_brute_force_cosine_integral():
    """Smooth map: order-2 SH irradiance vs a direct sum of L max(n.l, 0) dω over pixels (the
    SH truncation error of a smooth map is small: within 3 %)."""
    H = 48
    d = pixel_dirs(H, 2 * H)
    img = (1.0 + torch.exp(((d * torch.tensor([0.3, 0.4, 0.866])).sum(-1, keepdim=True) - 1)
                           / 0.5)).expand(H, 2 * H, 3).contiguous()
    om = pixel_solid_angles(H, 2 * H)
    n = torch.nn.functional.normalize(torch.tensor([[0.0, 0, 1], [1.0, 0, 0], [0, -1.0, -1]]),
                                      dim=-1)
    brute = torch.einsum("hw,nhw->n", om * img[..., 0],
                         (d[None] * n[:, None, None]).sum(-1).clamp_min(0))
    E = sh9_irradiance(sh9_project(img), n)[:, 0]
    assert torch.allclose(E, brute, rtol=0.03)
