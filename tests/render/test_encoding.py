"""Tests of voxnero/render/encoding.py: SH orthonormality, closed forms, IDE limits."""

from __future__ import annotations

import math

import numpy as np
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from voxnero.render.encoding import ide, sh_basis


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


SPECIAL = [(0.0, 0.0, 1.0), (0.0, 0.0, -1.0), (0.0, 0.0, 0.0), (1e-30, 0.0, 1.0), (1.0, 0.0, 0.0),
           (0.0, -1.0, 0.0), (3.0, 4.0, 0.0), (1e-7, -1e-7, -1.0)]


@settings(max_examples=25, deadline=None)
@given(st.tuples(st.floats(-1, 1), st.floats(-1, 1), st.floats(-1, 1)))
def test_sh_and_ide_finite_everywhere(v):
    d = torch.tensor([v] + SPECIAL, requires_grad=True)
    r = torch.tensor([[0.0]] * len(d), requires_grad=True)
    out = sh_basis(d, 16).sum() + ide(d, r).sum()
    out.backward()
    assert torch.isfinite(out) and torch.isfinite(d.grad).all() and torch.isfinite(r.grad).all()


def test_ide_shape_and_sh_limit():
    g = torch.Generator().manual_seed(1)
    d = torch.nn.functional.normalize(torch.randn(64, 3, generator=g, dtype=torch.float64), dim=-1)
    e0 = ide(d, torch.zeros(64, 1, dtype=torch.float64))
    assert e0.shape == (64, 72)
    Y = sh_basis(d, 16)
    levels = (1, 2, 4, 8, 16)
    # IDE(r = 0): Re part of complex Y_l^m = real SH / sqrt(2) (m > 0), Y_l0 (m = 0)
    k = 0
    for l in levels:
        for m in range(l + 1):
            ref_re = Y[:, l * l + l] if m == 0 else Y[:, l * l + l + m] / math.sqrt(2)
            ref_im = torch.zeros_like(ref_re) if m == 0 else Y[:, l * l + l - m] / math.sqrt(2)
            assert torch.allclose(e0[:, k], ref_re, atol=1e-12)
            assert torch.allclose(e0[:, 36 + k], ref_im, atol=1e-12)
            k += 1
    # roughness -> 0 converges continuously to the SH values
    e_small = ide(d, torch.full((64, 1), 1e-3, dtype=torch.float64))
    assert (e_small - e0).abs().max() < 136 * 1e-6 * e0.abs().max() + 1e-12
    # attenuation exp(-l(l+1) alpha / 2) with alpha = r^2
    r = 0.3
    e = ide(d, torch.full((64, 1), r, dtype=torch.float64))
    assert torch.allclose(e[:, 2:5], e0[:, 2:5] * math.exp(-3 * r * r))  # l = 2: columns 2-4


def test_ide_matches_vmf_expectation_for_large_kappa():
    # E_{w ~ vMF(mu, kappa)}[Y_lm(w)] = A_l(kappa) Y_lm(mu) exactly, with
    # A_l = I_{l+1/2}(kappa) / I_{1/2}(kappa) ~ exp(-l(l+1) / (2 kappa)) for large kappa
    from scipy.special import ive

    kappa = 200.0
    mu = torch.nn.functional.normalize(torch.tensor([0.3, -0.4, 0.8], dtype=torch.float64), dim=0)
    r = math.sqrt(1 / kappa)
    # vMF expectation by 1-D quadrature in t = cos(angle to mu) (zonal average)
    t, w = np.polynomial.legendre.leggauss(400)
    pdf = kappa / (2 * math.sinh(kappa)) * np.exp(kappa * t)  # density in t (times 2 pi / 2 pi)
    for l in (1, 2, 4, 8):
        P = np.polynomial.legendre.Legendre.basis(l)(t)
        a_exact = float(np.sum(w * pdf * P))
        a_bessel = ive(l + 0.5, kappa) / ive(0.5, kappa)
        assert abs(a_exact - a_bessel) < 1e-8
        e = ide(mu[None], torch.tensor([[r]], dtype=torch.float64))
        e0 = ide(mu[None], torch.zeros(1, 1, dtype=torch.float64))
        k = {1: 0, 2: 2, 4: 5, 8: 10}[l]
        ratio = (e[0, k] / e0[0, k]).item()
        assert abs(ratio - a_exact) < 0.02 * l, (l, ratio, a_exact)
